"""`fetchbench suite ...`: the task suites (stats table, list, show one task)."""
from __future__ import annotations

import json
from collections import Counter

COLUMNS = (("on_table", "On-Table"), ("on_shelf", "On-Shelf"), ("in_drawer", "In-Drawer"), ("in_basket", "In-Basket"))


def suite_stats(suite) -> dict:
    """Per scene type: scenes, tasks, tasks per category (the paper's appendix table), totals,
    and the suite's completeness and filter rejections (from its ``info``)."""
    rows: dict[str, dict] = {}
    scenes: dict[str, set] = {}
    for task in suite.tasks.values():
        row = rows.setdefault(task.scene_type, {"scenes": 0, "tasks": 0, **{c: 0 for c, _ in COLUMNS}})
        row["tasks"] += 1
        row[task.target_label] += 1
        scenes.setdefault(task.scene_type, set()).add((task.scene_seed, task.scene_hash))
    for scene_type, row in rows.items():
        row["scenes"] = len(scenes[scene_type])
    total = Counter()
    for row in rows.values():
        total.update(row)
    info = suite.info
    planned = _planned_by_category(info)
    return {
        "name": suite.name,
        "planned_by_category": planned,
        "rows": dict(sorted(rows.items())),
        "total": {k: total[k] for k in ("scenes", "tasks", *(c for c, _ in COLUMNS))},
        "complete": info.get("complete"),
        "complete_scenes": info.get("complete_scenes"),
        "planned_scenes": info.get("planned_scenes"),
        "planned_tasks": info.get("planned_tasks"),
        "rejected_by_type": info.get("rejected_by_type", {}),
    }


MIX_TOLERANCE = 0.10  # the bar: every category total within 10% of the paper's


def _planned_by_category(info: dict) -> dict | None:
    """The paper's tasks per category at the recipe's size (for ``test``: the paper's
    totals; the build plan shifts some per-type quotas, ``suite_build.PLAN_SHIFTS``), or
    None for a suite without a recipe (a subset such as ``smoke``)."""
    if "recipe" not in info:
        return None
    from .suite_build import SuiteRecipe, plan_scenes

    planned = Counter()
    for plan in plan_scenes(SuiteRecipe(**info["recipe"]), shifts={}):
        planned.update(plan.quota)
    return {c: planned[c] for c, _ in COLUMNS}


def category_mix_misses(stats: dict) -> list[str]:
    """The categories whose task total is more than ``MIX_TOLERANCE`` off the paper's."""
    planned = stats.get("planned_by_category") or {}
    return [c for c, n in planned.items() if n and abs(stats["total"][c] - n) > MIX_TOLERANCE * n]


def _aligner(rows):
    """A row formatter for a text table: first column left-aligned, the rest right-aligned."""
    widths = [max(len(str(x)) for x in col) for col in zip(*rows)]

    def fmt(cells) -> str:
        return "  ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w) for i, (c, w) in enumerate(zip(cells, widths)))

    return fmt


def format_stats(stats: dict) -> str:
    header = ["", "# Scenes", "# Tasks", *(name for _, name in COLUMNS)]
    lines = [[t, r["scenes"], r["tasks"], *(r[c] for c, _ in COLUMNS)] for t, r in stats["rows"].items()]
    total = stats["total"]
    lines.append(["Total", total["scenes"], total["tasks"], *(total[c] for c, _ in COLUMNS)])
    fmt = _aligner([header, *lines])
    rule = "-" * len(fmt(header))
    out = [f"suite {stats['name']}", rule, fmt(header), rule, *map(fmt, lines[:-1]), rule, fmt(lines[-1]), rule]
    if stats["planned_scenes"] is not None:
        state = "complete" if stats["complete"] else "PARTIAL"
        out.append(f"{state}: {stats['complete_scenes']} of {stats['planned_scenes']} planned scenes generated "
                   f"({total['tasks']} of {stats['planned_tasks']} planned tasks)")
    if stats.get("planned_by_category"):
        names = dict(COLUMNS)
        parts = [f"{names[c]} {total[c]}/{n} ({100 * (total[c] - n) / n:+.0f}%)"
                 for c, n in stats["planned_by_category"].items() if n]
        misses = category_mix_misses(stats)
        verdict = (f"NOT MET, more than {MIX_TOLERANCE:.0%} off: {', '.join(names[c] for c in misses)}" if misses
                   else f"met (every category within {MIX_TOLERANCE:.0%})")
        out.append(f"category mix vs the paper's: {', '.join(parts)}: {verdict}")
    return "\n".join(out)


