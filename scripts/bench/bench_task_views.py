"""CPU time of Contact-GraspNet task views (``baselines/contact_graspnet/task_views.py``) a task,
with the hand's scene test in clusters of nearby points (the labeller's broad phase) and with the
flat per-point broad phase, on the same tasks, in turn; checks that both make the same views.

    OMP_NUM_THREADS=1 python scripts/bench/bench_task_views.py --suite train --tasks 3000:3008 \\
        --json results/training/bench-task-views-cpu1-train3000-8.json

One process, one torch thread; the first task only warms the env and its caches up and is not
timed. CPU seconds (``time.process_time``) rather than wall seconds: the figure is what a core
spends, whatever else the machine runs.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "baselines" / "contact_graspnet"))


def same_views(a: list[dict], b: list[dict]) -> bool:
    return len(a) == len(b) and all(va.keys() == vb.keys() and all(np.array_equal(np.asarray(va[k]), np.asarray(vb[k]))
                                                                   for k in va) for va, vb in zip(a, b))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--suite", default="train", help="train or val (test is refused)")
    p.add_argument("--tasks", default="3000:3008", help="START:END of the suite's task order")
    p.add_argument("--json", help="write the figures here")
    args = p.parse_args(argv)
    if args.suite not in ("train", "val"):
        p.error(f"--suite {args.suite!r}: valid choices: train, val")
    import torch

    import task_views
    from fetchbench_ms.planning import world
    from fetchbench_ms.tasks.suite import load_suite

    torch.set_num_threads(1)
    try:
        start, end = (int(x) for x in args.tasks.split(":"))
    except ValueError:
        p.error(f"--tasks {args.tasks!r}: expected START:END")
    ids = load_suite(args.suite).ids()[start:end]
    if len(ids) < 2:
        p.error(f"--tasks {args.tasks!r}: at least 2 tasks of suite {args.suite!r} (the first only warms up)")
    task_views._init_worker(args.suite)
    view_args = task_views.Args(suite=args.suite)
    task_views.task_views(task_views._ENV, ids[0], view_args)  # warm-up: the env, object and grasp caches
    clustered_distance = world.CollisionWorld.distance

    def flat_distance(self, points, horizon=0.2, exclude=(), cluster_size=0):
        return clustered_distance(self, points, horizon, exclude)

    figures, views = {}, {}
    for mode, distance in (("clustered", clustered_distance), ("flat", flat_distance)):
        world.CollisionWorld.distance = distance
        t = time.process_time()
        views[mode] = [task_views.task_views(task_views._ENV, task_id, view_args) for task_id in ids[1:]]
        figures[mode] = {"cpu_s_a_task": round((time.process_time() - t) / (len(ids) - 1), 3)}
    world.CollisionWorld.distance = clustered_distance
    identical = all(same_views(a, b) for a, b in zip(views["clustered"], views["flat"]))
    record = {"suite": args.suite, "tasks": args.tasks, "timed_tasks": len(ids) - 1,
              "views": sum(len(v) for v in views["flat"]), **figures,
              "speedup": round(figures["flat"]["cpu_s_a_task"] / figures["clustered"]["cpu_s_a_task"], 2),
              "identical_views": identical, "command": "python scripts/bench/bench_task_views.py " + " ".join(argv or sys.argv[1:])}
    print(f"{record['timed_tasks']} {args.suite} tasks, {record['views']} views: clustered "
          f"{figures['clustered']['cpu_s_a_task']} CPU s a task, flat {figures['flat']['cpu_s_a_task']} "
          f"({record['speedup']}x); views identical: {identical}")
    if args.json:
        from fetchbench_ms.utils.io import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(record, indent=1) + "\n")
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
