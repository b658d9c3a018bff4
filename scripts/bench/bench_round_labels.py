"""CPU time a task of the grasp rounds' two labellers, each with its faster broad phase on and
off, on the same tasks in turn; checks that both ways make the same labels.

- ``--labeller views``: Contact-GraspNet task views (``baselines/contact_graspnet/task_views.py``),
  the open hand's scene test in clusters of nearby points against point by point;
- ``--labeller collision``: the scene-collision network's labelled queries
  (``baselines/mppi_collision/labels.py``), convex parts in torch worlds by plane count
  (``plane_buckets``) against one world padded to the largest part.

    OMP_NUM_THREADS=1 python scripts/bench/bench_round_labels.py --labeller views --suite train --tasks 3000:3009 \\
        --json results/training/bench-task-views-cpu1-train3000-9.json
    OMP_NUM_THREADS=1 python scripts/bench/bench_round_labels.py --labeller collision --suite train --tasks 3000:3005 \\
        --json results/training/bench-collision-labels-cpu1-train3000-5.json

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
LABELLERS = ("views", "collision")


def same(a, b) -> bool:
    """Labels equal to the bit: dicts, lists of them and arrays (a task's ``seconds`` left out)."""
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a if k != "seconds")
    if isinstance(a, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return np.array_equal(np.asarray(a), np.asarray(b))


def labellers(name: str, suite: str):
    """(label one task, {way: switch it on}) of a labeller, its env made."""
    if name == "views":
        sys.path.insert(0, str(ROOT / "baselines" / "contact_graspnet"))
        import task_views

        from fetchbench_ms.planning import world

        task_views._init_worker(suite)
        clustered = world.CollisionWorld.distance

        def flat(self, points, horizon=0.2, exclude=(), cluster_size=0):
            return clustered(self, points, horizon, exclude)

        ways = {"fast": lambda: setattr(world.CollisionWorld, "distance", clustered),
                "before": lambda: setattr(world.CollisionWorld, "distance", flat)}
        view_args = task_views.Args(suite=suite)
        return (lambda task_id: task_views.task_views(task_views._ENV, task_id, view_args)), ways
    sys.path.insert(0, str(ROOT / "baselines" / "mppi_collision"))
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401  (registers the envs)
    import labels

    env = gym.make("FetchBench-v0", obs_mode="pointcloud", task_suite=suite, control_mode="pd_joint_pos")
    buckets = labels.plane_buckets
    ways = {"fast": lambda: setattr(labels, "plane_buckets", buckets),
            "before": lambda: setattr(labels, "plane_buckets", lambda world: [world])}
    label_args = labels.Args(suite=suite)
    return (lambda task_id: labels.label_task(env, task_id, label_args)), ways


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--labeller", required=True, help=f"one of {', '.join(LABELLERS)}")
    p.add_argument("--suite", default="train", help="train or val (test is refused)")
    p.add_argument("--tasks", default="3000:3008", help="START:END of the suite's task order")
    p.add_argument("--json", help="write the figures here")
    args = p.parse_args(argv)
    if args.labeller not in LABELLERS:
        p.error(f"--labeller {args.labeller!r}: valid choices: {', '.join(LABELLERS)}")
    if args.suite not in ("train", "val"):
        p.error(f"--suite {args.suite!r}: valid choices: train, val")
    import torch

    from fetchbench_ms.tasks.suite import load_suite

    torch.set_num_threads(1)
    try:
        start, end = (int(x) for x in args.tasks.split(":"))
    except ValueError:
        p.error(f"--tasks {args.tasks!r}: expected START:END")
    ids = load_suite(args.suite).ids()[start:end]
    if len(ids) < 2:
        p.error(f"--tasks {args.tasks!r}: at least 2 tasks of suite {args.suite!r} (the first only warms up)")
    label, ways = labellers(args.labeller, args.suite)
    label(ids[0])  # warm-up: the env, object and grasp caches
    figures, made = {}, {}
    for way in ("fast", "before"):
        ways[way]()
        t = time.process_time()
        made[way] = [label(task_id) for task_id in ids[1:]]
        figures[way] = {"cpu_s_a_task": round((time.process_time() - t) / (len(ids) - 1), 3)}
    ways["fast"]()
    identical = same(made["fast"], made["before"])
    record = {"labeller": args.labeller, "suite": args.suite, "tasks": args.tasks, "timed_tasks": len(ids) - 1, **figures,
              "speedup": round(figures["before"]["cpu_s_a_task"] / figures["fast"]["cpu_s_a_task"], 2),
              "identical_labels": identical,
              "command": "python scripts/bench/bench_round_labels.py " + " ".join(argv or sys.argv[1:])}
    print(f"{args.labeller}: {record['timed_tasks']} {args.suite} tasks: {figures['fast']['cpu_s_a_task']} CPU s a task, "
          f"{figures['before']['cpu_s_a_task']} without the faster broad phase ({record['speedup']}x); "
          f"labels identical: {identical}")
    if args.json:
        from fetchbench_ms.utils.io import atomic_write_text

        atomic_write_text(Path(args.json), json.dumps(record, indent=1) + "\n")
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
