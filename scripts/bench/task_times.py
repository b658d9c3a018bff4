"""Seconds a task per method and machine kind, from the shipped records (what a user of each
kind of machine should expect a task to take).

    python scripts/bench/task_times.py                      # the table in docs/evaluation.md
    python scripts/bench/task_times.py --set "my laptop=runs/ga-mesh-rrt" --set "node=results/runs/ga-mesh-rrt-paper-test600"

A record's ``wall_time`` is the task's time in its worker: env reset, the method, the
judging (start-up and the pool's waiting left out), so it is a per-core figure. Each set is
one machine kind: a label and results folders (one method each, raw or packed). The default
sets are the repeatability runs: a 2-core CPU machine (Mesa's lavapipe renders; CGN, trajopt
and MPPI on the CPU; one worker) and a 64-core machine with four GPUs (54-64 workers over
the 64 cores), on the same test tasks; only the tasks every set of a method has are counted.
"""
from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
REPEATABILITY = ROOT / "results" / "repeatability"
DEFAULT_SETS = (
    ("2-core CPU, 1 worker", REPEATABILITY / "dev-1worker-test100"),
    ("64 cores + 4 GPUs, 54-64 workers", REPEATABILITY / "node-test100"),
)


def parse_set(text: str) -> tuple[str, list[Path]]:
    label, sep, paths = text.partition("=")
    if not sep or not label or not paths:
        raise argparse.ArgumentTypeError(f"--set takes LABEL=FOLDER[,FOLDER...], got {text!r}")
    return label, [Path(p) for p in paths.split(",")]


def load(folder: Path) -> tuple[str, dict[str, float]]:
    """A results folder's method and its tasks' wall times."""
    from fetchbench_ms.evaluation.store import ResultsStore

    records = ResultsStore(folder).records()
    if not records:
        raise SystemExit(f"{folder}: no records (a results folder of `fetchbench eval --out`)")
    methods = {r["method"] for r in records}
    if len(methods) != 1:
        raise SystemExit(f"{folder}: records of several methods ({', '.join(sorted(methods))})")
    return methods.pop(), {r["task_id"]: float(r["wall_time"]) for r in records if r.get("wall_time") is not None}


def table(sets: list[tuple[str, list[Path]]]) -> str:
    """Markdown: per method, the median, 90th percentile and mean of the seconds a task per
    set (the mean: the worker-seconds a task, what a run's wall time scales with)."""
    times: dict[str, dict[str, dict[str, float]]] = {}
    for label, folders in sets:
        for folder in folders:
            method, walls = load(folder)
            times.setdefault(method, {})[label] = walls
    header = ["method", "tasks"] + [f"{label}: median / p90 / mean s" for label, _ in sets]
    lines = ["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)]
    for method in sorted(times):
        if len(times[method]) < len(sets):
            continue  # a method must be in every set to compare
        common = set.intersection(*(set(w) for w in times[method].values()))
        if not common:
            continue
        cells = []
        for label, _ in sets:
            values = sorted(times[method][label][t] for t in common)
            p90 = values[min(len(values) - 1, int(round(0.9 * (len(values) - 1))))]
            cells.append(f"{statistics.median(values):.1f} / {p90:.1f} / {statistics.fmean(values):.2f}")
        lines.append(f"| `{method}` | {len(common)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--set", dest="sets", action="append", type=parse_set, default=None, metavar="LABEL=FOLDERS",
                   help="a machine kind and its results folders, comma-separated (repeatable; default: the "
                        "repeatability runs)")
    args = p.parse_args(argv)
    sets = args.sets or [(label, sorted(d for d in folder.iterdir() if d.is_dir())) for label, folder in DEFAULT_SETS]
    missing = [str(f) for _, folders in sets for f in folders if not f.is_dir()]
    if missing:
        p.error(f"no such results folder: {', '.join(missing)}")
    out = table(sets)
    if out.count("\n") < 2:
        print("no method has records in every set: nothing to compare", file=sys.stderr)
        return 1
    print(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
