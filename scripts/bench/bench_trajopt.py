"""RRTConnect vs the torch trajectory optimiser on the planning problems of suite tasks.

Problems are recorded from the ``ga-mesh-rrt`` (or ``--world pointcloud``: ``ga-ptd-rrt``)
pipeline itself: each task of the selection is reset, the pipeline runs up to its first
plan call (the pre-grasp problem: start, IK goal set, world, checker) and stops; with
``--full`` the episode runs on (with RRTConnect) and its retrieval problems are recorded
too. Then every problem is planned by

- RRTConnect (``plan_rrtconnect``, the pipelines' settings),
- trajopt one problem at a time (``plan_trajopt``),
- trajopt in batches of ``--batch`` problems (``plan_trajopt_batch``): time per problem
  is the batch's time over its size,

and the table gives success, plan time (median, p95), C-space length (L1 over the 7
joints, on problems both planners solved), the fraction of returned paths valid under a
finer re-check (0.005 rad), and how many trajopt plans needed the RRT fallback. With
``--phases`` (``TrajoptConfig.phase_times``) a second table gives the trajopt planners'
median wall seconds per phase of a plan on the searched problems: per problem one at a time,
per batch batched.

Usage (val tasks: the test suite is for the final figures):
  python scripts/bench/bench_trajopt.py --suite val --tasks 0:20 [--device cpu|cuda] [--batch 16] [--full]
  python scripts/bench/bench_trajopt.py --suite test --tasks 0:500 --full --workers 14   # >= 1,000 problems
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch


class _Recorded(Exception):
    pass


def record_problems(suite: str, tasks: str, world: str, full: bool) -> list[dict]:
    from fetchbench_ms.evaluation.methods import TaskRunner, resolve_run
    from fetchbench_ms.evaluation.runner import open_suite, parse_range, suite_items
    from fetchbench_ms.solutions import sense_plan_act as spa

    method = "ga-mesh-rrt" if world == "mesh" else "ga-ptd-rrt"
    suite_obj, _, _ = open_suite(suite)
    items = suite_items(suite_obj, parse_range(tasks, len(suite_obj.tasks)))
    runner = TaskRunner(resolve_run(method))
    problems, original = [], spa._plan_and_move

    def recorder(state, ex, rng, checker, q_start, q_goals, *args):
        kind = "pre-grasp" if not any(p["task"] == item.task_id for p in problems) else "retrieval/home"
        problems.append(dict(task=item.task_id, kind=kind, checker=checker, q_start=np.array(q_start, float),
                             q_goals=np.array(q_goals, float).reshape(-1, 7),
                             start_tolerance=state.config.start_escape_depth))
        if not full:
            raise _Recorded
        return original(state, ex, rng, checker, q_start, q_goals, *args)

    spa._plan_and_move = recorder
    try:
        for item in items:
            env = runner.env(item.env_id)
            env.reset(seed=item.seed, options={"task": item.task})
            try:
                spa.solve(env, seed=item.seed, method=method, reset=False)
            except _Recorded:
                pass
    finally:
        spa._plan_and_move = original
        runner.close()
    return problems


def cspace_length(path) -> float:
    return float(np.abs(np.diff(path, axis=0)).sum()) if path is not None else float("nan")


def is_searched(rrt_result) -> bool:
    """A problem the straight segment did not solve (nor started in collision): the ones the
    searched medians, ``--profile`` and ``--kernel-profile`` are over."""
    return rrt_result.status not in ("direct", "start_invalid")


def run_planners(problems: list[dict], device: str, batch: int, time_limit: float, profile=None,
                 overrides: dict | None = None) -> dict:
    """Every problem by each planner; ``profile`` (a ``cProfile.Profile``) records the one-at-a-time
    trajopt plans of the problems the straight segment does not solve; ``overrides``: ``TrajoptConfig``
    fields."""
    from fetchbench_ms.planning.rrt import densify, plan_rrtconnect
    from fetchbench_ms.planning.trajopt import TrajoptConfig, plan_trajopt, plan_trajopt_batch

    cfg = TrajoptConfig.for_device(device, **(overrides or {}))
    args = [(p["checker"], p["q_start"], p["q_goals"]) for p in problems]
    plan_trajopt(*args[0], time_limit=time_limit, config=cfg)  # warm-up (CUDA context, caches)
    rows = {"rrtconnect": [], "trajopt": [], f"trajopt batch {batch}": []}
    def timed(fn, *a, **kw):
        """The result, with ``cpu_time``: this process's CPU seconds (the machine may be shared)."""
        t = time.process_time()
        result = fn(*a, **kw)
        result.cpu_time = time.process_time() - t
        return result

    for p, a in zip(problems, args):
        rows["rrtconnect"].append(timed(plan_rrtconnect, *a, time_limit, start_tolerance=p["start_tolerance"]))
        if profile is not None and is_searched(rows["rrtconnect"][-1]):
            profile.enable()
        rows["trajopt"].append(timed(plan_trajopt, *a, time_limit, start_tolerance=p["start_tolerance"], config=cfg))
        if profile is not None:
            profile.disable()
    for i in range(0, len(args), batch):
        chunk = problems[i: i + batch]
        t, t_cpu = time.perf_counter(), time.process_time()
        results = plan_trajopt_batch(args[i: i + batch], time_limit, cfg,
                                     start_tolerance=chunk[0]["start_tolerance"])
        per, per_cpu = (time.perf_counter() - t) / len(chunk), (time.process_time() - t_cpu) / len(chunk)
        for r in results:
            r.planning_time, r.cpu_time = per, per_cpu
        # One record per batch, on its first result: the rows of --workers' slices join in order.
        results[0].extras["batch_phase_s"] = phase_record(results)
        rows[f"trajopt batch {batch}"] += results
    recheck = {}
    for name, results in rows.items():
        ok = [bool(p["checker"].valid(densify(r.path, 0.005)).all()) if r.success and not r.start_escaped else
              None for p, r in zip(problems, results)]
        recheck[name] = ok
    return rows, recheck


