"""The trajectory optimiser's world grid (``TrajoptConfig.world_grid``,
``distance.baked_grid_values``): wall milliseconds to bake one world's grid, per chunk size
(``distance.BAKED_CHUNK``: grid vertices measured per call), on the recorded pre-grasp worlds
of suite tasks, with the device memory the bake peaks at. The values do not depend on the
chunk: the bench checks each world's grids are equal bit for bit and fails if not.

Usage (val tasks):
  python scripts/bench/bench_world_grid.py --suite val --tasks 0:20 --device cuda --chunks 19 20 21 22 [--json PATH]
  python scripts/bench/bench_world_grid.py --show results/planning/bench-world-grid-h200-val40.json
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch


def bake_ms(world, exclude, resolution: float, device: torch.device, chunk: int, max_planes: int | None
            ) -> tuple[float, torch.Tensor, int]:
    """One bake of ``world``'s grid with ``chunk`` vertices a call, uncached: (wall ms, values,
    peak device bytes above the start, 0 on a CPU)."""
    from fetchbench_ms.planning import distance

    world.__dict__.pop("_baked_grids", None)  # measure, do not read the cache
    saved = dict(distance.BAKED_CHUNK)
    distance.BAKED_CHUNK[device.type] = chunk
    cuda = device.type == "cuda"
    try:
        if cuda:
            torch.cuda.synchronize(device)
            torch.cuda.reset_peak_memory_stats(device)
            base = torch.cuda.memory_allocated(device)
        t0 = time.perf_counter()
        values = distance.baked_grid_values(world, exclude, resolution, device, max_planes=max_planes)
        if cuda:
            torch.cuda.synchronize(device)
        ms = 1000 * (time.perf_counter() - t0)
        peak = torch.cuda.max_memory_allocated(device) - base if cuda else 0
    finally:
        distance.BAKED_CHUNK.clear()
        distance.BAKED_CHUNK.update(saved)
        world.__dict__.pop("_baked_grids", None)
    return ms, values, peak


def print_table(record: dict) -> None:
    run = record["run"]
    print(f"{run['worlds']} worlds of {run['suite']} {run['tasks']} on {run['device']} (torch {run['torch']}), "
          f"median of {run['repeats']} bakes each; the same values at every chunk")
    print(f"{'chunk':>6} {'median ms':>10} {'max ms':>8} {'peak MB':>8}")
    for name, r in record["chunks"].items():
        print(f"{name:>6} {r['median_ms']:10.1f} {r['max_ms']:8.1f} {r['peak_mb']:8.0f}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--suite", default="val")
    parser.add_argument("--tasks", default="0:20")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--chunks", type=int, nargs="+", default=[19, 20, 21, 22], metavar="LOG2",
                        help="chunk sizes as powers of two (19: 524,288 vertices a call)")
    parser.add_argument("--repeats", type=int, default=3, help="bakes per world and chunk (the median counts)")
    parser.add_argument("--json", default=None, metavar="PATH")
    parser.add_argument("--show", default=None, metavar="JSON", help="print a record's table and exit")
    args = parser.parse_args(argv)
    if args.show:
        print_table(json.loads(Path(args.show).read_text()))
        return 0
    if any(not 10 <= c <= 26 for c in args.chunks) or args.repeats < 1:
        print("bench_world_grid: --chunks are powers of two from 10 to 26, --repeats >= 1", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    sys.path.insert(0, str(Path(__file__).parent))
    from bench_trajopt import record_problems
    from fetchbench_ms.planning.trajopt import LOOPS, TrajoptConfig

    device = torch.device(args.device)
    cfg = TrajoptConfig(**LOOPS["grid"])
    problems = record_problems(args.suite, args.tasks, "mesh", False)
    worlds = {id(p["checker"].world): p["checker"] for p in problems}.values()
    per_chunk = {c: {"ms": [], "peak_mb": []} for c in args.chunks}
    for checker in worlds:
        reference = None
        for c in args.chunks:
            runs = [bake_ms(checker.world, tuple(checker.exclude), cfg.world_grid, device, 1 << c, cfg.max_planes)
                    for _ in range(args.repeats)]
            per_chunk[c]["ms"].append(statistics.median(r[0] for r in runs))
            per_chunk[c]["peak_mb"].append(max(r[2] for r in runs) / 2**20)
            values = runs[0][1]
            if reference is None:
                reference = values
            elif not torch.equal(reference, values):
                print(f"bench_world_grid: chunk 2^{c} baked other values than 2^{args.chunks[0]}", file=sys.stderr)
                return 1
    rows = {f"2^{c}": dict(median_ms=statistics.median(r["ms"]), max_ms=max(r["ms"]),
                           peak_mb=max(r["peak_mb"])) for c, r in per_chunk.items()}
    record = dict(run=dict(command=" ".join(["scripts/bench/bench_world_grid.py", *sys.argv[1:]]),
                           suite=args.suite, tasks=args.tasks, device=str(device), torch=torch.__version__,
                           worlds=len(per_chunk[args.chunks[0]]["ms"]), repeats=args.repeats), chunks=rows)
    print_table(record)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
