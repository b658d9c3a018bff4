"""``fetchbench report DIR [DIR ...]``: one HTML page with PNG plots (matplotlib).

Tables of success by category and by scene type (methods side by side, as the paper's
tables), failure classes, the phase funnel (IK -> approach plan -> approach execution -> grasp ->
retrieval plan or the policy's retrieval -> final; '-' where the method has no such stage), distributions of computation time and C-space length, and a
gallery of sample failures: the start of the task seen by the env's two cameras
(rendered from the task) and the episode's video when one was recorded
(``DIR/videos/<task id>.gif`` or ``.mp4``).
"""
from __future__ import annotations

import html
import io
import os
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path

from ..utils.io import atomic_write_bytes, atomic_write_text
from .metrics import FUNNEL, failure_classes, summarize
from .methods import file_slug
from .store import VIDEO_DIR, ResultsStore


@dataclass
class Run:
    label: str
    root: Path
    manifest: dict
    records: list
    summary: dict


def load_runs(dirs) -> list[Run]:
    runs = []
    for d in dirs:
        root = Path(d)
        if not root.is_dir():
            raise FileNotFoundError(f"results directory {root} does not exist")
        store = ResultsStore(root)
        manifest = store.manifest()
        records = sorted(store.records(), key=lambda r: r["task_id"])
        if not records:
            raise ValueError(f"results directory {root} has no finished task yet")
        runs.append(Run(manifest["method"], root, manifest, records, summarize(records)))
    labels = [r.label for r in runs]
    for r in runs:  # the same method twice (e.g. two suites): tell them apart by folder
        if labels.count(r.label) > 1:
            r.label = f"{r.label} ({r.root.name})"
    return runs


# ---------------------------------------------------------------------------- plots
def _png(fig) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return buffer.getvalue()


def _percent(fraction: float | None) -> str:
    """A funnel cell: '-' for a stage the method does not have (not 0 %)."""
    return "-" if fraction is None else f"{100 * fraction:.1f}%"


def _grouped_bars(runs, groups: list[str], values, ylabel: str, title: str) -> bytes:
    import matplotlib.pyplot as plt
    import numpy as np

    fig, ax = plt.subplots(figsize=(max(5.0, 0.9 * len(groups) * max(1, len(runs)) * 0.6 + 2), 3.4))
    width = 0.8 / len(runs)
    x = np.arange(len(groups))
    for k, run in enumerate(runs):
        ax.bar(x + (k - (len(runs) - 1) / 2) * width, [values(run, g) for g in groups], width, label=run.label)
    ax.set_xticks(x, groups, rotation=30 if len(groups) > 5 else 0, ha="right" if len(groups) > 5 else "center")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8)
    return _png(fig)


def _rate(run: Run, by: str, group: str) -> float:
    stats = run.summary[by].get(group) if group != "all" else run.summary["all"]
    return 0.0 if stats is None else stats["success_rate"]


def plots(runs: list[Run]) -> dict[str, bytes]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    categories = _union(r.summary["by_category"] for r in runs)
    scene_types = _union(r.summary["by_scene_type"] for r in runs)
    out = {
        "success_by_category.png": _grouped_bars(runs, categories + ["all"], lambda r, g: _rate(r, "by_category", g),
                                                 "success rate", "Success by target category"),
        "success_by_scene_type.png": _grouped_bars(runs, scene_types, lambda r, g: _rate(r, "by_scene_type", g),
                                                   "success rate", "Success by scene type"),
        "funnel.png": _grouped_bars(runs, [name for _, name in FUNNEL],
                                    lambda r, g: r.summary["all"]["funnel"][dict((n, k) for k, n in FUNNEL)[g]] or 0.0,
                                    "fraction of tasks", "Phase funnel (reached by)"),
    }
    classes = failure_classes([x for r in runs for x in r.records])
    fig, ax = plt.subplots(figsize=(6, 0.6 * len(runs) + 1.6))
    left = [0.0] * len(runs)
    for c in classes:
        fractions = [r.summary["all"]["failures"].get(c, 0) / r.summary["all"]["tasks"] for r in runs]
        ax.barh([r.label for r in runs], fractions, left=left, label=c)
        left = [a + b for a, b in zip(left, fractions)]
    ax.set_xlim(0, 1)
    ax.set_xlabel("fraction of tasks")
    ax.set_title("Failure classes")
    if classes:
        ax.legend(fontsize=8, loc="lower right")
    out["failures.png"] = _png(fig)
    for key, xlabel, name in (("computation_time", "computation time per task (s)", "computation_time.png"),
                              ("cspace_length", "C-space path length per task (rad, 9 joints)", "cspace_length.png")):
        fig, ax = plt.subplots(figsize=(6, 3.2))
        drawn = False
        for r in runs:
            values = [x[key] for x in r.records if not x.get("error") and x.get(key) is not None]
            if values:
                ax.hist(values, bins=20, alpha=0.6, label=f"{r.label} (n={len(values)})")
                drawn = True
        ax.set_xlabel(xlabel)
        ax.set_ylabel("tasks")
        if drawn:  # (every task errored: no histogram, and no legend of nothing)
            ax.legend(fontsize=8)
        else:
            ax.text(0.5, 0.5, "no task ran to the end", ha="center", va="center", transform=ax.transAxes)
        out[name] = _png(fig)
    return out


