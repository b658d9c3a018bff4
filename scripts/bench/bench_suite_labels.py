"""Per support label: how many objects the suite generator places there, and which filter
each of them fails first (stable / visible / reachable) or whether it passes.

For each scene type, the first scene of the recipe's plan of that type and its
arrangements 0..N-1 (``suite_build.sample_arrangement`` with the scene's whole quota as
the need, as the build's first arrangement), every placed object checked by all three
filters (``FilterEnv.check``, IK for every visible object). Same arguments, same numbers.

    nice python scripts/bench/bench_suite_labels.py --types RoundTable CellShelfDesk --arrangements 6
    nice python scripts/bench/bench_suite_labels.py --json out.json     # also write the counts
"""
from __future__ import annotations

import argparse
import json
import time
from collections import Counter

from fetchbench_ms.tasks import suite_build
from fetchbench_ms.utils.io import atomic_write_text, canonical_json

DEFAULT_TYPES = ("RoundTable", "CellShelfDesk", "DrawerShelf", "Drawer", "LayerShelf")
COLUMNS = ("placed", "stable", "visible", "reachable", "passed")


def label_counts(r: suite_build.SuiteRecipe, plan: suite_build.ScenePlan, arrangements: int, filter_env) -> dict:
    """label -> Counter(placed, and the first failing filter or 'passed') over the arrangements."""
    counts: dict = {}
    for k in range(arrangements):
        task = suite_build.sample_arrangement(r, plan, k)
        if task is None:  # nothing could be placed or no robot pose: no candidates
            continue
        check = filter_env.check(task, seed=suite_build._arrangement_seed(r, plan, k))
        for i, placement in enumerate(task.objects):
            c = counts.setdefault(placement.support_label, Counter())
            c["placed"] += 1
            c[check.rejection(i) or "passed"] += 1
    return counts


def format_table(by_type: dict) -> str:
    rows = [["scene type", "label", *COLUMNS]]
    total: dict = {}
    for scene_type, labels in by_type.items():
        for label in suite_build.CATEGORY_ORDER:
            if label in labels:
                rows.append([scene_type, label, *(labels[label].get(c, 0) for c in COLUMNS)])
                total.setdefault(label, Counter()).update(labels[label])
    for label in suite_build.CATEGORY_ORDER:
        if label in total:
            rows.append(["Total", label, *(total[label].get(c, 0) for c in COLUMNS)])
    widths = [max(len(str(row[j])) for row in rows) for j in range(len(rows[0]))]
    return "\n".join("  ".join(str(v).ljust(w) if j < 2 else str(v).rjust(w) for j, (v, w) in
                               enumerate(zip(row, widths))) for row in rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--suite", default="test", help=f"recipe: {', '.join(suite_build.RECIPES)}")
    p.add_argument("--types", nargs="+", default=list(DEFAULT_TYPES),
                   help=f"scene types; valid: {', '.join(suite_build.PAPER_TABLE)}")
    p.add_argument("--arrangements", type=int, default=6, help="arrangements per scene type")
    p.add_argument("--json", default=None, help="also write the counts to this file")
    args = p.parse_args(argv)
    r = suite_build.recipe(args.suite)
    unknown = sorted(set(args.types) - set(suite_build.PAPER_TABLE))
    if unknown:
        raise SystemExit(f"unknown scene types {unknown}; valid: {', '.join(suite_build.PAPER_TABLE)}")
    plans = suite_build.plan_scenes(r)
    from fetchbench_ms.tasks.filters import FilterEnv

    filter_env = FilterEnv(num_objects=r.num_objects)
    by_type, start = {}, time.perf_counter()
    for scene_type in args.types:
        plan = next(pl for pl in plans if pl.scene_type == scene_type)
        t0 = time.perf_counter()
        by_type[scene_type] = label_counts(r, plan, args.arrangements, filter_env)
        print(f"# {scene_type} (scene {plan.index}, quota {plan.quota}): {time.perf_counter() - t0:.0f} s", flush=True)
    filter_env.close()
    print(f"# {args.arrangements} arrangements per type, {time.perf_counter() - start:.0f} s in all")
    print(format_table(by_type))
    if args.json:
        atomic_write_text(args.json, canonical_json({t: {lab: dict(c) for lab, c in labels.items()}
                                                     for t, labels in by_type.items()}) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
