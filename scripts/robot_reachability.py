"""Re-judge the suite's robot-dependent filter (reachability) for each robot.

The task suites were filtered for the Panda: every task's target has an annotated grasp
with a collision-free IK solution from the Panda's base. The other setups keep the same
tasks (same scene, objects, target, base pose and cameras), so that filter is judged
again here for each robot, with the same check (``tasks.filters.FilterEnv.reachable``:
the open hand free of the scene, then collision-aware IK over up to 32 grasps, 6 seeds
each drawn from the task's own seed as when the suite was built, in the oracle mesh
world) and that robot's model; the tasks it fails are the ones the robot cannot fetch
whatever the method.

    python scripts/robot_reachability.py --suite test --tasks 0:60 [--robots panda,kinova_gen3_robotiq] [--out FILE]

Prints per robot and scene type how many targets are reachable, and writes the per-task
verdicts as JSON (``--out``).
"""
from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict

from fetchbench_ms.evaluation.runner import open_suite, parse_range
from fetchbench_ms.robots import ROBOT_UIDS, check_robot_uid
from fetchbench_ms.tasks.filters import FilterEnv
from fetchbench_ms.utils.io import atomic_write_text, canonical_json


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", default="test")
    parser.add_argument("--tasks", default="0:60", help="START:END slice of the suite's tasks")
    parser.add_argument("--robots", default=",".join(ROBOT_UIDS))
    parser.add_argument("--out", default=None, help="JSON file of the per-task verdicts")
    args = parser.parse_args()
    robots = [check_robot_uid(r.strip()) for r in args.robots.split(",") if r.strip()]
    suite, _, _ = open_suite(args.suite)
    ids = list(suite.tasks)
    selection = [ids[i] for i in parse_range(args.tasks, len(ids))]
    if not selection:
        raise SystemExit(f"no tasks in {args.suite} {args.tasks}")
    verdicts: dict = {}
    for robot in robots:
        started = time.perf_counter()
        filt = FilterEnv(robot_uids=robot, obs_mode="none")
        try:
            verdicts[robot] = {}
            for task_id in selection:
                task = suite.get(task_id)
                filt.load(task)
                # The IK seeds the suite builder drew for this task (its arrangement seed), so
                # the Panda's verdicts reproduce the suite's filter.
                reachable = filt.reachable([task.target_index], seed=task.seed)
                verdicts[robot][task_id] = bool(reachable[task.target_index])
        finally:
            filt.close()
        by_type = defaultdict(lambda: [0, 0])
        for task_id, ok in verdicts[robot].items():
            by_type[suite.get(task_id).scene_type][0] += ok
            by_type[suite.get(task_id).scene_type][1] += 1
        total = sum(verdicts[robot].values())
        print(f"{robot}: {total}/{len(selection)} targets reachable ({time.perf_counter() - started:.0f} s); "
              + ", ".join(f"{t} {a}/{b}" for t, (a, b) in sorted(by_type.items())))
    if args.out:
        atomic_write_text(args.out, canonical_json({"suite": suite.name, "tasks": args.tasks, "reachable": verdicts}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
