"""Per-task agreement of the same evaluation on other machines and loads.

    python scripts/maint/repeatability.py                       # the shipped records, results/repeatability
    python scripts/maint/repeatability.py --root DIR --reference NAME[,NAME...]

``--root`` holds one folder per condition (e.g. ``dev-1worker``, ``dev-2workers-6busy``,
``node-8workers``), each with one packed run per method (``fetchbench results pack RUN
--name METHOD --runs-dir ROOT/CONDITION``). For every other condition and every method both
have and that share tasks (a ``smoke`` reference is compared with the other ``smoke``
conditions, a test-slice reference with the test-slice ones), the table gives the tasks they share and how many of them end the same: the same
outcome, the same outcome and failure class (the goal: >= 99 %), and the same outcome with
the same executed C-space length to 1e-4 rad (the same motion, not only the same verdict).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fetchbench_ms.evaluation import ResultsStore
from fetchbench_ms.evaluation.results_table import default_runs_dir

DEFAULT_ROOT = default_runs_dir().parent / "repeatability"


def _records(run_dir: Path) -> dict:
    return {r["task_id"]: r for r in ResultsStore(run_dir).records()}


def agreement(a: dict, b: dict) -> dict:
    common = sorted(set(a) & set(b))
    same = [t for t in common if a[t]["success"] == b[t]["success"]]
    same_kind = [t for t in same if a[t].get("failure") == b[t].get("failure")]
    # Among tasks of the same outcome, not only of the same failure class: a failure class
    # renamed between two versions of the code is no other motion.
    same_motion = [t for t in same
                   if abs((a[t].get("cspace_length") or 0) - (b[t].get("cspace_length") or 0)) < 1e-4]
    return {"tasks": len(common), "same_outcome": len(same), "same_kind": len(same_kind),
            "same_motion": len(same_motion), "differ": [t for t in common if t not in same_kind]}


def table(root: Path, reference: str) -> str:
    conditions = sorted(p.name for p in root.iterdir() if p.is_dir())
    if reference not in conditions:
        raise SystemExit(f"error: no condition {reference!r} in {root}; valid: {', '.join(conditions)}")
    lines = [f"reference: {reference}",
             "| condition | method | tasks | same outcome | same outcome and failure class | same motion | differ |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for condition in (c for c in conditions if c != reference):
        for method_dir in sorted((root / condition).iterdir()):
            ref_dir = root / reference / method_dir.name
            if not ref_dir.is_dir():
                continue
            g = agreement(_records(ref_dir), _records(method_dir))
            n = g["tasks"]
            if n == 0:
                continue  # other tasks (a smoke run against a test slice): nothing to compare
            lines.append(f"| {condition} | `{method_dir.name}` | {n} | {g['same_outcome']} | "
                         f"{g['same_kind']} ({100 * g['same_kind'] / max(n, 1):.0f} %) | {g['same_motion']} | "
                         f"{', '.join(g['differ']) or '-'} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", type=Path, default=DEFAULT_ROOT)
    ap.add_argument("--reference", default="dev-1worker,dev-1worker-test100,cpu2-1worker",
                    help="comma-separated reference conditions, one table each")
    args = ap.parse_args(argv)
    if not args.root.is_dir():
        print(f"error: {args.root} is not a folder of conditions", file=sys.stderr)
        return 2
    print("\n\n".join(table(args.root, ref.strip()) for ref in args.reference.split(",") if ref.strip()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
