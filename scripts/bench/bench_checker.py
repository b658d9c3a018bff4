"""The exact collision checker's speed on the planning problems of suite tasks.

Every planner's verdicts go through ``CollisionChecker.valid``: RRTConnect's extensions, the
trajectory optimiser's direct segments and its chosen path's check and shortcuts. This times
``clearance`` on what those calls look like in a task's world: each recorded problem's
straight segments from the start to its goals, densified at 0.02 rad (as the planners check
them), in batches of ``--batch`` configurations. It prints configurations per second (median
over problems of the best of ``--repeats``), and ``--json PATH`` writes the same with the run.

Problems are recorded as ``bench_trajopt.py`` records them (the ``ga-mesh-rrt`` pipeline up to
its first plan call), so the worlds are the tasks' own: furniture, clutter, target.

Usage: python scripts/bench/bench_checker.py --suite val --tasks 0:20 [--batch 16 128] [--json PATH]
"""
from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_trajopt import record_problems  # noqa: E402  (the same recorded problems)


def segment_configs(problem: dict, resolution: float = 0.02) -> np.ndarray:
    """The problem's start-to-goal straight segments, densified as the planners check them."""
    from fetchbench_ms.planning.rrt import densify

    return np.concatenate([densify(np.stack([problem["q_start"], g]), resolution) for g in problem["q_goals"]])


def configs_per_second(checker, q: np.ndarray, batch: int, repeats: int) -> float:
    """Best of ``repeats`` passes over ``q`` in batches of ``batch``: configurations a second."""
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        for i in range(0, len(q), batch):
            checker.clearance(q[i: i + batch])
        best = min(best, time.perf_counter() - t)
    return len(q) / best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--suite", default="val")
    parser.add_argument("--tasks", default="0:20")
    parser.add_argument("--batch", type=int, nargs="+", default=[16, 128], help="configurations per clearance call")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--json", default=None, metavar="PATH")
    args = parser.parse_args()
    if any(b < 1 for b in args.batch) or args.repeats < 1:
        parser.error("--batch and --repeats take positive counts")
    torch.set_num_threads(args.threads)
    problems = record_problems(args.suite, args.tasks, "mesh", False)
    if not problems:
        sys.exit(f"no planning problems recorded from {args.suite} {args.tasks}: nothing was measured")
    rows = {}
    for batch in args.batch:
        rates = [configs_per_second(p["checker"], segment_configs(p), batch, args.repeats) for p in problems]
        rows[f"batch_{batch}"] = {"problems": len(rates), "configs_per_s_median": statistics.median(rates),
                                  "configs_per_s_min": min(rates), "configs_per_s_max": max(rates)}
        print(f"batch {batch:4d}: {statistics.median(rates):8.0f} configurations/s median over {len(rates)} "
              f"problems (min {min(rates):.0f}, max {max(rates):.0f})")
    if args.json:
        record = {**rows, "run": {"command": " ".join(["scripts/bench/bench_checker.py"] + sys.argv[1:]),
                                  "suite": args.suite, "tasks": args.tasks, "threads": args.threads,
                                  "repeats": args.repeats, "torch": torch.__version__,
                                  "machine": platform.machine()}}
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
