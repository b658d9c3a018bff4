"""The shipped evaluation records and the tables printed from them (``fetchbench results``).

Every success figure in README.md and docs/ comes from a packed run in ``results/runs/<name>/``:
``run.json`` (the run's manifest, as ``fetchbench eval`` wrote it) and ``results.jsonl.xz``
(its records, one JSON line per task, sorted by task id, xz with fixed settings so the same
records always give the same bytes; a folder with the earlier ``results.jsonl.gz`` reads
too). ``pack`` makes such a folder from a results directory; ``tables`` prints the Markdown
tables of docs/results.md from every packed run.

Runs whose ``method_options`` have no ``pipeline`` were made with the earlier code (the
extended pipeline with wall-clock planning budgets): they are labelled ``legacy`` and get a
table of their own. Functions take manifests and records and return strings.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..method_spec import registry
from ..utils.io import atomic_write_bytes, atomic_write_text, canonical_json, current_umask
from ..utils.packed import unxz_bytes, xz_bytes
from .metrics import CATEGORIES, summarize
from .store import MANIFEST_FILE, PACKED_RESULTS_FILE, ResultsStore, read_packed_records

BEGIN = "<!-- results-table:begin -->"
END = "<!-- results-table:end -->"
NAME_PATTERN = re.compile(r"[a-z0-9][a-z0-9._-]*")

#: The paper's funnel stages: the record's phase that stands for each (the last is the verdict).
FUNNEL = (("approach plan", "pregrasp_plan"), ("approach exec", "approach_reached"),
          ("retrieval plan", "retrieval_plan"), ("final", "success"))
HEADER = (["run", "method", "pipeline", "suite", "tasks", "success (95% CI)", "paper"] + list(CATEGORIES)
          + [name for name, _ in FUNNEL]
          + ["timeouts", "median computation time", "median C-space length (successes)", "failures"])


@dataclass
class Run:
    name: str
    manifest: dict
    records: list


# ------------------------------------------------------------------------------- packing
def default_runs_dir() -> Path:
    """``results/runs`` of the source checkout, else of the working directory."""
    checkout = Path(__file__).resolve().parents[2] / "results" / "runs"
    return checkout if checkout.is_dir() else Path("results") / "runs"


def packed_bytes(manifest: dict, records: list[dict]) -> tuple[bytes, bytes]:
    """(run.json, results.jsonl.xz) of a packed run: records sorted by task id, one canonical
    JSON line each, xz with fixed settings (the same records give the same bytes)."""
    lines = "".join(canonical_json(r) + "\n" for r in sorted(records, key=lambda r: r["task_id"]))
    return ((json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode(), xz_bytes(lines.encode()))


def _packed_content(folder: Path) -> tuple[bytes, bytes] | None:
    """(run.json, the records' JSON lines) of a packed run folder in either form; None if not one."""
    records = ResultsStore(folder).packed_records_file()
    if records is None or not (folder / MANIFEST_FILE).is_file():
        return None
    return (folder / MANIFEST_FILE).read_bytes(), read_packed_records(records)


def _read_run(run_dir: Path) -> tuple[dict, list[dict]]:
    """(manifest, records) of one results directory of `fetchbench eval --out`, checked."""
    if not run_dir.is_dir():
        raise FileNotFoundError(f"{run_dir} is not a directory")
    store = ResultsStore(run_dir)
    manifest = store.manifest()  # raises: no run.json
    if not isinstance(manifest, dict) or "method" not in manifest:
        raise ValueError(f"{store.manifest_path} names no method: not a run of `fetchbench eval`")
    records = store.records()
    if not records:
        raise ValueError(f"{run_dir} holds no finished task (no record to pack)")
    bad = next((r for r in records if "success" not in r), None)
    if bad is not None:
        raise ValueError(f"{run_dir}: the record of {bad['task_id']} has no 'success': not a task record")
    return manifest, records


def _shard_range(run_dir: Path, manifest: dict) -> tuple[int, int]:
    tasks = str((manifest.get("selection") or {}).get("tasks") or "")
    start, _, end = tasks.partition(":")
    if not (start.strip().isdigit() and end.strip().isdigit()):
        raise ValueError(f"{run_dir}: its selection {manifest.get('selection')} is no explicit START:END range "
                         f"of a suite; only such shards can be packed together")
    return int(start), int(end)


def merge_shards(shards: list[tuple[Path, dict, list[dict]]]) -> tuple[dict, list[dict]]:
    """One run from shards of it: the same method, options and suite, task ranges (``--tasks
    START:END``) that tile one range without gap or overlap. Each task's outcome depends on its
    id alone (count budgets, per-task seeds), so a run split over machines and packed here has
    the records the same run on one machine would have."""
    def compared(manifest: dict) -> dict:
        # a suite's path is where it lay on the machine that ran the shard; its hash (where
        # recorded) says whether it is the same suite, as when a run resumes (ResultsStore)
        skip = {"selection", "source"} if manifest.get("source_sha256") else {"selection"}
        return {k: v for k, v in manifest.items() if k not in skip}

    base = compared(shards[0][1])
    suite = shards[0][1].get("selection", {}).get("suite")
    for run_dir, manifest, _ in shards[1:]:
        other = compared(manifest)
        differ = sorted(k for k in set(base) | set(other) if base.get(k) != other.get(k))
        if differ or manifest.get("selection", {}).get("suite") != suite:
            raise ValueError(f"{run_dir} is not a shard of the same run as {shards[0][0]} "
                             f"(its {', '.join(differ) or 'suite'} differ)")
    ranges = sorted((_shard_range(d, m), d) for d, m, _ in shards)
    for ((_, end), d), ((start, _), next_dir) in zip(ranges, ranges[1:]):
        if start != end:
            raise ValueError(f"the shards {d} and {next_dir} {'overlap' if start < end else 'leave a gap'} "
                             f"(tasks {end} and {start})")
    records = [r for _, _, rs in shards for r in rs]
    if len({r["task_id"] for r in records}) != len(records):
        raise ValueError("the shards hold records of the same task")
    selection = {"suite": suite, "tasks": f"{ranges[0][0][0]}:{ranges[-1][0][1]}"}
    first_manifest = next(m for d, m, _ in shards if d == ranges[0][1])  # its source path: the first range's
    return {**first_manifest, "selection": selection}, records


def pack(run_dirs, name: str, runs_dir=None, force: bool = False) -> Path:
    """Pack the results directory ``run_dirs`` (or several: shards of one run, see
    ``merge_shards``) into ``runs_dir/name``; returns that folder. Refuses a directory that is
    no run or has no record, a bad name, and a folder that holds another run (unless
    ``force``). Packing the same run again changes nothing."""
    dirs = [Path(d) for d in ([run_dirs] if isinstance(run_dirs, (str, os.PathLike)) else run_dirs)]
    runs_dir = Path(runs_dir) if runs_dir is not None else default_runs_dir()
    if not NAME_PATTERN.fullmatch(name):
        raise ValueError(f"bad run name {name!r}: use lower-case letters, digits, '.', '_' and '-' "
                         f"(e.g. cgn-ptd-rrt-pretrained-test600)")
    shards = [(d, *_read_run(d)) for d in dirs]
    manifest, records = merge_shards(shards) if len(shards) > 1 else shards[0][1:]
    files = dict(zip((MANIFEST_FILE, PACKED_RESULTS_FILE), packed_bytes(manifest, records)))
    target = runs_dir / name
    if target.exists():
        old = {f: (target / f).read_bytes() if (target / f).is_file() else None for f in files}
        if old == files:
            return target
        # the same run in the earlier .gz form: rewritten in the present one, as a repack
        same_run = _packed_content(target) == (files[MANIFEST_FILE], unxz_bytes(files[PACKED_RESULTS_FILE]))
        if not force and not same_run:
            raise ValueError(f"{target} holds another run (its {' and '.join(f for f in files if old[f] != files[f])} "
                             f"differ); choose another --name, or --force to replace it")
    runs_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=runs_dir))
    os.chmod(staging, 0o777 & ~current_umask())  # mkdtemp's 0700 would outlive the rename
    try:
        for file, data in files.items():
            atomic_write_bytes(staging / file, data)
        if target.exists():  # (--force, or a repack) the old folder goes only once the new one is complete
            trash = Path(tempfile.mkdtemp(prefix=f".{name}.old.", dir=runs_dir))
            os.replace(target, trash / name)
            os.replace(staging, target)
            shutil.rmtree(trash)
        else:
            os.replace(staging, target)
    finally:
        if staging.exists():
            shutil.rmtree(staging)
    return target