def _bench_slice(job: tuple) -> tuple:
    """One worker's share (``--workers``): record and plan the problems of a task slice;
    the checkers stay here (they hold the worlds), the rows travel back."""
    suite, tasks, world, full, device, batch, time_limit, threads, overrides = job
    torch.set_num_threads(threads)
    problems = record_problems(suite, tasks, world, full)
    if not problems:
        return [], {}, {}
    rows, recheck = run_planners(problems, device, batch, time_limit, overrides=overrides)
    return [{k: v for k, v in p.items() if k != "checker"} for p in problems], rows, recheck


def bench_parallel(args, device: str) -> tuple:
    """Split the task range into ``args.workers`` contiguous slices, one process each
    (``spawn``: CUDA and the simulator do not survive a fork), and join their rows in task
    order. Success, C-space length and validity do not depend on the split; times do (the
    processes share the cores and the GPU), so timings come from a run with one worker."""
    import multiprocessing as mp

    from fetchbench_ms.evaluation.runner import open_suite, parse_range

    ids = parse_range(args.tasks, len(open_suite(args.suite)[0].tasks))
    bounds = np.linspace(0, len(ids), args.workers + 1).round().astype(int)
    jobs = [(args.suite, f"{ids[a]}:{ids[b - 1] + 1}", args.world, args.full, device, args.batch, args.time_limit,
             args.threads, trajopt_overrides(args)) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
    problems, rows, recheck = [], {}, {}
    with mp.get_context("spawn").Pool(len(jobs)) as pool:
        for part_problems, part_rows, part_recheck in pool.imap(_bench_slice, jobs):
            problems += part_problems
            for name in part_rows:
                rows.setdefault(name, []).extend(part_rows[name])
                recheck.setdefault(name, []).extend(part_recheck[name])
    return problems, rows, recheck


def print_table(problems, rows, recheck, device) -> None:
    rrt = rows["rrtconnect"]
    print(f"{len(problems)} problems ({sum(p['kind'] == 'pre-grasp' for p in problems)} pre-grasp) from "
          f"{len({p['task'] for p in problems})} tasks; trajopt on {device} "
          f"(torch {torch.__version__}, {torch.get_num_threads()} threads)")
    head = (f"{'planner':<20} {'success':>8} {'direct':>7} {'time med s':>10} {'time p95 s':>10} "
            f"{'searched med s':>14} {'(CPU s)':>7} {'C-len med':>9} {'C-len/RRT':>9} {'valid':>6} {'fallback':>8}")
    print(head)
    print("-" * len(head))
    for name, results in rows.items():
        both = [(r, q) for r, q in zip(results, rrt) if r.success and q.success]
        times = [r.planning_time for r in results]
        ratio = (statistics.median([cspace_length(r.path) / max(cspace_length(q.path), 1e-9) for r, q in both
                                    if q.status != "direct" or r.status != "direct"] or [float("nan")]))
        ok = [v for v in recheck[name] if v is not None]
        print(f"{name:<20} {sum(r.success for r in results) / len(results):>8.3f} "
              f"{sum(r.status == 'direct' for r in results):>7d} {statistics.median(times):>10.3f} "
              f"{np.percentile(times, 95):>10.3f} "
              f"{statistics.median([t for t, r in zip(times, results) if r.status != 'direct'] or [np.nan]):>14.3f} "
              f"{statistics.median([r.cpu_time for r in results if r.status != 'direct'] or [np.nan]):>7.3f} "
              f"{statistics.median([cspace_length(r.path) for r, _ in both] or [float('nan')]):>9.2f} "
              f"{ratio:>9.2f} {sum(ok) / max(len(ok), 1):>6.3f} "
              f"{sum(r.planner == 'trajopt+rrtconnect' for r in results):>8d}")
    for name, results in rows.items():
        if name.startswith("trajopt batch"):
            searched = [r for r in results if r.status != "direct"]
            print(f"{name}: {len(results) / sum(r.planning_time for r in results):.1f} problems/s over all problems "
                  f"(batch wall time; {len(searched)} of them needed the optimiser)")
    statuses = {name: dict(sorted({r.status: sum(x.status == r.status for x in rs) for r in rs}.items()))
                for name, rs in rows.items()}
    print(f"statuses: {statuses}")
    print("searched: problems the straight segment did not solve (wall s, and this process's CPU s); "
          "C-len/RRT: median ratio of C-space lengths on problems both solved, leaving out those both solved "
          "by the straight segment; batch times are the batch's time over its problems")


def phase_record(results) -> dict | None:
    """Wall seconds per trajopt phase (``trajopt.PHASES``, ``phase_times``) of ``results``'
    searched problems (not ``direct``), a phase they did not go through 0: of one problem, or
    of a batch (its shared phases once, its problems' own summed); None when none was timed."""
    from fetchbench_ms.planning.trajopt import BATCH_PHASES, PHASES

    timed = [r.extras["phase_s"] for r in results if r.status != "direct" and "phase_s" in r.extras]
    if not timed:
        return None
    shared = next((p for p in timed if "batch_size" in p), {})
    return {k: shared.get(k, 0.0) if k in BATCH_PHASES else sum(p.get(k, 0.0) for p in timed) for k in PHASES}


def phase_medians(name: str, results) -> tuple[dict, int] | None:
    """The median of each phase and of their sum (``phases_sum``) over a trajopt planner's
    records: per searched problem one at a time, per batch batched; and the records' count."""
    if name.startswith("trajopt batch"):
        records = [r.extras["batch_phase_s"] for r in results if r.extras.get("batch_phase_s")]
    else:
        records = [rec for r in results if (rec := phase_record([r])) is not None]
    if not records:
        return None
    medians = {k: statistics.median(rec[k] for rec in records) for k in records[0]}
    medians["phases_sum"] = statistics.median(sum(rec.values()) for rec in records)
    return medians, len(records)


def print_phases(rows: dict) -> None:
    """The median wall seconds per phase of each timed trajopt planner (``--phases``)."""
    medians = {name: m for name, results in rows.items() if (m := phase_medians(name, results)) is not None}
    if not medians:
        return
    keys = list(next(iter(medians.values()))[0])
    print("trajopt phases, median wall s over the searched problems (one at a time: per problem; "
          "batched: per batch, its shared phases once and its problems' own summed; a phase not run is 0)")
    print(f"{'planner':<20} {'n':>4} " + " ".join(f"{k:>{max(len(k), 6)}}" for k in keys))
    for name, (m, n) in medians.items():
        print(f"{name:<20} {n:>4} " + " ".join(f"{m[k]:>{max(len(k), 6)}.3f}" for k in keys))


def summary(rows: dict, recheck: dict) -> dict:
    """Per planner (``rrtconnect``, ``trajopt``, ``trajopt_batch``): success, median and p95
    plan time, the median over problems the straight segment did not solve, C-space length
    (median of the successes) and validity at the finer check; with ``--phases``, the trajopt
    planners' median seconds per phase (``phase_median_s``)."""
    out = {}
    for name, results in rows.items():
        key = "trajopt_batch" if name.startswith("trajopt batch") else name
        times = [r.planning_time for r in results]
        searched = [r for r in results if r.status != "direct"]
        ok = [v for v in recheck[name] if v is not None]
        out[key] = dict(
            problems=len(results), success=sum(r.success for r in results) / len(results),
            median_s=statistics.median(times), p95_s=float(np.percentile(times, 95)),
            searched=len(searched),
            searched_median_s=statistics.median([r.planning_time for r in searched]) if searched else None,
            searched_median_cpu_s=statistics.median([r.cpu_time for r in searched]) if searched else None,
            cspace_length_median=statistics.median([cspace_length(r.path) for r in results if r.success] or [np.nan]),
            valid_fine=sum(ok) / max(len(ok), 1), fallback=sum(r.planner == "trajopt+rrtconnect" for r in results))
        phases = phase_medians(name, results)
        if phases is not None:  # --phases: per searched problem one at a time, per batch batched
            out[key]["phase_median_s"] = phases[0]
    return out


def counts_of(overrides: dict) -> str:
    """The optimiser's counts a run planned with, ``SEEDSxITERSxSUBSTEPS`` (as the planner
    option ``trajopt_counts`` spells them): a record says them even when its flags set none."""
    from fetchbench_ms.planning import trajopt

    return trajopt.counts_of(trajopt.TrajoptConfig(**{k: v for k, v in overrides.items() if k in trajopt.COUNT_FIELDS}))


def config_overrides(items: list[str]) -> dict:
    """``--config NAME=VALUE`` items as ``TrajoptConfig`` fields (values parsed as Python literals)."""
    import ast
    from dataclasses import fields

    from fetchbench_ms.planning.trajopt import TrajoptConfig

    names = {f.name for f in fields(TrajoptConfig)}
    out = {}
    for item in items:
        name, _, value = item.partition("=")
        if name not in names:
            raise SystemExit(f"unknown TrajoptConfig field {name!r}; valid: {', '.join(sorted(names))}")
        if value.lower() in ("true", "false"):
            out[name] = value.lower() == "true"
            continue
        try:
            out[name] = ast.literal_eval(value)
        except (ValueError, SyntaxError):  # a bare word: a string (--config compile_backend=inductor)
            out[name] = value
    try:
        TrajoptConfig(**out)  # the config's own checks
    except (TypeError, ValueError) as err:
        raise SystemExit(f"bad --config: {err}") from None
    return out


def trajopt_overrides(args) -> dict:
    """The run's ``TrajoptConfig`` changes: ``--config`` items, and ``--phases``' timer."""
    return dict(config_overrides(args.config), **({"phase_times": True} if args.phases else {}))


def write_profile(profile, path: str, rows: dict) -> None:
    """The profile of the searched one-at-a-time trajopt plans as text: the command, the plans,
    then cProfile's 40 largest cumulative times
    (file names without their folders)."""
    import io
    import pstats
    import sys

    plans = [(r.status, round(r.cpu_time, 2)) for r, q in zip(rows["trajopt"], rows["rrtconnect"]) if is_searched(q)]
    text = io.StringIO()
    pstats.Stats(profile, stream=text).strip_dirs().sort_stats("cumulative").print_stats(40)
    with open(path, "w") as f:
        f.write(f"command: {' '.join(sys.argv)}\ntorch {torch.__version__}, {torch.get_num_threads()} threads; "
                f"{len(plans)} plans profiled (status, CPU s under the profiler): {plans}\n")
        f.write(text.getvalue())


def write_kernel_profile(problems: list[dict], rows: dict, device: str, overrides: dict, path: str) -> None:
    """The searched problems' one-at-a-time trajopt plans again (the same counts, so the same
    work), under ``torch.profiler``: per operator (on CUDA, per kernel too) the calls and the
    time, most device time first, as text. What a GPU spends its time on: the cProfile of
    ``--profile`` sees only the host, which waits."""
    import sys

    from torch.profiler import ProfilerActivity, profile

    from fetchbench_ms.planning.trajopt import TrajoptConfig, plan_trajopt

    cfg = TrajoptConfig.for_device(device, **overrides)
    cuda = torch.device(cfg.device).type == "cuda"
    problems = [p for p, q in zip(problems, rows["rrtconnect"]) if is_searched(q)]
    activities = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])
    t = time.perf_counter()
    with profile(activities=activities) as prof:
        for p in problems:
            plan_trajopt(p["checker"], p["q_start"], p["q_goals"], start_tolerance=p["start_tolerance"], config=cfg)
        if cuda:
            torch.cuda.synchronize()
    wall = time.perf_counter() - t
    events = prof.key_averages()
    sort = "self_device_time_total" if cuda else "self_cpu_time_total"
    ops = sum(e.count for e in events)
    head = (f"command: {' '.join(sys.argv)}\ntorch {torch.__version__} on {cfg.device}; {len(problems)} searched plans "
            f"one at a time under torch.profiler in {wall:.2f} s wall; {ops} profiled calls "
            f"({ops / max(1, len(problems)):.0f} a plan); sorted by {sort}\n")
    with open(path, "w") as f:
        f.write(head + events.table(sort_by=sort, row_limit=50, max_name_column_width=60) + "\n")
    print(f"kernel profile of {len(problems)} plans -> {path}")


