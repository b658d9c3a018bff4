"""The expert demo generator with and without the per-task mesh-world cache
(``planning.world_models.MESH_WORLD_CACHE``): seconds a task, and the trajectories compared.

Runs ``demos.generate.run_task`` (the generator's worker: up to --per-task successful
trajectories from up to 8 tries) on the suite's tasks --start .. --start + --tasks - 1, once
with ``FETCHBENCH_MESH_WORLD_CACHE=0`` (every world built from scratch) and once with the cache,
each in a process of its own after an untimed warm-up task, and checks that both made the same
trajectories (every dataset of every ``traj_N``, and the episodes' JSON). Prints seconds a task
each way and the speed-up.

    PYTHONPATH=. python scripts/bench_expert_world.py --tasks 3
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
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


def run_mode(args) -> None:
    """One mode in this process (the parent's subprocess): a warm-up task, then the tasks."""
    from fetchbench_ms.demos.generate import DemoJob, run_task, suite_task_ids
    from fetchbench_ms.planning import world_models as worlds

    os.environ["FETCHBENCH_MESH_WORLD_CACHE"] = "0" if args.mode == "rebuilt" else "1"
    # The reference expert: the fast one reuses sets at nearby poses, which a rebuilt world cannot.
    job = DemoJob(task_suite=args.suite, per_task=args.per_task, expert="reference")
    ids = suite_task_ids(job.env_id, args.suite)
    out = Path(args.parts)
    (out / "warm-up").mkdir(parents=True)
    # Untimed: the env, the objects' and grasps' caches. Another task than the timed ones, so
    # that each timed task starts with a new scene, as in the generator's workers.
    warm = args.start + args.tasks if args.start + args.tasks < len(ids) else args.start - 1
    run_task(job, out / "warm-up", warm, ids[warm])
    seconds = []
    for seed in range(args.start, args.start + args.tasks):
        t = time.perf_counter()
        summary = run_task(job, out, seed, ids[seed])
        seconds.append(time.perf_counter() - t)
        print(f"{ids[seed]} {args.mode}: {seconds[-1]:.1f} s, {summary['successes']} trajectories of "
              f"{summary['tries']} tries", flush=True)
    (out / "seconds.json").write_text(json.dumps({"seconds": seconds, "hits": worlds.MESH_WORLD_CACHE.hits}))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--suite", default="train", choices=["train", "val"])
    p.add_argument("--start", type=int, default=0)
    p.add_argument("--tasks", type=int, default=3)
    p.add_argument("--per-task", type=int, default=5)
    p.add_argument("--mode", choices=["rebuilt", "cached"], help=argparse.SUPPRESS)  # (a subprocess's)
    p.add_argument("--parts", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.tasks < 1:
        p.error("--tasks must be >= 1")
    if args.mode:
        return run_mode(args)
    from fetchbench_ms.demos.generate import part_path

    # Each mode in a fresh process, as a generator's worker runs: a task's trajectories depend
    # on its seed and on the task the worker's env was on before (a reset to the same task
    # again skips the scene rebuild and starts from other physics state).
    seconds, hits = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        for mode in ("rebuilt", "cached"):
            folder = Path(tmp) / mode
            subprocess.run([sys.executable, __file__, "--suite", args.suite, "--start", str(args.start), "--tasks",
                            str(args.tasks), "--per-task", str(args.per_task), "--mode", mode, "--parts", str(folder)],
                           check=True)
            record = json.loads((folder / "seconds.json").read_text())
            seconds[mode], hits[mode] = record["seconds"], record["hits"]
        same = all(same_part(part_path(Path(tmp) / "rebuilt", seed), part_path(Path(tmp) / "cached", seed))
                   for seed in range(args.start, args.start + args.tasks))
    rebuilt, cached = sum(seconds["rebuilt"]), sum(seconds["cached"])
    print(f"machine: {platform.node()}, {os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}")
    print(f"{args.tasks} {args.suite} tasks from {args.start}, one process each way: rebuilt {rebuilt:.1f} s, "
          f"cached {cached:.1f} s: {rebuilt / cached:.2f}x; the same trajectories: {same}; "
          f"the furniture's sets reused {hits['cached']} times")
    if not same:
        raise SystemExit("the cached worlds made other trajectories")


if __name__ == "__main__":
    main()