def load_runs(runs_dir=None) -> list[Run]:
    """Every run under ``runs_dir`` (default: results/runs; a packed run or a results
    directory: a folder with a run.json), in folder-name order."""
    runs_dir = Path(runs_dir) if runs_dir is not None else default_runs_dir()
    folders = sorted(p for p in runs_dir.iterdir() if (p / MANIFEST_FILE).is_file()) if runs_dir.is_dir() else []
    if not folders:
        raise FileNotFoundError(f"no run in {runs_dir} (make one with `fetchbench results pack RUN_DIR --name NAME`)")
    runs = []
    for folder in folders:
        store = ResultsStore(folder)
        records = sorted(store.records(), key=lambda r: r["task_id"])
        if not records:
            raise ValueError(f"{folder} holds no record")
        runs.append(Run(folder.name, store.manifest(), records))
    return runs


# ------------------------------------------------------------------------------- labels
def options(manifest: dict) -> dict:
    return manifest.get("method_options") or {}


def is_legacy(manifest: dict) -> bool:
    return "pipeline" not in options(manifest)


def robot(manifest: dict) -> str:
    """The run's robot (``fetchbench eval --robot``; runs without one are the Panda's)."""
    return options(manifest).get("robot") or "panda"


def method_spec_of(manifest: dict):
    """The registered method a run names (``method_spec.registry()``); None for another
    (an importable ``module:function``)."""
    return registry().get(manifest["method"])


