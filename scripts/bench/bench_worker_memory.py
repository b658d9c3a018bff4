"""Memory of one evaluation worker over a run: RSS (and CUDA memory on a GPU) after each task.

Runs the tasks one after another in this process exactly as a worker of `fetchbench eval` does
(``evaluation.methods.TaskRunner``: one env kept across tasks, one torch thread), and prints
the first and last tasks' figures with the sizes of the caches a worker keeps across tasks
(``evaluation.worker_caches``):

    python scripts/bench/bench_worker_memory.py --method ga-mesh-trajopt --suite val --tasks 0:40 \\
        --json results/planning/worker-memory-cpu-val40.json

RSS is the process's resident memory (VmRSS); on a GPU, ``cuda_allocated_mb`` is what live
tensors hold and ``cuda_reserved_mb`` what torch's caching allocator holds from the device
(the renderer's memory is not in either: see nvidia-smi); ``cuda_graph_pools_mb`` is the part
of it in the private pools of captured CUDA graphs (``trajopt_loop=graph``), which emptying
the cache between tasks cannot return while a graph of the pool lives, and ``graph_loops``
the process's cached captured loops and their counts (``trajopt_graph.GraphCache``).

With ``--live-tensors N`` (CUDA only) torch records where every CUDA allocation was made, and
the end prints the N Python lines of this package that hold the most live CUDA memory (each
live block charged to the innermost ``fetchbench_ms`` frame of its allocation): what a
growing ``cuda_allocated_mb`` is made of.

``--show JSON ...`` reprints the figures of ``--json`` records:

    python scripts/bench/bench_worker_memory.py --show results/planning/worker-memory-*.json

``--planner-option`` is ``fetchbench eval``'s; ``--config FIELD=VALUE`` changes a
``TrajoptConfig`` field of the run's trajectory-optimiser loop (a diagnosis: such a run is
not one of the tables' settings), e.g. ``--planner-option trajopt_loop=graph --config
graph_cache=1``.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def cuda_mb() -> dict:
    import torch

    if not torch.cuda.is_initialized():
        return {}
    return {"cuda_allocated_mb": round(torch.cuda.memory_allocated() / 2**20, 1),
            "cuda_reserved_mb": round(torch.cuda.memory_reserved() / 2**20, 1)}


def graph_figures() -> dict:
    """The CUDA graphs' private pools' reserved memory and the cached loops' counts."""
    import torch

    out = {}
    if torch.cuda.is_initialized():
        private = sum(seg["total_size"] for seg in torch.cuda.memory_snapshot()
                      if tuple(seg.get("segment_pool_id", (0, 0))) != (0, 0))
        out["cuda_graph_pools_mb"] = round(private / 2**20, 1)
    from fetchbench_ms.planning import trajopt_graph

    if trajopt_graph._CACHE is not None:
        out["graph_loops"] = {"cached": len(trajopt_graph._CACHE.entries), **trajopt_graph._CACHE.counts}
    return out