def format_rejections(stats: dict) -> str:
    """Share of candidate targets each filter rejected, by scene type (a candidate is every
    placed object of every arrangement tried; the first failing filter counts; stable,
    visible objects of a category whose quota was already full get no IK and are counted
    apart)."""
    header = ["", "candidates", "unstable", "not visible", "unreachable", "passed", "no IK (quota full)"]
    lines = []
    total = Counter()
    for scene_type, counts in stats["rejected_by_type"].items():
        total.update(counts)
        lines.append(_rejection_row(scene_type, counts))
    if not lines:
        return "(no filter statistics in this suite)"
    lines.append(_rejection_row("Total", total))
    fmt = _aligner([header, *lines])
    return "\n".join([fmt(header), *map(fmt, lines)])


def _rejection_row(name, counts) -> list:
    n = sum(v for k, v in counts.items() if k != "no_arrangement")
    share = lambda k: f"{100 * counts.get(k, 0) / n:.1f}%" if n else "-"  # noqa: E731
    return [name, n, share("stable"), share("visible"), share("reachable"), share("passed"), share("unchecked")]


def _stats(args) -> int:
    from .suite import load_suite

    stats = suite_stats(load_suite(args.suite))
    if args.json:
        print(json.dumps(stats, indent=1, sort_keys=True))
    else:
        print(format_stats(stats))
        if args.filters:
            print("\nfilter rejections (share of candidate targets, first failing filter):")
            print(format_rejections(stats))
    return 0


def _list(args) -> int:
    from .suite import load_suite, shipped_suites

    if args.suite is None:
        for name in shipped_suites():
            print(name, len(load_suite(name)), "tasks")
        return 0
    suite = load_suite(args.suite)
    for task_id in suite.ids()[: args.limit]:
        t = suite.get(task_id)
        print(task_id, t.scene_type, t.target_label, t.target.object_id)
    return 0


def _show(args) -> int:
    from .suite import load_suite

    suite_name = args.suite or args.task_id.split("/")[0]
    print(json.dumps(load_suite(suite_name).get(args.task_id).to_dict(), indent=1, sort_keys=True))
    return 0


def add_commands(subparsers) -> None:
    suite = subparsers.add_parser("suite", help="task suites: per-type/category table, list, show a task")
    sub = suite.add_subparsers(dest="suite_command", required=True, metavar="ACTION")
    s = sub.add_parser("stats", help="the paper's appendix table (scene types x categories) of a suite")
    s.add_argument("--suite", default="test", help="shipped suite name (test, val, smoke) or a suite file")
    s.add_argument("--json", action="store_true", help="print the table as JSON")
    s.add_argument("--filters", action="store_true", help="also print the filters' rejection shares by type")
    s.set_defaults(func=_stats)
    s = sub.add_parser("list", help="list shipped suites, or the tasks of one")
    s.add_argument("--suite", default=None)
    s.add_argument("--limit", type=int, default=None)
    s.set_defaults(func=_list)
    s = sub.add_parser("show", help="print one task as JSON")
    s.add_argument("task_id", help="e.g. test/0042")
    s.add_argument("--suite", default=None, help="default: the part of the id before '/'")
    s.set_defaults(func=_show)