def paper_reference(manifest: dict) -> tuple[float, tuple | None] | None:
    """The paper's success rate and funnel (approach plan, approach execution, retrieval plan;
    None where not given) for the method on the run's robot (its ``PaperRow``); None where the
    paper has none."""
    spec = method_spec_of(manifest)
    row = spec.paper if spec is not None else None
    rate = row.on_robot(robot(manifest)) if row is not None else None
    if rate is None:
        return None
    return rate, row.funnel if robot(manifest) == "panda" else None


def method_label(manifest: dict) -> str:
    """The method, its grasp model (cgn-*), tries (xN), policy stride (when not 1) and robot
    (when not the Panda)."""
    o, method = options(manifest), manifest["method"]
    label = f"`{method}`"
    if robot(manifest) != "panda":
        label += f" on `{robot(manifest)}`"
    spec = method_spec_of(manifest)
    if spec is not None and spec.grasps == "cgn" and o.get("grasp_model"):
        label += f" {o['grasp_model']}"
    if (o.get("retries") or 1) > 1:
        label += f" x{o['retries']}"
    if (o.get("policy_stride") or 1) != 1:
        label += f", policy stride {o['policy_stride']}"
    return label


#: Planner options that set a planner's counts, its loop or its checks rather than a factor of the
#: pipeline: a run is compared (the ablation table) only with runs of the same values.
SETTING_OPTIONS = ("trajopt_counts", "trajopt_loop", "trajopt_certify")


def settings(manifest: dict) -> dict:
    """The run's ``SETTING_OPTIONS`` it names (none: the planners' defaults)."""
    planner = options(manifest).get("planner_options") or {}
    return {k: v for k, v in planner.items() if k in SETTING_OPTIONS}


