"""Run a sense-plan-act baseline over many episodes: one JSON line per episode, appended
as it finishes (resumable: seeds already in the file are skipped), and a summary by
target category."""
from __future__ import annotations

import json
import statistics
from pathlib import Path

from ..utils.io import append_jsonl_atomic, atomic_write_text, canonical_json
from .sense_plan_act import FAILURE_CLASSES, METHODS, PHASES, solve

RESULTS_FILE = "episodes.jsonl"
SUMMARY_FILE = "summary.json"


def make_env(method: str, env_id: str):
    from ..envs import make

    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; valid: {', '.join(METHODS)}")
    obs_mode = "pointcloud" if METHODS[method]["world"] == "pointcloud" else "none"
    return make(env_id, obs_mode=obs_mode, control_mode="pd_joint_pos")


def read_results(path: Path) -> list[dict]:
    if not path.exists():
        return []
    records = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip():
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError as error:
                raise ValueError(f"{path}:{n} is not a JSON line ({error}); remove it to resume") from error
    return records


def run_episodes(method: str, env_id: str, episodes: int, seed: int, out_dir: str | None, retries: int = 1,
                 progress: bool = True, reachable_only: bool = False) -> list[dict]:
    """Episodes with seeds ``seed .. seed + episodes - 1``; returns every record (old and new).

    A seed whose task cannot be built (the env's reset raises) or, with
    ``reachable_only``, fails FetchBench's reachability filter is recorded with a
    ``skipped`` reason and left out of the summary.
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    path = Path(out_dir) / RESULTS_FILE if out_dir else None
    done = {}
    if path is not None:
        for r in read_results(path):
            if (r.get("method"), r.get("env_id"), r.get("retries"), r.get("reachable_only", False)) == \
                    (method, env_id, retries, reachable_only):
                done[r["seed"]] = r
    seeds = [s for s in range(seed, seed + episodes) if s not in done]
    env = make_env(method, env_id) if seeds else None
    from tqdm import tqdm

    records = [done[s] for s in range(seed, seed + episodes) if s in done]
    bar = tqdm(total=episodes, initial=len(records), disable=not progress, desc=method, unit="ep")
    for s in seeds:
        record = _episode(env, s, method, retries, reachable_only)
        record.update(env_id=env_id, retries=retries, reachable_only=reachable_only)
        if path is not None:
            append_jsonl_atomic(path, record)
        records.append(record)
        bar.update(1)
        run = [r for r in records if "skipped" not in r]
        bar.set_postfix(success=f"{sum(r['success'] for r in run)}/{len(run)}")
    bar.close()
    if env is not None:
        env.close()
    records.sort(key=lambda r: r["seed"])
    if out_dir:
        atomic_write_text(Path(out_dir) / SUMMARY_FILE, canonical_json(summarize(records)))
    return records


def _episode(env, seed: int, method: str, retries: int, reachable_only: bool) -> dict:
    try:
        env.reset(seed=seed)
    except (ValueError, KeyError, RuntimeError) as error:  # a task the sampler cannot build
        return {"seed": seed, "method": method, "skipped": f"reset failed: {error}"}
    if reachable_only:
        from .task_filters import is_reachable

        if not is_reachable(env):
            return {"seed": seed, "method": method, "skipped": "no collision-free IK for any grasp"}
    return solve(env, seed=seed, method=method, retries=retries, reset=False)


def summarize(records: list[dict]) -> dict:
    """Per category and overall: episodes, success rate, median computation time, C-space
    length, phase rates and failure counts (skipped seeds left out)."""
    records = [r for r in records if "skipped" not in r]
    if not records:
        return {}
    groups: dict[str, list[dict]] = {}
    for r in records:
        groups.setdefault(r["category"], []).append(r)
    groups["all"] = list(records)
    out = {}
    for name, rs in groups.items():
        out[name] = {
            "episodes": len(rs),
            "success_rate": round(sum(r["success"] for r in rs) / len(rs), 4),
            "median_computation_time": round(statistics.median(r["computation_time"] for r in rs), 3),
            "median_cspace_length": round(statistics.median(r["cspace_length"] for r in rs), 3),
            "phases": {p: round(sum(bool(r["phases"][p]) for r in rs) / len(rs), 4) for p in PHASES},
            "failures": {f: sum(r["failure"] == f for r in rs) for f in FAILURE_CLASSES},
        }
    return out


def format_summary(summary: dict) -> str:
    header = f"{'category':<12}{'episodes':>9}{'success':>9}{'med time s':>12}{'med C-len':>11}  failures"
    lines = [header, "-" * len(header)]
    for name in sorted(summary, key=lambda n: (n == "all", n)):
        s = summary[name]
        failures = ", ".join(f"{k} {v}" for k, v in s["failures"].items() if v) or "-"
        lines.append(f"{name:<12}{s['episodes']:>9}{s['success_rate']:>9.0%}{s['median_computation_time']:>12.2f}"
                     f"{s['median_cspace_length']:>11.2f}  {failures}")
    return "\n".join(lines)
