"""Metrics over task records: success by category and by scene type, failure classes,
the phase funnel, computation time and C-space length.

A task that errored (crash, timeout, exception) counts as a failed task of the method:
its rate is in every table (column ``errors``) so a broken run cannot look like a good one.
``timeout`` (failure class) is a task or a plan stopped by a wall-clock safety net (the
budgets are counts; a timeout says the machine was too slow): counted apart (``timeouts``).
Medians of computation time and C-space length are over tasks that ran (no error); the
tables (``format_table``, the report, ``results_table``) show the C-space length's median
over the successes (``median_cspace_length_successes``): a failure's path is cut short.

The funnel is the paper's (approach plan, approach execution, retrieval plan, final) plus
the stages between; a stage no record of the group has (an imitation method plans
nothing) is None, not 0: "not a stage of this method", not "never passed".
"""
from __future__ import annotations

import math
import statistics

CATEGORIES = ("on_table", "on_shelf", "in_drawer", "in_basket")  # the paper's column order
# FetchBench's pipeline stages in order; the last is the env's verdict.
FUNNEL = (("ik_found", "IK"), ("pregrasp_plan", "approach plan"), ("approach_reached", "approach execution"),
          ("grasped", "grasp"), ("retrieval_plan", "retrieval plan"), ("retrieved", "retrieved (policy)"),
          ("success", "final"))
FAILURE_ORDER = ("no_grasp_candidate", "motion_planning_failure", "grasp_failure", "retrieval_failure", "collision",
                 "timeout", "not_attempted", "error")


def _median(values) -> float | None:
    values = [v for v in values if v is not None]
    return round(statistics.median(values), 3) if values else None


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float] | None:
    """95% Wilson score interval of a success rate (sound at 0 and n, unlike the normal one)."""
    if n == 0:
        return None
    p = successes / n
    centre = p + z * z / (2 * n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return round((centre - half) / (1 + z * z / n), 4), round((centre + half) / (1 + z * z / n), 4)


def failure_classes(records: list[dict]) -> list[str]:
    seen = {r["failure"] for r in records if r.get("failure")}
    return [f for f in FAILURE_ORDER if f in seen] + sorted(seen - set(FAILURE_ORDER))


def group_stats(records: list[dict]) -> dict:
    n = len(records)
    ran = [r for r in records if not r.get("error")]
    successes = sum(bool(r["success"]) for r in records)
    # With --retries N a task that succeeded on its first try is what a single-try run gives
    # (the first try draws the same random numbers; only a planner's time limit can cut a plan
    # differently), so one x5 run has both figures.
    first_try = sum(bool(r["success"]) and (r.get("attempts") or 1) == 1 for r in records)
    return {
        "tasks": n,
        "successes": successes,
        "success_rate": round(successes / n, 4) if n else None,
        "success_ci95": wilson_interval(successes, n),
        "first_try_success_rate": round(first_try / n, 4) if n else None,
        "errors": n - len(ran),
        "timeouts": sum(r.get("failure") == "timeout" for r in records),
        "median_computation_time": _median(r.get("computation_time") for r in ran),
        "median_cspace_length": _median(r.get("cspace_length") for r in ran),
        "median_cspace_length_successes": _median(r.get("cspace_length") for r in ran if r["success"]),
        "funnel": {key: round(sum(bool(_stage(r, key)) for r in records) / n, 4) if n and _has_stage(records, key)
                   else None for key, _ in FUNNEL},
        "failures": {f: sum(r.get("failure") == f for r in records) for f in failure_classes(records)},
    }


def _has_stage(records: list[dict], key: str) -> bool:
    """Whether the method has this stage: some record that ran carries it."""
    return key == "success" or any(key in (r.get("phases") or {}) for r in records)


def _stage(record: dict, key: str) -> bool:
    return bool(record["success"]) if key == "success" else bool((record.get("phases") or {}).get(key))


def grouped(records: list[dict], field: str) -> dict[str, list[dict]]:
    groups: dict[str, list[dict]] = {}
    for r in records:
        groups.setdefault(r.get(field) or "unknown", []).append(r)
    order = list(CATEGORIES) if field == "category" else sorted(groups)
    return {k: groups[k] for k in order + sorted(set(groups) - set(order)) if k in groups}


def summarize(records: list[dict]) -> dict:
    """``{"all": stats, "by_category": {...}, "by_scene_type": {...}}``; ``{}`` when empty."""
    if not records:
        return {}
    return {
        "all": group_stats(records),
        "by_category": {k: group_stats(v) for k, v in grouped(records, "category").items()},
        "by_scene_type": {k: group_stats(v) for k, v in grouped(records, "scene_type").items()},
    }


def format_table(summary: dict, by: str = "by_category", timing: bool = True) -> str:
    """A plain-text table of one grouping plus the overall row. ``timing=False`` leaves out the
    computation time (the machine's): what is left is the same on every machine."""
    if not summary:
        return "no task ran"
    label = "category" if by == "by_category" else "scene type"
    time_header = f"{'med time s':>11}" if timing else ""
    header = f"{label:<22}{'tasks':>6}{'success':>9}{'errors':>7}{time_header}{'med C-len (succ)':>17}  failures"
    lines = [header, "-" * len(header)]
    rows = list(summary[by].items()) + [("all", summary["all"])]
    for name, s in rows:
        failures = ", ".join(f"{k} {v}" for k, v in s["failures"].items() if v) or "-"
        t = "-" if s["median_computation_time"] is None else f"{s['median_computation_time']:.2f}"
        t = f"{t:>11}" if timing else ""
        c = s["median_cspace_length_successes"]
        c = "-" if c is None else f"{c:.2f}"
        lines.append(f"{name:<22}{s['tasks']:>6}{s['success_rate']:>9.1%}{s['errors']:>7}{t}{c:>17}  {failures}")
    return "\n".join(lines)