def pipeline_label(manifest: dict, with_settings: bool = True) -> str:
    """``legacy``, ``paper``, ``ours`` or ``ours minus X, Y``, then the env options and the
    planner options (``+ mppi_goal_region=0``); without the ``SETTING_OPTIONS`` when not
    ``with_settings``."""
    o = options(manifest)
    pipeline = "legacy" if is_legacy(manifest) else str(o["pipeline"])
    if pipeline.startswith("ours-minus-"):  # the runner's name: ours-minus-retreat+start_escape
        pipeline = "ours minus " + ", ".join(pipeline[len("ours-minus-"):].split("+"))
    elif pipeline == "ours" and o.get("improvements") is not None:
        from ..solutions.sense_plan_act import IMPROVEMENTS

        off = [i for i in IMPROVEMENTS if i not in o["improvements"]]
        pipeline = "ours minus " + ", ".join(off) if off else "ours"
    env, planner = o.get("env_options") or {}, o.get("planner_options") or {}
    if not with_settings:
        planner = {k: v for k, v in planner.items() if k not in SETTING_OPTIONS}
    return pipeline + "".join(f" + {k}={v}" for k, v in [*sorted(env.items()), *sorted(planner.items())])


def selection_label(manifest: dict) -> str:
    s = manifest.get("selection") or {}
    if "suite" in s:
        return f"{s['suite']} {s.get('tasks') or 'all'}"
    if "env_id" in s:
        return f"{s['env_id']} seeds {s['seed']}-{s['seed'] + s['episodes'] - 1}"
    return "-"


def _rate(v) -> str:
    return "-" if v is None else f"{v:.3f}"


def paper_label(manifest: dict) -> str:
    reference = paper_reference(manifest)
    if reference is None:
        return "-"
    rate, funnel = reference
    return f"{rate:.3f}" + (f" (funnel {' / '.join(map(_rate, funnel))})" if funnel else "")


# ------------------------------------------------------------------------------- tables
def row(run: Run) -> str:
    """One run's row of the runs table."""
    s, records = summarize(run.records), run.records
    a = s["all"]
    lo, hi = a["success_ci95"]
    success = f"**{a['success_rate']:.3f}** ({lo:.3f}-{hi:.3f})"
    if (options(run.manifest).get("retries") or 1) > 1:
        success += f"; first try {a['first_try_success_rate']:.3f}"
    cats = [f"{c['success_rate']:.3f} ({c['tasks']})" if (c := s["by_category"].get(k)) else "-" for k in CATEGORIES]
    funnel = [_rate(a["funnel"][key]) if key == "success" or any(key in (r.get("phases") or {}) for r in records)
              else "-" for _, key in FUNNEL]
    timeouts = sum(r.get("failure") == "timeout" for r in records)
    time, clen = a["median_computation_time"], a["median_cspace_length_successes"]
    failures = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in a["failures"].items() if v) or "-"
    cells = ([run.name, method_label(run.manifest), pipeline_label(run.manifest), selection_label(run.manifest),
              str(a["tasks"]), success, paper_label(run.manifest)] + cats + funnel
             + [str(timeouts), "-" if time is None else f"{time:.2f} s", "-" if clen is None else f"{clen:.2f} rad",
                failures])
    return "| " + " | ".join(cells) + " |"


def runs_table(runs: list[Run]) -> str:
    """The Markdown table of ``runs``: test-suite runs first, then by run name."""
    runs = sorted(runs, key=lambda r: ((r.manifest.get("selection") or {}).get("suite") != "test", r.name))
    lines = ["| " + " | ".join(HEADER) + " |", "|" + " --- |" * len(HEADER)]
    return "\n".join(lines + [row(r) for r in runs])


def _comparable(manifest: dict) -> str:
    """What two runs must share to be compared: method, options other than the pipeline's, the
    planners' counts (``SETTING_OPTIONS``), tasks."""
    o = {k: v for k, v in options(manifest).items()
         if k not in ("pipeline", "improvements", "env_options", "planner_options")}
    return canonical_json([manifest["method"], o, settings(manifest), manifest.get("selection"),
                           manifest.get("source_sha256")])


def _points(d: float) -> str:
    return f"{100 * d:+.1f}"


def _share(num: float, den: float) -> str:
    return "-" if abs(den) < 1e-9 else f"{100 * num / den:+.0f} %"


