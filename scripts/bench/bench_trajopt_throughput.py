"""Batched trajopt throughput: problems planned a second by several processes sharing a device.

One process plans a batch's host phases (the exact checker's direct segments, the chosen
paths' checks and shortcuts) on one core, so a GPU serves many problems a second only when
several processes feed it, as the evaluation's workers do. Each of ``--workers`` processes
(``spawn``) records the planning problems of its contiguous slice of the tasks (as
``bench_trajopt.py`` records them), plans them all once in batches of ``--batch`` (the warm
pass: CUDA context, compiled shapes), waits for the others, then plans them all again (the
timed pass; the same plans: the budgets are counts). Throughput is all workers' problems
over the wall time from the first timed pass's start to the last one's end.

Usage (val tasks; the figure is for one device, so pin the processes to it):
  CUDA_VISIBLE_DEVICES=0 python scripts/bench/bench_trajopt_throughput.py --suite val --tasks 0:120 \\
      --workers 8 --batch 16 --device cuda --config cuda_graph=true --config world_grid=0.015
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_trajopt import config_overrides, counts_of, is_searched, record_problems  # noqa: E402  (the same problems, --config)


def plan_pass(problems: list[dict], cfg, batch: int, time_limit: float) -> list:
    """Every problem planned by ``plan_trajopt_batch`` in batches of ``batch``, in order."""
    from fetchbench_ms.planning.trajopt import plan_trajopt_batch

    results = []
    for i in range(0, len(problems), batch):
        chunk = problems[i: i + batch]
        results += plan_trajopt_batch([(p["checker"], p["q_start"], p["q_goals"]) for p in chunk], time_limit, cfg,
                                      start_tolerance=chunk[0]["start_tolerance"])
    return results


def _worker(job: tuple) -> dict:
    suite, tasks, device, batch, time_limit, overrides, barrier = job
    torch.set_num_threads(1)
    from fetchbench_ms.planning.trajopt import TrajoptConfig

    problems = record_problems(suite, tasks, "mesh", False)
    cfg = TrajoptConfig.for_device(device, **overrides)
    warm = plan_pass(problems, cfg, batch, time_limit) if problems else []
    barrier.wait()
    t0 = time.time()
    timed = plan_pass(problems, cfg, batch, time_limit) if problems else []
    t1 = time.time()
    return dict(tasks=tasks, problems=len(timed), solved=sum(r.success for r in timed),
                searched=sum(is_searched(r) for r in timed), start=t0, end=t1,
                same_as_warm=[r.status for r in warm] == [r.status for r in timed]
                and all(np.array_equal(a.path, b.path) for a, b in zip(warm, timed) if a.success))


def aggregate(parts: list[dict]) -> dict:
    """All workers' problems over the wall time from the first timed start to the last end."""
    problems = sum(p["problems"] for p in parts)
    seconds = max(p["end"] for p in parts) - min(p["start"] for p in parts)
    return dict(workers=len(parts), problems=problems, searched=sum(p["searched"] for p in parts),
                success=sum(p["solved"] for p in parts) / max(problems, 1), seconds=seconds,
                problems_per_s=problems / seconds if seconds > 0 else None,
                same_as_warm=all(p["same_as_warm"] for p in parts))


def main() -> None:
    import multiprocessing as mp

    from fetchbench_ms.evaluation.runner import open_suite, parse_range

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--suite", default="val")
    parser.add_argument("--tasks", default="0:120")
    parser.add_argument("--workers", type=int, default=8)
    parser.add_argument("--batch", type=int, default=16)
    parser.add_argument("--device", default=None, help="trajopt device (default: cuda when available)")
    parser.add_argument("--time-limit", type=float, default=300.0, help="s per batch: the safety net")
    parser.add_argument("--config", action="append", default=[], metavar="NAME=VALUE",
                        help="a TrajoptConfig field for this run (repeatable), as bench_trajopt.py's")
    parser.add_argument("--json", default=None, metavar="PATH")
    args = parser.parse_args()
    if args.workers < 1 or args.batch < 1:
        parser.error("--workers and --batch take positive counts")
    from fetchbench_ms.planning.trajopt import default_device

    device = args.device or default_device()
    overrides = config_overrides(args.config)
    ids = parse_range(args.tasks, len(open_suite(args.suite)[0].tasks))
    bounds = np.linspace(0, len(ids), args.workers + 1).round().astype(int)
    slices = [f"{ids[a]}:{ids[b - 1] + 1}" for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    ctx = mp.get_context("spawn")
    with ctx.Manager() as manager, ctx.Pool(len(slices)) as pool:
        barrier = manager.Barrier(len(slices))
        parts = pool.map(_worker, [(args.suite, s, device, args.batch, args.time_limit, overrides, barrier)
                                   for s in slices])
    result = aggregate(parts)
    if result["problems"] == 0:
        sys.exit(f"no planning problems recorded from {args.suite} {args.tasks}: nothing was measured")
    print(f"{result['problems']} problems ({result['searched']} searched) by {result['workers']} processes on "
          f"{device}, batches of {args.batch}: {result['problems_per_s']:.1f} problems/s over {result['seconds']:.1f} s;"
          f" success {result['success']:.3f}; timed pass as the warm pass: {result['same_as_warm']}")
    if args.json:
        record = dict(throughput=result, parts=parts, run=dict(
            command=" ".join(["scripts/bench/bench_trajopt_throughput.py"] + sys.argv[1:]), suite=args.suite,
            tasks=args.tasks, device=device, batch=args.batch, config=overrides, counts=counts_of(overrides),
            torch=torch.__version__))
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
