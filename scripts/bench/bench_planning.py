"""Planner figures on the hand-made shelf world (robot base frame):

- collision checks per second (batched sphere-world queries, and one config at a time),
- IK time (collision-aware, 32 seeds, one target pose),
- RRTConnect planning time from the default configuration into the shelf,
- with ``--tasks N``: the ga-mesh-rrt pipeline on N sampled FetchBench tasks
  (success rate, median computation time).

Usage: python scripts/bench/bench_planning.py [--trials 10] [--tasks 0] [--method ga-mesh-rrt] [--workers 1] [--out DIR]
"""
from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch


def bench_core(trials: int) -> None:
    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.demo_worlds import hand_pose, shelf_worlds
    from fetchbench_ms.planning.ik import solve_ik
    from fetchbench_ms.planning.robot import Q_DEFAULT, panda
    from fetchbench_ms.planning.rrt import plan_rrtconnect

    robot = panda()
    world, _ = shelf_worlds()
    checker = CollisionChecker(robot, world)
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.q_min, robot.q_max, (4096, 7))
    checker.valid(q[:64])  # warm-up
    t = time.perf_counter()
    for chunk in np.split(q, 4):
        checker.valid(chunk)
    batched = len(q) / (time.perf_counter() - t)
    t = time.perf_counter()
    for qi in q[:300]:
        checker.valid(qi)
    single = 300 / (time.perf_counter() - t)
    print(f"collision checks/s: {batched:,.0f} batched (1024 per call), {single:,.0f} one at a time "
          f"({len(robot.spheres.radii)} robot spheres, 6-box shelf + robot table)")

    # Goals on the lower and middle shelf, hand pointing in (+x), random lateral offsets.
    poses = [hand_pose([rng.uniform(0.62, 0.72), rng.uniform(-0.25, 0.25), z]) for z in
             rng.choice([0.1, 0.4], size=trials)]
    ik_times, plan_times, statuses = [], [], []
    for T in poses:
        t = time.perf_counter()
        ik = solve_ik(robot, T, checker=checker, q_seed=Q_DEFAULT, n_seeds=32, rng=np.random.default_rng(1))
        ik_times.append(time.perf_counter() - t)
        if not ik.found:
            statuses.append("no_ik")
            continue
        result = plan_rrtconnect(checker, Q_DEFAULT, ik.q[:5], time_limit=10.0)
        statuses.append(result.status)
        if result.success:
            plan_times.append(result.planning_time)
    print(f"IK (32 seeds, collision-aware): median {statistics.median(ik_times) * 1000:.0f} ms over {len(ik_times)} poses")
    if plan_times:
        print(f"RRTConnect into the shelf: median {statistics.median(plan_times):.2f} s, max {max(plan_times):.2f} s, "
              f"{len(plan_times)}/{trials} solved; statuses {dict((s, statuses.count(s)) for s in set(statuses))}")


def bench_pipeline(n_tasks: int, method: str, seed: int, out_dir: str | None, workers: int) -> None:
    """The pipeline on ``n_tasks`` sampled (unfiltered) tasks, seeds ``seed..``, through the
    evaluation runner; success overall and on the tasks where an annotated grasp had a
    collision-free IK solution (what FetchBench's reachability filter keeps)."""
    import collections
    import tempfile

    from fetchbench_ms.evaluation import evaluate
    from fetchbench_ms.evaluation.metrics import format_table, summarize

    out_dir = out_dir or tempfile.mkdtemp(prefix=f"bench_{method}_")
    records = evaluate(method, out_dir, env_id="FetchBench-v0", episodes=n_tasks, seed=seed,
                       workers=workers, progress=False)
    ran = [r for r in records if not r.get("error")]
    reachable = [r for r in ran if r["phases"]["ik_found"]]
    for which, rs in (("sampled tasks (unfiltered)", ran), ("tasks with an IK-feasible annotated grasp", reachable)):
        if not rs:
            print(f"{method} on {which}: none")
            continue
        by = collections.defaultdict(lambda: [0, 0])
        for r in rs:
            by[r["category"]][0] += bool(r["success"])
            by[r["category"]][1] += 1
        per = ", ".join(f"{c} {a}/{b}" for c, (a, b) in sorted(by.items()))
        times = [r["computation_time"] for r in rs]
        print(f"{method} on {which}: success {sum(bool(r['success']) for r in rs)}/{len(rs)} ({per}); "
              f"computation time median {statistics.median(times):.2f} s, max {max(times):.2f} s; "
              f"failures {dict(collections.Counter(r['failure'] for r in rs if not r['success']))}")
    print(format_table(summarize(records), "by_category"))
    print(f"records: {out_dir}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--tasks", type=int, default=0)
    parser.add_argument("--method", default="ga-mesh-rrt")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1, help="evaluation worker processes for --tasks")
    parser.add_argument("--out", default=None, help="results folder for --tasks (resumable; default a temporary one)")
    args = parser.parse_args()
    torch.set_num_threads(1)  # small batches: threads only add overhead on a shared CPU
    bench_core(args.trials)
    if args.tasks:
        bench_pipeline(args.tasks, args.method, args.seed, args.out, args.workers)


if __name__ == "__main__":
    main()