def ablation_table(runs: list[Run]) -> str:
    """Each run of a method beside its `paper`-variant run on the same tasks: the difference
    in points and the share of the gap (see docs/results.md, "Ablations")."""
    current = [r for r in runs if not is_legacy(r.manifest)]
    lines = []
    for base in sorted((r for r in current if pipeline_label(r.manifest, False) == "paper"), key=lambda r: r.name):
        key, method = _comparable(base.manifest), base.manifest["method"]
        rate = summarize(base.records)["all"]["success_rate"]
        reference = paper_reference(base.manifest)
        paper = None if reference is None else reference[0]
        others = sorted((r for r in current if r is not base and _comparable(r.manifest) == key), key=lambda r: r.name)
        ours = next((r for r in others if pipeline_label(r.manifest, False) == "ours"), None)
        ours_rate = summarize(ours.records)["all"]["success_rate"] if ours else None
        for run in others:
            label, o = pipeline_label(run.manifest), options(run.manifest)
            r = summarize(run.records)["all"]["success_rate"]
            share = "-"
            if paper is not None and o["pipeline"] == "paper" and pipeline_label(run.manifest, False) != "paper":
                share = _share(rate - r, rate - paper)  # > 0: the factor moves us toward the paper
            elif paper is not None and label.startswith("ours minus ") and ours_rate is not None:
                share = _share(ours_rate - r, ours_rate - paper)
            lines.append(f"| {method_label(base.manifest)} | {selection_label(base.manifest)} | {base.name} | "
                         f"{rate:.3f} | {_rate(paper)} | {run.name} | {label} | {r:.3f} | "
                         f"{_points(r - rate)} | {share} |")
    if not lines:
        return "No method has a `paper`-variant run and another run on the same tasks yet."
    header = ["method", "suite", "`paper`-variant run", "its success", "paper", "run", "pipeline", "success",
              "difference (points)", "share of the gap"]
    return "\n".join(["| " + " | ".join(header) + " |", "|" + " --- |" * len(header)] + lines)


def tables(runs: list[Run]) -> str:
    """The Markdown that docs/results.md holds between its results-table markers."""
    current = [r for r in runs if not is_legacy(r.manifest)]
    legacy = [r for r in runs if is_legacy(r.manifest)]
    parts = ["### Runs", "", runs_table(current) if current else "No run of the current pipelines is shipped yet.",
             "", "### Ablations", "", ablation_table(runs)]
    if legacy:
        parts += ["", "### Earlier runs (extended pipeline, wall-clock planning budgets)", "", runs_table(legacy)]
    return "\n".join(parts) + "\n"


# ------------------------------------------------------------------------------- the doc's copy
def _split(text: str, path) -> tuple[str, str, str]:
    if text.count(BEGIN) != 1 or text.count(END) != 1 or text.index(BEGIN) > text.index(END):
        raise ValueError(f"{path} needs one '{BEGIN}' line and, after it, one '{END}' line")
    head, rest = text.split(BEGIN, 1)
    body, tail = rest.split(END, 1)
    return head + BEGIN + "\n", body[1:] if body.startswith("\n") else body, END + tail


def check_doc(path, output: str) -> str | None:
    """None when ``path``'s tables are ``output``; else where they first differ (one line)."""
    text = Path(path).read_text()
    head, body, _ = _split(text, path)
    first = head.count("\n") + 1  # the file's line number of the body's first line
    have, want = body.splitlines(), output.splitlines()
    for n in range(max(len(have), len(want))):
        h = have[n] if n < len(have) else "<the end marker>"
        w = want[n] if n < len(want) else "<the end marker>"
        if h != w:
            return (f"{path}:{first + n}: differs from `fetchbench results table`: has {h[:120]!r}, "
                    f"the command prints {w[:120]!r} (rewrite with --write {path})")
    return None


def write_doc(path, output: str) -> bool:
    """Put ``output`` between ``path``'s markers; True when the file changed."""
    text = Path(path).read_text()
    head, body, tail = _split(text, path)
    new = head + output + tail
    if new != text:
        atomic_write_text(path, new)
    return new != text