def live_tensor_lines(top: int) -> list[str]:
    """The ``top`` lines of this package holding the most live CUDA memory now (torch's
    allocation history must be on), as "MB  blocks  file:line function"."""
    import collections

    import torch

    held, count = collections.Counter(), collections.Counter()
    for segment in torch.cuda.memory._snapshot()["segments"]:
        for block in segment["blocks"]:
            if block["state"] != "active_allocated":
                continue
            frames = block.get("frames") or []  # innermost first
            ours = [f for f in frames if "fetchbench_ms" in f["filename"]]
            where = (f"{ours[0]['filename'].split('fetchbench_ms/')[-1]}:{ours[0]['line']} {ours[0]['name']}"
                     if ours else "(no fetchbench_ms frame)")
            held[where] += block["size"]
            count[where] += 1
    return [f"{held[w] / 2**20:9.1f} MB {count[w]:6d}  {w}" for w, _ in held.most_common(top)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--method", default="ga-mesh-trajopt")
    parser.add_argument("--pipeline", choices=("paper", "ours"), default="paper")
    parser.add_argument("--suite", default="val", help="task suite: test, val, smoke, or a suite file")
    parser.add_argument("--tasks", default="0:40", help="START:END slice of the suite's tasks")
    parser.add_argument("--planner-option", action="append", default=[], metavar="KEY=VALUE",
                        help="as fetchbench eval's (e.g. trajopt_loop=graph)")
    parser.add_argument("--config", action="append", default=[], metavar="FIELD=VALUE",
                        help="a TrajoptConfig field of the run's trajopt loop (a diagnosis, not a table setting)")
    parser.add_argument("--live-tensors", type=int, default=0, metavar="N",
                        help="CUDA: record allocations and print the N lines holding the most live memory at the end")
    parser.add_argument("--json", default=None, metavar="PATH", help="write every task's figures here")
    parser.add_argument("--show", nargs="+", metavar="JSON", help="reprint the figures of --json records and exit")
    args = parser.parse_args()
    if args.show:
        sys.exit(show(args.show))

    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    from fetchbench_ms.evaluation.methods import TaskRunner, resolve_run
    from fetchbench_ms.evaluation.runner import open_suite, parse_range, suite_items
    from fetchbench_ms.evaluation.worker_caches import cache_sizes
    from fetchbench_ms.method_spec import IMPROVEMENTS
    from fetchbench_ms.planning import trajopt
    from fetchbench_ms.solutions.planner_options import parse_planner_options

    try:
        suite, _, _ = open_suite(args.suite)
        items = suite_items(suite, parse_range(args.tasks, len(suite.tasks)))
        options = parse_planner_options(args.planner_option)
        run = resolve_run(args.method, improvements=IMPROVEMENTS if args.pipeline == "ours" else (),
                          planner_options=options)
    except (ValueError, KeyError, FileNotFoundError) as error:  # the message names what is valid
        parser.error(str(error).strip("'\""))
    if args.config:
        from bench_trajopt import config_overrides

        loop = options.get("trajopt_loop") or "eager"
        trajopt.LOOPS[loop] = {**trajopt.LOOPS[loop], **config_overrides(args.config)}

    torch.set_num_threads(1)  # as a worker (evaluation.local)
    if args.live_tensors < 0:
        parser.error(f"--live-tensors: a number of lines >= 0, not {args.live_tensors}")
    if args.live_tensors and not torch.cuda.is_available():
        parser.error("--live-tensors needs a CUDA device (torch records CUDA allocations only)")
    if args.live_tensors:
        torch.cuda.memory._record_memory_history(enabled="all", context="alloc", stacks="python",
                                                 max_entries=100_000)
    runner = TaskRunner(run)
    rows = []
    start = time.perf_counter()
    try:
        for item in items:
            record = runner(item)
            rows.append({"task_id": item.task_id, "success": record["success"], "failure": record.get("failure"),
                         "wall_time": record["wall_time"], "rss_mb": round(rss_mb(), 1), **cuda_mb(), **graph_figures(),
                         "caches": {c.name: c.size for c in cache_sizes()}})
            print(f"{len(rows):4d} {item.task_id}  rss {rows[-1]['rss_mb']:7.1f} MB  "
                  + "".join(f"{k[:-3]} {v:.1f} MB  " for k, v in rows[-1].items() if k.startswith("cuda"))
                  + "".join(f"loops {v['cached']} ({v['new']} new, {v['evicted']} evicted)  "
                            for k, v in rows[-1].items() if k == "graph_loops")
                  + f"{record['wall_time']:.1f} s", flush=True)
    finally:
        runner.close()
    if not rows:
        sys.exit("no task ran")
    record = {"method": args.method, "pipeline": args.pipeline, "suite": args.suite, "tasks": args.tasks,
              "planner_options": options, "config": args.config,
              "device": run_device(), "torch_threads": torch.get_num_threads(),
              "seconds": round(time.perf_counter() - start, 1),
              "command": " ".join([os.path.basename(sys.executable)] + sys.argv),
              "cache_bounds": {c.name: c.bound for c in cache_sizes()}, "per_task": rows}
    print()
    print("\n".join(summary_lines(record)))
    if args.live_tensors:
        print("live CUDA memory by the line that allocated it:")
        print("\n".join(live_tensor_lines(args.live_tensors)))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(record, f, indent=1)
            f.write("\n")
        print(f"wrote {args.json}")


def summary_lines(record: dict) -> list[str]:
    """A run's figures (``--json``'s record) as printed at its end and by ``--show``: the
    first, last and largest RSS and CUDA figures over its tasks, the captured loops and the
    caches' sizes after the last task."""
    rows = record["per_task"]
    first, last = rows[0], rows[-1]
    took = f" in {record['seconds']:.0f} s" if "seconds" in record else ""
    options = "".join(f" {k}={v}" for k, v in (record.get("planner_options") or {}).items())
    options += "".join(f" --config {c}" for c in record.get("config") or ())
    lines = [f"{record['method']} ({record['pipeline']}{options}), {record['suite']} {record['tasks']}: "
             f"{len(rows)} tasks{took} on {record['device']}",
             f"RSS after the first task {first['rss_mb']:.0f} MB, after the last {last['rss_mb']:.0f} MB, "
             f"largest {max(r['rss_mb'] for r in rows):.0f} MB"]
    for key in ("cuda_allocated_mb", "cuda_reserved_mb", "cuda_graph_pools_mb"):
        if key in last:
            lines.append(f"{key}: first {first.get(key, 0.0):.1f}, last {last[key]:.1f}, "
                         f"largest {max(r.get(key, 0.0) for r in rows):.1f}")
    if "graph_loops" in last:
        lines.append("captured loops at the end: " + ", ".join(f"{k} {v}" for k, v in last["graph_loops"].items()))
    bounds = record.get("cache_bounds", {})
    lines.append("caches at the end (entries / bound): "
                 + ", ".join(f"{name} {size}/{bounds.get(name, '?')}" for name, size in last["caches"].items()))
    return lines


def show(paths: list[str]) -> int:
    """Reprint the figures of ``--json`` records."""
    for path in paths:
        try:
            with open(path) as f:
                record = json.load(f)
            lines = summary_lines(record)
        except (OSError, ValueError, KeyError, IndexError) as error:
            print(f"bench_worker_memory: {path}: not a record of --json ({error})", file=sys.stderr)
            return 1
        print(f"{path}:\n  " + "\n  ".join(lines))
    return 0


def run_device() -> str:
    from fetchbench_ms.planning.trajopt import default_device

    return f"trajopt on {default_device()}, {os.cpu_count()} CPU cores"


if __name__ == "__main__":
    main()
