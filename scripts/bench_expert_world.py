"""The expert demo generator with and without the per-task mesh-world cache
(``solutions.worlds.MESH_WORLD_CACHE``): seconds a task, and the trajectories compared.

Runs ``demos.generate.run_task`` (the generator's worker: up to --per-task successful
trajectories from up to 8 tries) on the suite's tasks --start .. --start + --tasks - 1 in this
process, once with ``FETCHBENCH_MESH_WORLD_CACHE=0`` (every world built from scratch) and once
with the cache, and checks that both made the same trajectories (every dataset of every
``traj_N``, and the episodes' JSON). Prints seconds a task each way and the speed-up.

    PYTHONPATH=. python scripts/bench_expert_world.py --tasks 3
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np


def datasets(path: Path) -> dict:
    import h5py

    out = {}
    with h5py.File(path, "r") as f:
        f.visititems(lambda name, obj: out.__setitem__(name, obj[()]) if isinstance(obj, h5py.Dataset) else None)
    return out


def same_part(a: Path, b: Path) -> bool:
    da, db = datasets(a), datasets(b)
    if set(da) != set(db) or not all(np.array_equal(da[k], db[k]) for k in da):
        return False
    ja, jb = (json.loads(p.with_suffix(".json").read_text())["episodes"] for p in (a, b))
    return ja == jb


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--suite", default="train", choices=["train", "val"])
    p.add_argument("--start", type=int, default=0)
    p.add_argument("--tasks", type=int, default=3)
    p.add_argument("--per-task", type=int, default=5)
    args = p.parse_args(argv)
    if args.tasks < 1:
        p.error("--tasks must be >= 1")
    from fetchbench_ms.demos.generate import DemoJob, part_path, run_task, suite_task_ids
    from fetchbench_ms.solutions import worlds

    job = DemoJob(task_suite=args.suite, per_task=args.per_task)
    ids = suite_task_ids(job.env_id, args.suite)[args.start:args.start + args.tasks]
    modes = ("rebuilt", "cached")
    seconds = {m: [] for m in modes}
    with tempfile.TemporaryDirectory() as tmp:
        parts = {m: Path(tmp) / m for m in ("warm-up", *modes)}
        for folder in parts.values():
            folder.mkdir()
        # Untimed: the env, the renderer-free scene build, the objects' and grasps' caches.
        run_task(job, parts["warm-up"], args.start, ids[0])
        for i, task_id in enumerate(ids):
            # Each task in both modes, in turn first (what one run warms, the other reuses).
            for mode in (modes if i % 2 == 0 else modes[::-1]):
                os.environ["FETCHBENCH_MESH_WORLD_CACHE"] = "0" if mode == "rebuilt" else "1"
                worlds.MESH_WORLD_CACHE.__init__()  # a task starts with an empty cache
                t = time.perf_counter()
                summary = run_task(job, parts[mode], args.start + i, task_id)
                seconds[mode].append(time.perf_counter() - t)
                print(f"{task_id} {mode}: {seconds[mode][-1]:.1f} s, {summary['successes']} trajectories of "
                      f"{summary['tries']} tries", flush=True)
        same = all(same_part(part_path(parts["rebuilt"], args.start + i), part_path(parts["cached"], args.start + i))
                   for i in range(len(ids)))
    cache = worlds.MESH_WORLD_CACHE
    print(f"machine: {platform.node()}, {os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}")
    print(f"{len(ids)} {args.suite} tasks from {args.start}, one process: rebuilt {sum(seconds['rebuilt']):.1f} s, "
          f"cached {sum(seconds['cached']):.1f} s: {sum(seconds['rebuilt']) / sum(seconds['cached']):.2f}x; "
          f"the same trajectories: {same}; the last task's furniture sets reused {cache.hits} times")
    if not same:
        raise SystemExit("the cached worlds made other trajectories")


if __name__ == "__main__":
    main()