def show_records(paths: list[str]) -> None:
    """Reprint the figures of ``--json`` records: per record and planner, success, median, p95 and
    searched median plan time, and the phase medians when the run had ``--phases``."""
    import json

    for path in paths:
        record = json.loads(Path(path).read_text())
        run = record["run"]
        # (records older than --config have no config: the default one)
        print(f"{path}: {run['suite']} {run['tasks']}, {run['problems']} problems on {run['device']}, batch "
              f"{run.get('batch')}, config {run.get('config') or 'default'}")
        for name in (n for n in ("rrtconnect", "trajopt", "trajopt_batch") if n in record):
            r = record[name]
            line = (f"  {name:<14} success {r['success']:.3f}  median {r['median_s']:.3f} s  p95 {r['p95_s']:.3f} s  "
                    f"searched median {r['searched_median_s']:.3f} s")
            phases = r.get("phase_median_s")
            if phases:
                line += "\n    phases: " + ", ".join(f"{k} {v:.3f}" for k, v in phases.items())
            print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--suite", default="val")
    parser.add_argument("--tasks", default="0:20")
    parser.add_argument("--world", choices=("mesh", "pointcloud"), default="mesh")
    parser.add_argument("--full", action="store_true", help="run whole episodes: retrieval problems too")
    parser.add_argument("--device", default=None, help="trajopt device (default: cuda when available)")
    parser.add_argument("--batch", type=int, default=16, help="problems per batched trajopt call")
    parser.add_argument("--time-limit", type=float, default=300.0,
                        help="s per problem: a safety net, as the pipelines' (the budgets are counts)")
    parser.add_argument("--verbose", action="store_true", help="a line per problem")
    parser.add_argument("--json", default=None, metavar="PATH",
                        help="write the figures: one object per planner (rrtconnect, trajopt, trajopt_batch), and run")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    parser.add_argument("--profile", default=None, metavar="PATH",
                        help="write where the one-at-a-time trajopt plans of the searched problems spend their "
                             "time (cProfile, cumulative; one worker)")
    parser.add_argument("--kernel-profile", default=None, metavar="PATH",
                        help="plan the searched problems once more under torch.profiler (CUDA kernels on a GPU) and "
                             "write its operator table, most device time first (one worker)")
    parser.add_argument("--config", action="append", default=[], metavar="NAME=VALUE",
                        help="a TrajoptConfig field for this run (repeatable), e.g. --config seeds=16; "
                             "--config cuda_graph=true: the fixed-shape loop replayed as a CUDA graph")
    parser.add_argument("--phases", action="store_true",
                        help="time each trajopt plan phase by phase (TrajoptConfig.phase_times; on CUDA a sync per "
                             "phase) and print the medians over the searched problems")
    parser.add_argument("--workers", type=int, default=1,
                        help="processes over contiguous task slices (success and lengths; take timings with 1)")
    parser.add_argument("--show", nargs="+", default=None, metavar="JSON",
                        help="reprint the figures of --json records and exit")
    args = parser.parse_args()
    if args.show:
        return show_records(args.show)
    if (args.profile or args.kernel_profile) and args.workers > 1:
        parser.error("--profile and --kernel-profile take one worker (--workers 1)")
    if args.suite == "test":
        print("note: the test suite is for final figures; planner tuning belongs on val")
    config_overrides(args.config)  # a bad --config is answered before any task is recorded
    torch.set_num_threads(args.threads)
    from fetchbench_ms.planning.trajopt import default_device

    device = args.device or default_device()
    t = time.perf_counter()
    if args.workers > 1:
        problems, rows, recheck = bench_parallel(args, device)
        print(f"recorded and planned {len(problems)} problems in {time.perf_counter() - t:.0f} s with "
              f"{args.workers} workers (times below are under that load)")
        if not problems:
            return
    else:
        problems = record_problems(args.suite, args.tasks, args.world, args.full)
        print(f"recorded {len(problems)} problems in {time.perf_counter() - t:.0f} s")
        if not problems:
            return
        profile = None
        if args.profile:
            import cProfile

            profile = cProfile.Profile()
        rows, recheck = run_planners(problems, device, args.batch, args.time_limit, profile, trajopt_overrides(args))
        if profile is not None:
            write_profile(profile, args.profile, rows)
        if args.kernel_profile:
            write_kernel_profile(problems, rows, device, trajopt_overrides(args), args.kernel_profile)
    if args.verbose:
        for i, p in enumerate(problems):
            print(f"{p['task']} {p['kind']:<15} goals {len(p['q_goals'])}: " + "; ".join(
                f"{name} {rs[i].status}/{rs[i].planner} {rs[i].planning_time:.2f}s len {cspace_length(rs[i].path):.2f}"
                for name, rs in rows.items()))
    print_table(problems, rows, recheck, device)
    print_phases(rows)
    from fetchbench_ms.planning import trajopt_graph

    # cuda_graph: how often a plan's Adam loop was new (captured on CUDA) or reused (one process only).
    graph_counts = dict(trajopt_graph._CACHE.counts) if trajopt_graph._CACHE is not None else None
    if graph_counts is not None:
        print(f"cuda_graph loops: {graph_counts}")
    if args.json:
        import json
        import sys

        with open(args.json, "w") as f:
            json.dump(dict(summary(rows, recheck), run=dict(
                command=" ".join(sys.argv), suite=args.suite, tasks=args.tasks, world=args.world, full=args.full,
                device=device, batch=args.batch, threads=torch.get_num_threads(), torch=torch.__version__,
                config=config_overrides(args.config), counts=counts_of(config_overrides(args.config)),
                graph_cache=graph_counts,
                problems=len(problems))), f, indent=1)


if __name__ == "__main__":
    main()