def _union(dicts) -> list[str]:
    keys: list[str] = []
    for d in dicts:
        keys += [k for k in d if k not in keys]
    return keys


# ---------------------------------------------------------------------------- tables
def _pct(stats) -> str:
    return "–" if stats is None else f"{100 * stats['success_rate']:.1f}% <small>({stats['successes']}/{stats['tasks']})</small>"


def _table(header: list[str], rows: list[list[str]], css: str = "") -> str:
    head = "".join(f"<th>{h}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f'<table class="{css}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def paper_reference(run: Run) -> tuple[float, tuple | None] | None:
    """The FetchBench paper's success rate (and its funnel: approach plan, approach execution,
    retrieval plan) for a run of the paper's variant of a method the paper reports: the
    ``paper`` pipeline (or a method without one), the env's defaults and the planners'. None
    otherwise."""
    from . import results_table

    options = run.manifest.get("method_options") or {}
    if run.manifest.get("method") is None or options.get("pipeline") not in ("paper", "none") \
            or options.get("env_options") or options.get("planner_options"):
        return None
    return results_table.paper_reference(run.manifest)


#: The paper's funnel stages in the report's funnel (the record's phase for each).
PAPER_FUNNEL_PHASES = ("pregrasp_plan", "approach_reached", "retrieval_plan")


def _paper_row(cells: int, all_column: int, rate: float) -> list[str]:
    row = ["–"] * cells
    row[all_column] = f"{100 * rate:.1f}%"
    return row


def tables(runs: list[Run]) -> dict[str, str]:
    esc = html.escape
    categories = _union(r.summary["by_category"] for r in runs)
    scene_types = _union(r.summary["by_scene_type"] for r in runs)
    out = {}
    rows = []
    for r in runs:
        rows.append([esc(r.label)] + [_pct(r.summary["by_category"].get(c)) for c in categories] + [
            _pct(r.summary["all"]), str(r.summary["all"]["errors"]),
            _num(r.summary["all"]["median_computation_time"]), _num(r.summary["all"]["median_cspace_length_successes"])])
        paper = paper_reference(r)
        if paper is not None:  # the paper's figure for this method, beside ours
            rows.append([f"<i>FetchBench paper: {esc(r.manifest['method'])}</i>"]
                        + _paper_row(len(categories) + 4, len(categories), paper[0]))
    out["by_category"] = _table(
        ["method"] + [esc(c) for c in categories] + ["all", "errors", "median time (s)",
                       "median C-space length (successes, rad)"],
        rows, "by_category")
    out["by_scene_type"] = _table(["scene type"] + [esc(r.label) for r in runs],
                                  [[esc(t)] + [_pct(r.summary["by_scene_type"].get(t)) for r in runs]
                                   for t in scene_types] + [["all"] + [_pct(r.summary["all"]) for r in runs]],
                                  "by_scene_type")
    classes = failure_classes([x for r in runs for x in r.records])
    out["failures"] = _table(["method"] + [esc(c) for c in classes],
                             [[esc(r.label)] + [str(r.summary["all"]["failures"].get(c, 0)) for c in classes]
                              for r in runs], "failures")
    funnel_rows = []
    for r in runs:
        funnel_rows.append([esc(r.label)] + [_percent(r.summary['all']['funnel'][k]) for k, _ in FUNNEL])
        paper = paper_reference(r)
        if paper is not None and paper[1] is not None:
            given = dict(zip(PAPER_FUNNEL_PHASES, paper[1]))
            funnel_rows.append([f"<i>FetchBench paper: {esc(r.manifest['method'])}</i>"]
                               + [_percent(paper[0] if k == "success" else given.get(k)) for k, _ in FUNNEL])
    out["funnel"] = _table(["method"] + [esc(name) for _, name in FUNNEL], funnel_rows, "funnel")
    return out


def _num(value) -> str:
    return "–" if value is None else f"{value:.2f}"


# ---------------------------------------------------------------------------- gallery
def sample_failures(records: list[dict], n: int) -> list[dict]:
    """Up to ``n`` failed tasks, taking the failure classes in turn (task order within each)."""
    by_class: dict[str, list[dict]] = {}
    for r in records:
        if not r["success"]:
            by_class.setdefault(r.get("failure") or "unknown", []).append(r)
    picked, k = [], 0
    while len(picked) < n and any(k < len(v) for v in by_class.values()):
        picked += [v[k] for v in by_class.values() if k < len(v)][: n - len(picked)]
        k += 1
    return picked


def _task_for(run: Run, record: dict):
    """(env id, reset kwargs) that rebuild the record's task."""
    if run.manifest["source"].startswith("env:"):
        return record["env_id"], {"seed": record["seed"]}
    from ..tasks.suite import load_suite

    suite = load_suite(run.manifest["source"])
    return record.get("env_id", "FetchBench-v0"), {"seed": record["seed"],
                                                   "options": {"task": suite.get(record["task_id"]).to_dict()}}


#: RGB of the outline drawn around the target in the gallery's start images.
TARGET_OUTLINE = (255, 0, 255)


def outline_target(rgb, mask, width: int = 2):
    """``rgb`` [H, W, 3] uint8 with a ``TARGET_OUTLINE`` band of ``width`` px drawn just
    outside ``mask`` [H, W] (the target's pixels), which stay as rendered."""
    import numpy as np

    grown = mask.copy()
    for _ in range(width):
        shifted = grown.copy()
        shifted[1:] |= grown[:-1]
        shifted[:-1] |= grown[1:]
        shifted[:, 1:] |= grown[:, :-1]
        shifted[:, :-1] |= grown[:, 1:]
        grown = shifted
    out = rgb.copy()
    out[grown & ~mask] = TARGET_OUTLINE
    return out


def render_starts(run: Run, records: list[dict]) -> dict[str, bytes]:
    """task id -> PNG of the left and right cameras at the task's start, the target outlined
    (``TARGET_OUTLINE``) where a camera sees it."""
    import numpy as np
    from PIL import Image

    from ..envs import make
    from .methods import SAMPLED_TASK_SPLIT

    envs, images = {}, {}
    try:
        for r in records:
            env_id, reset = _task_for(run, r)
            if env_id not in envs:
                # Seed records rebuild their task only with the split the run sampled from.
                envs[env_id] = make(env_id, obs_mode="rgb+segmentation", object_split=SAMPLED_TASK_SPLIT)
            obs, _ = envs[env_id].reset(**reset)
            target_id = int(envs[env_id].unwrapped.target.per_scene_id[0])
            views = []
            for side in ("left", "right"):
                camera = obs["sensor_data"][f"{side}_camera"]
                mask = camera["segmentation"][0, ..., 0].cpu().numpy() == target_id
                views.append(outline_target(camera["rgb"][0].cpu().numpy(), mask))
            buffer = io.BytesIO()
            Image.fromarray(np.concatenate(views, axis=1)).save(buffer, format="PNG")
            images[r["task_id"]] = buffer.getvalue()
    finally:
        for env in envs.values():
            env.close()
    return images


def source_label(manifest: dict) -> str:
    """Where a run's tasks came from, without the suite file's path: ``suite test (sha256
    0123456789ab)`` or ``env:FetchBench-v0``."""
    source = manifest["source"]
    if source.startswith("env:"):
        return source
    name = (manifest.get("selection") or {}).get("suite") or Path(source).name
    sha = manifest.get("source_sha256")
    return f"suite {name}" + (f" (sha256 {sha[:12]})" if sha else "")


# ---------------------------------------------------------------------------- page
STYLE = """body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}
td:first-child,th:first-child{text-align:left}img{max-width:100%}.card{display:inline-block;width:48%;
vertical-align:top;margin:0 1% 1em 0}pre{white-space:pre-wrap;font-size:11px;background:#f6f6f6}"""


def build_report(dirs, out=None, gallery: int = 6, render: bool = True) -> Path:
    """Write ``index.html`` and its PNGs into ``out`` (default ``FIRST_DIR/report``)."""
    runs = load_runs(dirs)
    out = Path(out) if out else runs[0].root / "report"
    out.mkdir(parents=True, exist_ok=True)
    for name, data in plots(runs).items():
        atomic_write_bytes(out / name, data)
    t = tables(runs)
    esc = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>FetchBench-MS results</title>"
             f"<style>{STYLE}</style></head><body><h1>FetchBench-MS results</h1>"]
    # Paths relative to the report (a page shared or served shows no one's home folder).
    parts.append(_table(["method", "results", "task source", "tasks"],
                        [[esc(r.label), esc(os.path.relpath(r.root.resolve(), out.resolve())),
                          esc(source_label(r.manifest)), str(len(r.records))] for r in runs], "runs"))
    parts.append("<h2>Success by target category</h2>" + t["by_category"] + "<img src='success_by_category.png'>")
    parts.append("<h2>Success by scene type</h2>" + t["by_scene_type"] + "<img src='success_by_scene_type.png'>")
    parts.append("<h2>Failure classes</h2>" + t["failures"] + "<img src='failures.png'>")
    parts.append("<h2>Phase funnel</h2><p>Fraction of tasks that reached each stage (in any try); '-': not a stage of that method.</p>"
                 + t["funnel"] + "<img src='funnel.png'>")
    parts.append("<h2>Computation time and C-space length</h2><p>Computation time counts grasp inference, "
                 "IK, world building and planning (not simulation); tasks that errored are left out.</p>"
                 "<img src='computation_time.png'><img src='cspace_length.png'>")
    parts.append("<h2>Sample failures</h2>")
    for run in runs:
        failures = sample_failures(run.records, gallery)
        parts.append(f"<h3>{esc(run.label)}</h3>")
        if not failures:
            parts.append("<p>No failed task.</p>")
            continue
        images = {}
        if render:
            try:
                images = render_starts(run, [f for f in failures if not f.get("error")])
            except (RuntimeError, ValueError, KeyError, FileNotFoundError) as error:
                # No renderer here, or the task source moved: the report stands without pictures.
                warnings.warn(f"start images of {run.label} not rendered: {error}", stacklevel=1)
                parts.append(f"<p>Start images not rendered: {esc(str(error))}</p>")
        for r in failures:
            card = [f"<div class='card'><b>{esc(r['task_id'])}</b>: {esc(str(r.get('scene_type')))}, "
                    f"{esc(str(r.get('category')))}, target {esc(str(r.get('target_object', '?')))}<br>"
                    f"failure <b>{esc(str(r.get('failure')))}</b>"]
            if r["task_id"] in images:
                name = f"start_{file_slug(run.label)}_{file_slug(r['task_id'])}.png"
                atomic_write_bytes(out / name, images[r["task_id"]])
                card.append(f"<br><img src='{esc(name)}' title='left and right camera at the start'>")
            for ext in (".gif", ".mp4"):
                video = run.root / VIDEO_DIR / f"{file_slug(r['task_id'])}{ext}"
                if video.exists():  # copied, so the report folder stands alone
                    name = f"video_{file_slug(run.label)}_{file_slug(r['task_id'])}{ext}"
                    shutil.copyfile(video, out / name)
                    card.append(f"<br><video src='{name}' controls></video>" if ext == ".mp4"
                                else f"<br><img src='{name}' title='episode video'>")
            if r.get("error"):
                card.append(f"<pre>{esc(r['error']['message'])}\n{esc(r['error'].get('traceback', ''))[-1500:]}</pre>")
            elif r.get("notes"):
                card.append(f"<pre>{esc(chr(10).join(r['notes']))}</pre>")
            card.append("</div>")
            parts.append("".join(card))
    parts.append("</body></html>")
    page = out / "index.html"
    atomic_write_text(page, "\n".join(parts))
    return page
