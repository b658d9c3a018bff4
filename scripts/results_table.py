"""A Markdown table of finished evaluation runs, the layout of docs/results.md.

    python scripts/results_table.py runs/cgn-ptd-rrt-pretrained-600 runs/ga-ptd-trajopt-x5-600 ...
    tar xzf results/h100-2026-11-23-runs.tar.gz -C /tmp && python scripts/results_table.py /tmp/runs/*

One row per results directory (`fetchbench eval --out DIR`): the method and its options
(grasp model, tries), tasks, success with its 95% Wilson interval, the first-try success
(with `--retries N` the same as a single-try run: the first try draws the same random
numbers), success by target category (tasks in brackets), median computation time, median
executed C-space length of the successes, and the failure classes. Reads records only.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from fetchbench_ms.evaluation import ResultsStore
from fetchbench_ms.evaluation.metrics import CATEGORIES, summarize

HEADER = ("| method | tasks | success (95% CI) | first try | " + " | ".join(CATEGORIES)
          + " | median computation time | median C-space length (successes) | failures |")


def method_label(manifest: dict) -> str:
    options = manifest.get("method_options") or {}
    label = f"`{manifest['method']}`"
    if options.get("grasp_model") and manifest["method"].startswith("cgn-"):
        label += f" {options['grasp_model']}"
    if (options.get("retries") or 1) > 1:
        label += f" x{options['retries']}"
    return label


def _value(v: float | None, unit: str) -> str:
    return "-" if v is None else f"{v:.2f} {unit}"


def row(run_dir: Path) -> str:
    store = ResultsStore(run_dir)
    if not store.manifest_path.exists():
        raise SystemExit(f"{run_dir} is not a results directory (no {store.manifest_path.name})")
    s = summarize(store.records())
    if not s:
        raise SystemExit(f"{run_dir} holds no finished task")
    a = s["all"]
    lo, hi = a["success_ci95"]
    cats = [f"{c['success_rate']:.3f} ({c['tasks']})" if (c := s["by_category"].get(k)) else "-" for k in CATEGORIES]
    failures = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in a["failures"].items() if v) or "-"
    return (f"| {method_label(store.manifest())} | {a['tasks']} | **{a['success_rate']:.3f}** ({lo:.3f}-{hi:.3f}) | "
            f"{a['first_try_success_rate']:.3f} | " + " | ".join(cats)
            + f" | {_value(a['median_computation_time'], 's')} | {_value(a['median_cspace_length_successes'], 'rad')} | {failures} |")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="results directories")
    args = parser.parse_args(argv)
    print(HEADER)
    print("|" + " --- |" * HEADER.count(" | ") + " --- |")
    for run_dir in args.runs:
        print(row(run_dir))


if __name__ == "__main__":
    main()
