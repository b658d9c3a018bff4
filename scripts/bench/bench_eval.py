"""Evaluation throughput: tasks per hour per core of a method, and the projected wall time
of the test suite (the shipped one, and the planned 6,000 tasks) on 16 cores.

    python scripts/bench/bench_eval.py --suite smoke --tasks 0:8 --workers 2 --out out/bench_eval

Runs ``fetchbench eval`` (resuming if OUT already has results) and measures from the
records: per-task wall time in the worker (env reset + method + judging), so the figure
is per core, independent of how many workers shared the machine. Worker start-up
(imports, ~10 s once per worker) is amortised over a long run and left out; the run's
own wall clock is printed too. Numbers taken while other jobs load the machine are
pessimistic: the load average is printed with them.
"""
from __future__ import annotations

import argparse
import os
import statistics
import time

PLANNED_SUITE_TASKS = 6000  # the paper's test suite; the shipped one may hold fewer (docs/suite.md)
PROJECTION_CORES = 16


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", default="ga-mesh-rrt")
    parser.add_argument("--suite", default="smoke")
    parser.add_argument("--tasks", default="0:8")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="out/bench_eval")
    args = parser.parse_args()

    from fetchbench_ms.evaluation import evaluate, format_table, summarize
    from fetchbench_ms.tasks.suite import load_suite

    shipped_test_tasks = len(load_suite("test"))

    load_before = os.getloadavg()
    start = time.perf_counter()
    records = evaluate(args.method, os.path.join(args.out, args.method), suite=args.suite, tasks=args.tasks,
                       workers=args.workers)
    wall = time.perf_counter() - start
    ran = [r for r in records if "wall_time" in r]
    per_task = [r["wall_time"] for r in ran]
    mean = statistics.mean(per_task)
    per_hour_per_core = 3600.0 / mean
    print(format_table(summarize(records)))
    print()
    print(f"method {args.method}, suite {args.suite} tasks {args.tasks}: {len(ran)} tasks timed "
          f"({len(records) - len(ran)} errored without a time)")
    print(f"per-task wall time in a worker: mean {mean:.1f} s, median {statistics.median(per_task):.1f} s, "
          f"max {max(per_task):.1f} s")
    print(f"throughput: {per_hour_per_core:.0f} tasks per hour per core")
    for n, what in ((shipped_test_tasks, "shipped test"), (PLANNED_SUITE_TASKS, "planned")):
        print(f"projected wall time of the {n}-task {what} suite on {PROJECTION_CORES} cores: "
              f"{n * mean / PROJECTION_CORES / 3600.0:.2f} h")
    print(f"this run: {wall:.0f} s wall with {args.workers} worker(s) (incl. start-up; resumed tasks not re-run)")
    print(f"load average before / after: {load_before[0]:.1f} / {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
