"""Fraction of default seed-reset tasks that pass FetchBench's filters, per env id.

For every registered id and seeds 0..N-1, the task a default ``reset(seed=s)`` loads is
the suite task ``FetchBenchEnv.suite_task_id(s)`` picks (default suite: ``train``; pass
``--suite val`` while it is not shipped). Every distinct task drawn is judged once with
the filters themselves (``tasks.filters.FilterEnv.check``: stable, visible in both
cameras, collision-free IK for a grasp), and each id's fraction counts seeds.

    PYTHONPATH=. python scripts/bench/check_default_tasks.py [--seeds 200] [--suite val] [--max-checks K]

``--max-checks K`` judges only the first K distinct tasks (in order of first draw) and
reports the fraction over the seeds whose task was judged.
"""
from __future__ import annotations

import argparse
import time

import fetchbench_ms  # noqa: F401  (FetchBench-*-v0)
from fetchbench_ms.envs import ENV_KWARGS
from fetchbench_ms.envs.task_source import DEFAULT_OBJECT_SPLIT, DEFAULT_TASK_SUITE, resolve_task_source


def draws(suite: str, seeds: int) -> dict[str, list[str]]:
    """env id -> the suite task id of each seed (what the env's reset loads)."""
    import numpy as np

    out = {}
    for env_id, kwargs in ENV_KWARGS.items():
        try:
            _, _, pool = resolve_task_source(None, suite, DEFAULT_OBJECT_SPLIT, kwargs.get("scene_type"),
                                             kwargs.get("category"))
        except ValueError as error:
            print(f"{env_id}: {error}")
            continue
        out[env_id] = [pool[int(np.random.default_rng(s).integers(len(pool)))] for s in range(seeds)]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=200)
    parser.add_argument("--suite", default=DEFAULT_TASK_SUITE)
    parser.add_argument("--max-checks", type=int, default=None)
    args = parser.parse_args()
    from fetchbench_ms.tasks.filters import FilterEnv
    from fetchbench_ms.tasks.suite import load_suite

    suite = load_suite(args.suite)
    picked = draws(args.suite, args.seeds)
    order = list(dict.fromkeys(i for ids in picked.values() for i in ids))[: args.max_checks]
    filters = FilterEnv()
    verdict, start = {}, time.perf_counter()
    try:
        for task_id in order:
            task = suite.get(task_id)
            check = filters.check(task, targets=[task.target_index])
            verdict[task_id] = check.rejection(task.target_index)
    finally:
        filters.close()
    print(f"judged {len(verdict)} distinct tasks of suite {args.suite!r} in {time.perf_counter() - start:.0f} s; "
          f"failing: {sorted((i, r) for i, r in verdict.items() if r) or 'none'}")
    for env_id, ids in picked.items():
        judged = [i for i in ids if i in verdict]
        passing = sum(verdict[i] is None for i in judged)
        print(f"{env_id}: {passing}/{len(judged)} = {passing / max(1, len(judged)):.3f} of seeds 0-{args.seeds - 1} "
              f"({len(set(ids))} distinct tasks)")


if __name__ == "__main__":
    main()
