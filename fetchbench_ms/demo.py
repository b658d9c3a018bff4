"""``fetchbench demo``: the project's main job (``make demo``).

Evaluates the ``ga-mesh-rrt`` sense-plan-act baseline (annotated grasps, oracle meshes,
RRTConnect) on the ``smoke`` task suite on CPU, one worker process per core, prints the
success table by category and writes the HTML report. It is ``fetchbench eval`` plus
``fetchbench report``: results go to ``OUT/results`` (re-running resumes, so a second run
only rebuilds the report) and the report to ``OUT/report/index.html``. Results of an
earlier run that no longer match (an updated suite or method) are moved aside to
``OUT/results.previous-N``, not deleted, and the demo starts afresh.
"""
from __future__ import annotations

import os
import time
from pathlib import Path


def default_workers() -> int:
    """One per core this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def run_demo(out_dir, method: str = "ga-mesh-rrt", suite: str = "smoke", tasks: str | None = None,
             workers: int | None = None, render: bool = True) -> int:
    from .evaluation import evaluate, format_table, summarize
    from .evaluation.report import build_report

    out_dir = Path(out_dir)
    workers = workers or default_workers()
    start = time.perf_counter()
    print(f"FetchBench-MS demo: {method} (the paper's pipeline) on the {suite!r} suite, {workers} worker(s) "
          f"-> {out_dir}/")
    from .evaluation.store import RunMismatchError

    try:
        records = evaluate(method, out_dir / "results", suite=suite, tasks=tasks, workers=workers)
    except RunMismatchError as error:
        kept = _set_aside(out_dir / "results")
        print(f"{error}\nthe demo keeps that run in {kept} and starts afresh")
        records = evaluate(method, out_dir / "results", suite=suite, tasks=tasks, workers=workers)
    summary = summarize(records)
    print()
    # Outcomes only: budgets are counts, so these tables are the same on every machine.
    print(format_table(summary, "by_category", timing=False))
    print()
    print(format_table(summary, "by_scene_type", timing=False))
    if summary:
        print(f"\nmedian computation time on this machine: {summary['all']['median_computation_time']} s")
    errors = [r for r in records if r.get("error")]
    for r in errors:
        print(f"{r['task_id']}: {r['error']['kind']}: {r['error']['message']}")
    page = build_report([out_dir / "results"], out_dir / "report", render=render)
    print()
    print(f"results: {out_dir / 'results' / 'results.jsonl'}")
    print(f"report:  {page}")
    print(f"done in {time.perf_counter() - start:.0f} s")
    return 0


def _set_aside(results_dir: Path) -> Path:
    """Rename ``results_dir`` to the first free ``results.previous-N`` beside it."""
    n = 1
    while (target := results_dir.with_name(f"{results_dir.name}.previous-{n}")).exists():
        n += 1
    results_dir.rename(target)
    return target


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("demo", help="the main job: evaluate ga-mesh-rrt on the smoke suite, report (make demo)")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--method", default="ga-mesh-rrt", help="method to evaluate (see fetchbench eval --help)")
    p.add_argument("--suite", default="smoke", help="task suite (default smoke)")
    p.add_argument("--tasks", default=None, help="START:END slice of the suite")
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: one per core)")
    p.add_argument("--no-render", action="store_true", help="report without start images")
    p.set_defaults(func=lambda a: run_demo(a.out, a.method, a.suite, a.tasks, a.workers, not a.no_render))
