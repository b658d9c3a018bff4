"""One round of our Contact-GraspNet weights (``ours``) and the scene-collision network grown on
train-suite tasks, as one command (docs/grasp-rounds.md).

    # a 1-GPU node, 16 cores
    python scripts/grasp_round.py --work out/grasp-rounds --tasks 300 --procs 16 --gpus 0 --ship
    # a 2-GPU node, 32 cores
    python scripts/grasp_round.py --work out/grasp-rounds --tasks 600 --procs 32 --gpus 0,1 --ship
    # where the rounds stand (data, steps, val figures, the plateau check); the val curve; the label rates
    python scripts/grasp_round.py --status
    python scripts/grasp_round.py --plot docs/img/grasp-rounds.png
    python scripts/grasp_round.py --costs --cores 16

A round takes the next ``--tasks`` tasks of the ``train`` suite after the last recorded round's and:

1. **labels** (``--procs`` workers, an env each): Contact-GraspNet views of those tasks through
   their own cameras, scene-consistent grasp labels (``baselines/contact_graspnet/task_views.py``),
   then the collision network's labelled queries of the same tasks and of the ``--val-tasks``
   val tasks (``baselines/mppi_collision/labels.py``; the last round's val labels are copied when it
   ran in the same ``--work`` folder on the same val tasks with the same labeller settings); the
   rates are labels per core-minute;
2. **training**: both models go on from the last round's candidate when that round ran in the same
   ``--work`` folder and its candidate did not ship (training goes on along one line; val only
   picks what ships), else from their shipped weights (``assets/checkpoints/cgn_ours.pt``,
   ``collision_net.pt``; the pretrained CGN weights where ours is missing), on this round's labels
   alone, for ``--cgn-steps`` and ``--collision-steps``; the two trainers run at once, CGN on the
   first of ``--gpus``, the collision net on the last;
3. **val**: the CGN candidate, the shipped ``ours`` and (once per val slice, for reference) the
   pretrained weights, each on the ``--val-tasks`` val tasks, judged by physics: the precision of
   the top-1 and top-10 predicted grasps (``fetchbench_ms.evaluation.grasp_quality``); a
   checkpoint already judged on the same tasks (by sha256, in the record) is not judged again.
   The collision candidate and the shipped network on every labelled query of the val tasks:
   accuracy and the share of all queries called free that collide, at clearance 0;
4. **choice**: a CGN candidate replaces the shipped weights when its top-1 plus top-10 precision
   exceeds theirs, a collision candidate when its accuracy minus its false-free share does (a
   colliding query called free costs twice a free one called colliding); a tie keeps the shipped
   one. With ``--ship`` the winners are packed into ``assets/checkpoints/`` (fp16, ``.planes.xz``)
   with their JSON: the trainer's export JSON plus the count of train-suite tasks the lineage
   trained on (``train_tasks_seen``), its rounds, this round's data manifests and val figures;
5. **record**: the round is appended to ``--record``/rounds.json (tasks, label counts and rates,
   data hashes, steps, val figures, the choice, what shipped, the command, seconds per stage), and
   the round's data manifests are copied beside it (``round_NN/``).

Every stage resumes in ``--work``/round_NN: the labellers skip the shards and task files made, a
stage that finished (``stages/<stage>.json``) is not run again, so the same command continues a
round that stopped; a round in the record is not redone (the next call takes the next slice).
Budgets are counts (tasks, steps, val tasks); ``--time-limit`` stops a trainer only as a safety
net (run the same command again to go on). The test split never trains or chooses: the labels are
of ``train`` tasks, the choice of ``val`` tasks (both labellers refuse test tasks).
"""
from __future__ import annotations

import argparse
import json
import lzma
import math
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

from fetchbench_ms.utils.io import atomic_write_bytes, atomic_write_text
from fetchbench_ms.utils.rounds import answer_report, next_tasks, no_gain_in_two as plateau, parse_slice, round_log

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "results/training/grasp-rounds"
VAL_TASKS = "0:50"
MIN_VAL_TASKS = 50
TOP = 10  # the precision of the top-1 and of the top-TOP grasps
#: ~4 minutes each on an H100 / H200 (cgn_ours.log: 0.234 s a step at batch 16; collision_net.log:
#: ~60k queries a second, 4,096 a step).
CGN_STEPS = 1000
COLLISION_STEPS = 3000
STAGES = ("labels", "training", "val")
GOAL_TASKS = 3000  # issue 53's scale: both models trained on views / labels of >= 3,000 train tasks


ARCHIVED_FILE_SHA = 16  # hex digits of each data file's sha256 kept in an archived manifest


def compact_manifest(manifest: dict) -> dict:
    """A data manifest as the record keeps it: each file's or shard's sha256 cut to its first
    ``ARCHIVED_FILE_SHA`` hex digits (incompressible, most of an archived manifest's bytes); the
    manifest's own sha256, over all its files, stays whole."""
    out = dict(manifest)
    for key in ("files", "shards"):
        if key in out:
            out[key] = [{**e, "sha256": e["sha256"][:ARCHIVED_FILE_SHA]} if "sha256" in e else e for e in out[key]]
    out["archived"] = f"per-file sha256 cut to {ARCHIVED_FILE_SHA} hex digits; sha256 above is whole"
    return out


def archive_round(work: Path, folder: Path) -> None:
    """Keep beside the record what its figures rest on, xz-compressed (the tree's budget): the three
    data manifests (``compact_manifest``), and the per-task rows of the CGN val runs at the path
    their ``run`` field names (``round_NN/val/cgn/NAME.jsonl`` -> ``.jsonl.xz`` under the record folder)."""
    for key, source in (("cgn-views", "cgn_views"), ("collision-labels", "collision"), ("collision-val", "collision_val")):
        manifest = compact_manifest(json.loads((work / source / "manifest.json").read_text()))
        atomic_write_bytes(folder / f"{key}-manifest.json.xz", lzma.compress(json.dumps(manifest, indent=1).encode(), preset=9))
    for rows in sorted((work / "val" / "cgn").glob("*.jsonl")):
        atomic_write_bytes(folder / "val" / "cgn" / f"{rows.name}.xz", lzma.compress(rows.read_bytes(), preset=9))


# ----------------------------------------------------------------------------- the record
def load_record(record: Path) -> dict:
    path = record / "rounds.json"
    if path.is_file():
        return json.loads(path.read_text())
    return {"suite": "train", "val": {"suite": "val", "top": TOP}, "pretrained_val": [], "rounds": []}


def cgn_score(figures: dict) -> float | None:
    """What CGN weights are chosen by: top-1 plus top-10 precision (None: no task judged)."""
    if figures.get("precision_top1") is None:
        return None
    return figures["precision_top1"] + figures[f"precision_top{TOP}"]


def collision_score(figures: dict) -> float:
    """What collision networks are chosen by (at clearance 0): accuracy minus the false-free share."""
    return figures["accuracy"] - figures["false_free_of_all"]


def choose(candidate: dict, shipped: dict | None, score) -> dict:
    """The choice rule (module docstring): the candidate ships when its score exceeds the shipped one's."""
    new = score(candidate)
    if new is None:
        return {"ships": False, "why": "the candidate has no judged val task"}
    if shipped is None or score(shipped) is None:
        return {"ships": True, "why": "nothing shipped with figures on these val tasks"}
    old = score(shipped)
    return {"ships": new > old, "score": [round(new, 4), round(old, 4)],
            "why": f"val score {new:.4f} against the shipped one's {old:.4f}"}


def known_quality(record: dict, sha256: str, tasks: str) -> dict | None:
    """Figures of a CGN checkpoint (by sha256) on exactly these val tasks, if the record has them."""
    entries = list(record.get("pretrained_val", []))
    for r in record["rounds"]:
        entries += [r["cgn"]["val"], r["cgn"].get("shipped_val") or {}]
    for e in entries:
        if e.get("checkpoint_sha256") == sha256 and e.get("tasks") == tasks and e.get("top") == TOP:
            return e
    return None


def best_scores(record: dict) -> dict:
    """Per model, each round's candidate val score."""
    return {"cgn": [cgn_score(r["cgn"]["val"]) or 0.0 for r in record["rounds"]],
            "collision_net": [collision_score(r["collision_net"]["val"]) for r in record["rounds"]]}


def default_grasp_model(record: dict) -> tuple[str, str]:
    """Which weights val says should be the default grasp model, and why: ``ours`` only when the
    last shipped CGN candidate's top-1 and top-10 are both at or above the pretrained weights' on
    the same val tasks (the default changes every Contact-GraspNet row: one figure is not enough)."""
    shipped = [r["cgn"] for r in record["rounds"] if r["cgn"]["shipped"]]
    if not shipped:
        return "pretrained", "no round shipped CGN weights"
    ours = shipped[-1]["val"]
    pretrained = next((p for p in record.get("pretrained_val", []) if p["tasks"] == ours["tasks"]), None)
    if pretrained is None:
        return "pretrained", f"the pretrained weights were not judged on val {ours['tasks']}"
    keys = ("precision_top1", f"precision_top{TOP}")
    figures = ", ".join(f"{k[len('precision_'):]} {ours[k]} vs {pretrained[k]}" for k in keys)
    beats = all(ours[k] is not None and ours[k] >= pretrained[k] for k in keys)
    return ("ours" if beats else "pretrained"), f"ours against pretrained on val {ours['tasks']}: {figures}"


def status(record: dict) -> str:
    lines = [f"{len(record['rounds'])} rounds of train-suite tasks"]
    for p in record.get("pretrained_val", []):
        lines.append(f"pretrained CGN on val {p['tasks']}: top-1 {p['precision_top1']}, top-{TOP} "
                     f"{p[f'precision_top{TOP}']} ({p['tasks_with_predictions']} tasks judged)")
    for r in record["rounds"]:
        lab = r["labels"]
        lines.append(f"round {r['round']}: train tasks {r['tasks'][0]}:{r['tasks'][1]}, {lab['cgn_views']['views']} CGN "
                     f"views, {lab['collision']['queries']} collision queries; val {r['val_tasks']}"
                     + (" (small val: a test)" if r["small_val"] else ""))
        c, n = r["cgn"], r["collision_net"]
        shipped, shipped_net = c.get("shipped_val") or {}, n.get("shipped_val") or {}
        lines.append(f"  cgn: steps {c['steps'][0]}->{c['steps'][1]}, {c['tasks_seen']} train tasks seen; top-1 "
                     f"{c['val']['precision_top1']}, top-{TOP} {c['val'][f'precision_top{TOP}']} (shipped "
                     f"{shipped.get('precision_top1')}, {shipped.get(f'precision_top{TOP}')}); "
                     f"{'shipped' if c['shipped'] else 'not shipped'} ({c['choice']['why']})")
        lines.append(f"  collision net: steps {n['steps'][0]}->{n['steps'][1]}, {n['tasks_seen']} train tasks seen; "
                     f"accuracy {n['val']['accuracy']:.4f}, false-free {n['val']['false_free_of_all']:.4f} of all "
                     f"(shipped {shipped_net.get('accuracy', math.nan):.4f}, {shipped_net.get('false_free_of_all', math.nan):.4f}); "
                     f"{'shipped' if n['shipped'] else 'not shipped'} ({n['choice']['why']})")
    choice, why = default_grasp_model(record)
    lines.append(f"default grasp model by val: {choice} ({why}; both must be at or above)")
    for name, scores in best_scores(record).items():
        lines.append(f"{name}: " + ("plateau: val has not improved for two rounds" if plateau(scores)
                                     else "no plateau yet: another round can improve val"))
    return "\n".join(lines)


def costs(record: dict, cores: int) -> str:
    """Label rates per core-minute and stage seconds of every round, and what the remaining
    tasks up to ``GOAL_TASKS`` take on ``cores`` cores at the last round's rates."""
    if not record["rounds"]:
        return "no round recorded: no measured rate"
    lines = ["| round | where | tasks | CGN views / core-min | collision queries / core-min | seconds: labels, "
             "training, val |", "| --- | --- | --- | --- | --- | --- |"]
    for r in record["rounds"]:
        lab, sec = r["labels"], r["seconds"]
        lines.append(f"| {r['round']} | {r['procs']} procs, gpus {r['gpus']} | {r['tasks'][0]}:{r['tasks'][1]} | "
                     f"{lab['cgn_views']['per_core_minute']['views']} | {lab['collision']['per_core_minute']['queries']}"
                     f" | {sum(sec['labels'].values()):.0f}, {sec['training']:.0f}, {sec['val']:.0f} |")
    last = record["rounds"][-1]
    lab = last["labels"]
    task_minutes = (lab["cgn_views"]["views"] / lab["cgn_views"]["per_core_minute"]["views"]
                    + lab["collision"]["queries"] / lab["collision"]["per_core_minute"]["queries"]) / (
        last["tasks"][1] - last["tasks"][0])
    left = max(0, GOAL_TASKS - last["cgn"]["tasks_seen"])
    lines += ["", f"At round {last['round']}'s rates a train task costs {task_minutes:.2f} core-minutes of labels; "
              f"the {left} tasks left to {GOAL_TASKS} take {left * task_minutes / cores:.0f} minutes on {cores} cores."]
    return "\n".join(lines)


def plot(record: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rounds = record["rounds"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(9.6, 3.8))

    def curve(model: str, figure) -> tuple[list, list, list, list]:
        """The shipped lineage (x: train tasks seen, y: the figure), from the weights round 1 went
        on from to each shipped candidate; then the candidates that did not ship (off that line)."""
        first = rounds[0][model]
        kept = [(first["init_from"]["tasks_seen"], first["shipped_val"])] if first.get("shipped_val") else []
        dropped = []
        for r in rounds:
            (kept if r[model]["shipped"] else dropped).append((r[model]["tasks_seen"], r[model]["val"]))
        return ([x for x, _ in kept], [figure(v) for _, v in kept],
                [x for x, _ in dropped], [figure(v) for _, v in dropped])

    def lineage(ax, model: str, figure, style: str, color: str, label: str) -> None:
        xs, ys, dx, dy = curve(model, figure)
        ax.plot(xs, ys, style, color=color, label=f"{label}, shipped")
        if dx:
            ax.plot(dx, dy, style[-1], color=color, mfc="none", label=f"{label}, not shipped")

    for key, style, color in (("precision_top1", "-o", "C0"), (f"precision_top{TOP}", "--s", "C1")):
        lineage(a, "cgn", lambda v, key=key: math.nan if v[key] is None else v[key], style, color, key)
    for p in record.get("pretrained_val", []):
        a.axhline(p["precision_top1"], color="grey", lw=0.8, label=f"pretrained top-1 (val {p['tasks']})")
        a.axhline(p[f"precision_top{TOP}"], color="grey", lw=0.8, ls="--", label=f"pretrained top-{TOP}")
    a.set_xlabel("train tasks seen by the weights' lineage")
    a.set_ylabel("physics-judged precision on val")
    a.set_title("Contact-GraspNet (ours)")
    lineage(b, "collision_net", lambda v: v["accuracy"], "-o", "C0", "accuracy")
    b.axhline(0.97, color="C0", lw=0.8, ls=":", label="accuracy goal 0.97")
    b.set_ylabel("accuracy")
    b2 = b.twinx()  # the two figures differ 40-fold: one axis each
    lineage(b2, "collision_net", lambda v: 100 * v["false_free_of_all"], "--s", "C1", "false-free %")
    b2.axhline(1.0, color="C1", lw=0.8, ls=":", label="false-free goal 1 %")
    b2.set_ylabel("false-free, % of all queries")
    b2.set_ylim(bottom=0)
    # one legend for both axes, in room left below the curves
    handles, labels = [sum(pair, []) for pair in zip(b.get_legend_handles_labels(), b2.get_legend_handles_labels())]
    low, high = b.get_ylim()
    b.set_ylim(low - (high - low), high)
    b2.legend(handles, labels, fontsize=7, loc="lower right", ncol=2)
    b.set_xlabel("train tasks seen by the network's lineage")
    b.set_title("scene-collision network (val queries)")
    a.legend(fontsize=7, loc="best")
    for ax in (a, b):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, metadata={"Software": None})  # (no date in the PNG: same record, same bytes)
    print(f"wrote {out}")


# ----------------------------------------------------------------------------- the stages
def run(command: list[str], log, env: dict | None = None) -> None:
    log(f"$ {shlex.join(command)}")
    code = subprocess.call(command, cwd=ROOT, env={**os.environ, **(env or {})})
    if code != 0:
        raise SystemExit(f"stopped: exit {code} from {shlex.join(command[:3])} ...; run the same command to resume")


def stage(work: Path, name: str, body, log) -> dict:
    """A stage's result: from ``stages/<name>.json`` when it finished before, else ``body()`` (timed), saved."""
    path = work / "stages" / f"{name}.json"
    if path.is_file():
        log(f"{name}: finished before ({path}), not run again")
        return json.loads(path.read_text())
    t = time.perf_counter()
    result = body()
    # (the label stage times its three labellers itself)
    result["seconds"] = result.pop("stage_seconds", None) or round(time.perf_counter() - t, 1)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(result, indent=1) + "\n")
    return result


def shipped() -> dict:
    """The shipped checkpoints (path or None, content sha256, JSON) of both models: read once at a
    round's start and kept in its work folder, so that a round resumed after it shipped still
    names what it went on from."""
    from fetchbench_ms.grasp_prediction.predict import ours_checkpoint
    from fetchbench_ms.planning.collision_net import checkpoint_path
    from fetchbench_ms.utils.packed import content_sha256, packed_or_plain

    out = {}
    for name, plain in (("cgn", ours_checkpoint()), ("collision_net", checkpoint_path())):
        path = packed_or_plain(plain)
        side = plain.with_suffix(".json")
        meta = json.loads(side.read_text()) if side.is_file() else {}
        out[name] = {"path": str(path) if path.is_file() else None, "sha256": content_sha256(path) if path.is_file() else None,
                     "meta": meta}
    return out


EXPORTS = {"cgn": "cgn_ours", "collision_net": "collision_net"}  # a model's export name in a round's work folder


def starting_points(work_root: Path, record: dict, ship: dict) -> dict:
    """What each model goes on from: the last round's candidate when that round ran in this work
    folder and its candidate did not ship (its export is still here: training goes on along one
    line, val only picks what ships), else the shipped weights. Per model: path, sha256, steps,
    train tasks seen, the lineage's rounds and, for a candidate, its round."""
    from fetchbench_ms.utils.packed import content_sha256

    last = record["rounds"][-1] if record["rounds"] else None
    out = {}
    for model, name in EXPORTS.items():
        export = work_root / f"round_{last['round']:02d}" / "export" / f"{name}.pt" if last else None
        if last and not last[model]["shipped"] and export.is_file():
            out[model] = {"path": str(export), "sha256": content_sha256(export), "steps": last[model]["steps"][1],
                          "tasks_seen": last[model]["tasks_seen"], "round": last["round"],
                          "rounds": lineage_rounds(record, last, model) + [last["round"]]}
            continue
        meta = ship[model]["meta"]
        out[model] = {"path": ship[model]["path"], "sha256": ship[model]["sha256"],
                      "steps": int(meta.get("steps", 0)) if ship[model]["path"] else 0,
                      "tasks_seen": lineage_tasks(meta, model), "round": None,
                      "rounds": list(meta.get("rounds", [])) if ship[model]["path"] else []}
    return out


def lineage_rounds(record: dict, entry: dict, model: str) -> list[int]:
    """The rounds of the lineage a round's candidate went on from (older records: the rounds
    shipped before it)."""
    init = entry[model]["init_from"]
    if "rounds" in init:
        return list(init["rounds"])
    return [r["round"] for r in record["rounds"] if r["round"] < entry["round"] and r[model]["shipped"]]


def lineage_tasks(meta: dict, name: str) -> int:
    """Train-suite tasks a shipped checkpoint's lineage trained on (its JSON's count; before any
    round: the collision net's ``train_tasks``, CGN's table-top views none)."""
    if "train_tasks_seen" in meta:
        return int(meta["train_tasks_seen"])
    return int(meta.get("train_tasks", 0)) if name == "collision_net" else 0


def made_in_call(folder: Path, pattern: str, before: set[str]) -> list[str]:
    return sorted(p.name for p in folder.glob(pattern) if p.name not in before and ".tmp" not in p.name)


def reusable_val_labels(args, record: dict, train_config: dict) -> Path | None:
    """The last round's collision labels of the val tasks, when that round ran in this work folder
    on the same val tasks and its train labels had this round's labeller settings (so its val
    labels are the ones this round would make: ~50 s a round saved)."""
    if not record["rounds"]:
        return None
    last = record["rounds"][-1]
    folder = args.work / f"round_{last['round']:02d}" / "collision_val"
    same = last["val_tasks"] == args.val_tasks and last["labels"]["collision"]["config"] == train_config
    return folder if same and (folder / "manifest.json").is_file() else None


def label_stage(args, work: Path, record: dict, tasks: tuple[int, int], val: tuple[int, int], gpus, log) -> dict:
    """Stage 1: CGN views of the train tasks, collision labels of the train and the val tasks."""
    py = sys.executable
    views = work / "cgn_views"
    # task_views.py numbers its shards by place in the suite (a slice starts at a multiple of a
    # shard); four shards a worker or more keep the workers busy to the end
    shard = next(s for s in (16, 8, 4, 2, 1) if tasks[0] % s == 0 and (tasks[1] - tasks[0]) / s >= 4 * args.procs
                 or s == 1)
    seconds, rates, before = {}, {}, {}
    before["views"] = {p.name for p in views.glob("shard-*.npz")}
    t = time.perf_counter()
    run([py, "baselines/contact_graspnet/task_views.py", "--suite", "train", "--tasks", f"{tasks[0]}:{tasks[1]}",
         "--out", str(views), "--workers", str(args.procs), "--shard-tasks", str(shard), *shlex.split(args.views_args)],
        log)
    seconds["cgn_views"] = round(time.perf_counter() - t, 1)
    manifest = json.loads((views / "manifest.json").read_text())
    new = set(made_in_call(views, "shard-*.npz", before["views"]))
    core_minutes = args.procs * seconds["cgn_views"] / 60
    fresh = [s for s in manifest["shards"] if s["file"] in new]
    rates["cgn_views"] = {"views": round(sum(s["views"] for s in fresh) / core_minutes, 2),
                          "positives": round(sum(s["positives"] for s in fresh) / core_minutes),
                          "tasks": round(sum(s["task_count"] for s in fresh) / core_minutes, 3)}
    out = {"cgn_views": {"tasks": manifest["tasks"], "views": manifest["views"],
                         "positives": sum(s["positives"] for s in manifest["shards"]), "sha256": manifest["sha256"],
                         "config": manifest["config"], "per_core_minute": rates["cgn_views"],
                         "rate_over": f"{len(fresh)} of {len(manifest['shards'])} shards made in the timed call"}}
    device = ["--device", "cuda"] if gpus else []
    env = {"CUDA_VISIBLE_DEVICES": gpus[-1]} if gpus else None
    for key, suite, (a, b) in (("collision", "train", tasks), ("collision_val", "val", val)):
        folder = work / key
        copied = key == "collision_val" and reusable_val_labels(args, record, out["collision"]["config"])
        if copied:  # the same val tasks labelled by the same flags: the labeller finds them made
            shutil.copytree(copied, folder, dirs_exist_ok=True)
            log(f"labels collision_val: copied from {copied} (same val tasks and labeller flags)")
        before = {p.name for p in folder.glob("*.npz")}
        t = time.perf_counter()
        run([py, "baselines/mppi_collision/labels.py", "--suite", suite, "--tasks", f"{a}:{b}", "--out", str(folder),
             "--workers", str(args.procs), *device, *shlex.split(args.labels_args)], log, env)
        seconds[key] = round(time.perf_counter() - t, 1)
        manifest = json.loads((folder / "manifest.json").read_text())
        new = set(made_in_call(folder, "*.npz", before))
        fresh = [e for e in manifest["files"] if e["file"] in new]
        core_minutes = args.procs * seconds[key] / 60
        out[key] = {"tasks": manifest["tasks"], "queries": manifest["queries"], "sha256": manifest["sha256"],
                    "config": manifest["config"], **({"copied_from_round": record["rounds"][-1]["round"]}
                                                     if copied else {}),
                    "per_core_minute": {"queries": round(sum(e["queries"] for e in fresh) / core_minutes),
                                        "tasks": round(len(fresh) / core_minutes, 3)},
                    "rate_over": f"{len(fresh)} of {manifest['tasks']} tasks labelled in the timed call"}
    for key, rate in ((k, out[k]["per_core_minute"]) for k in out):
        log(f"labels {key}: {out[key].get('views', out[key].get('queries'))} in the folder; per core-minute {rate}")
    return {**out, "stage_seconds": seconds}


def repo_relative(path: str | None) -> str | None:
    """A path in the repository as the record names it (relative to it); others as they are."""
    return str(Path(path).relative_to(ROOT)) if path and Path(path).is_relative_to(ROOT) else path


def train_stage(args, work: Path, init: dict, gpus, log) -> dict:
    """Stage 2: both trainers at once, from their starting points (``starting_points``), on this
    round's labels."""
    py = sys.executable
    cgn, net = init["cgn"], init["collision_net"]
    points = json.loads((work / "cgn_views" / "manifest.json").read_text())["config"]["num_points"]
    cgn_init = str(cgn["path"]) if cgn["path"] else "pretrained"
    cgn_cmd = [py, "baselines/contact_graspnet/train.py", "--run", str(work / "runs/cgn"), "--views", "0",
               "--task-views", str(work / "cgn_views"), "--num-points", str(points), "--init", cgn_init,
               "--steps", str(args.cgn_steps), "--device", "cuda" if gpus else "cpu", "--workers", str(args.procs),
               "--time-limit", str(args.time_limit), "--export", "--export-dir", str(work / "export"),
               *shlex.split(args.cgn_args)]
    net_cmd = [py, "baselines/mppi_collision/train.py", "--data", str(work / "collision"), "--val",
               str(work / "collision_val"), "--run", str(work / "runs/collision"), "--steps", str(args.collision_steps),
               "--device", "cuda" if gpus else "cpu", "--time-limit", str(args.time_limit), "--export",
               "--export-path", str(work / "export/collision_net.pt"), *shlex.split(args.collision_args)]
    if net["path"]:
        net_cmd += ["--init-from", str(net["path"])]
    processes = []
    for name, command, gpu in (("cgn", cgn_cmd, gpus[0] if gpus else None),
                               ("collision_net", net_cmd, gpus[-1] if gpus else None)):
        if (work / "export" / f"{'cgn_ours' if name == 'cgn' else name}.json").is_file():
            log(f"training {name}: exported before, not trained again")
            continue
        log(f"$ {shlex.join(command)}")
        env = {**os.environ, "OMP_NUM_THREADS": "1" if not gpus else os.environ.get("OMP_NUM_THREADS", "4")}
        if gpu is not None:
            env["CUDA_VISIBLE_DEVICES"] = gpu
        (work / "runs").mkdir(parents=True, exist_ok=True)
        processes.append((name, subprocess.Popen(command, cwd=ROOT, env=env, stdout=open(work / "runs" / f"{name}.out", "a"),
                                                 stderr=subprocess.STDOUT)))
    failed = [f"{name} (exit {code}, {work / 'runs' / f'{name}.out'})" for name, p in processes if (code := p.wait())]
    if failed:
        raise SystemExit(f"stopped: training failed: {', '.join(failed)}; run the same command to resume")
    missing = [f for f in ("cgn_ours.json", "collision_net.json") if not (work / "export" / f).is_file()]
    if missing:
        raise SystemExit(f"stopped: a trainer reached --time-limit before its last step ({', '.join(missing)} not "
                         "exported); run the same command to resume")
    cgn_meta = json.loads((work / "export/cgn_ours.json").read_text())
    net_meta = json.loads((work / "export/collision_net.json").read_text())
    return {"cgn": {"init": repo_relative(cgn["path"]) or "pretrained", "init_sha256": cgn["sha256"], "steps": cgn_meta["steps"],
                    "checkpoint_sha256": cgn_meta["checkpoint_sha256"], "data_sha256": cgn_meta["data_sha256"]},
            "collision_net": {"init": repo_relative(net["path"]), "init_sha256": net["sha256"],
                              "steps": net_meta["steps"], "train_data_hash": net_meta["train_data_hash"],
                              "val_data_hash": net_meta["val_data_hash"]}}


def val_stage(args, work: Path, record: dict, ship: dict, val: tuple[int, int], gpus, log) -> dict:
    """Stage 3: physics-judged CGN precision and collision figures of candidates and shipped weights."""
    from fetchbench_ms.evaluation.grasp_quality import judge_tasks, summarize_quality
    from fetchbench_ms.tasks.suite import load_suite
    from fetchbench_ms.utils.packed import content_sha256

    tasks = f"{val[0]}:{val[1]}"
    candidate = work / "export/cgn_ours.pt"
    models = {"candidate": (str(candidate), content_sha256(candidate))}
    if ship["cgn"]["path"] and not known_quality(record, ship["cgn"]["sha256"], tasks):
        models["shipped"] = (str(ship["cgn"]["path"]), ship["cgn"]["sha256"])
    pretrained_sha = None
    if not args.skip_pretrained:
        from fetchbench_ms.grasp_prediction.predict import pretrained_checkpoint

        try:
            pretrained_sha = content_sha256(pretrained_checkpoint())
        except FileNotFoundError as error:
            log(f"the pretrained weights are not judged: {error}")
        if pretrained_sha and not known_quality(record, pretrained_sha, tasks):
            models["pretrained"] = ("pretrained", pretrained_sha)
    ids = load_suite("val").ids()[val[0]:val[1]]
    devices = [f"cuda:{g}" for g in gpus] if gpus else ["cpu"]
    rows = judge_tasks("val", ids, {k: v[0] for k, v in models.items()}, work / "val/cgn", args.procs, TOP,
                       devices=devices, log=log)
    figures = {k: {**summarize_quality(rows[k], TOP), "tasks": tasks, "top": TOP, "checkpoint_sha256": models[k][1],
                   "run": str((work / "val/cgn" / f"{k}.jsonl").relative_to(args.work))} for k in models}
    if "shipped" not in figures and ship["cgn"]["path"]:
        figures["shipped"] = known_quality(record, ship["cgn"]["sha256"], tasks)
    if "pretrained" not in figures and pretrained_sha:
        figures["pretrained"] = known_quality(record, pretrained_sha, tasks)
    # the collision networks: the candidate's export JSON judged it on every val query; the shipped one alike
    net_figures = {"candidate": json.loads((work / "export/collision_net.json").read_text())["validation"]}
    if ship["collision_net"]["path"]:
        out = work / "val/collision_shipped.json"
        run([sys.executable, "baselines/mppi_collision/train.py", "--val", str(work / "collision_val"), "--judge",
             str(ship["collision_net"]["path"]), "--judge-out", str(out), "--device", "cuda" if gpus else "cpu"], log,
            {"CUDA_VISIBLE_DEVICES": gpus[-1]} if gpus else None)
        net_figures["shipped"] = json.loads(out.read_text())["validation"]
    return {"cgn": figures, "collision_net": net_figures}


# ----------------------------------------------------------------------------- shipping
def ship_checkpoint(export_pt: Path, meta: dict, log_file: Path, name: str, log) -> None:
    """Pack an export into ``assets/checkpoints/<name>.pt.planes.xz`` with its JSON and log."""
    from fetchbench_ms.utils.packed import PLANES_SUFFIX, pack_planes, unpack_planes

    raw = export_pt.read_bytes()
    if len(raw) > 16e6:
        raise SystemExit(f"{export_pt}: {len(raw) / 1e6:.1f} MB, above the 16 MB a shipped checkpoint may take")
    packed = pack_planes(raw)
    target = ROOT / "assets/checkpoints" / f"{name}.pt{PLANES_SUFFIX}"
    if unpack_planes(packed, target) != raw:
        raise SystemExit(f"{export_pt}: its packed form does not unpack to the same bytes; nothing shipped")
    atomic_write_bytes(target, packed)
    (ROOT / "assets/checkpoints" / f"{name}.pt").unlink(missing_ok=True)  # a plain copy would be read instead
    atomic_write_text(target.parent / f"{name}.json", json.dumps(meta, indent=1) + "\n")
    if log_file.is_file():
        shutil.copyfile(log_file, target.parent / f"{name}.log")
    log(f"shipped {target.relative_to(ROOT)} ({len(packed) / 1e6:.2f} MB packed) and {name}.json")


def ship_meta(export_json: Path, before: dict, entry: dict, model: str, number: int, record: dict, command: str) -> dict:
    """The shipped JSON of a winner: the trainer's export JSON plus its lineage and this round's figures."""
    meta = json.loads(export_json.read_text())
    lineage = lineage_rounds(record, entry, model) + [number]
    meta.update({"steps": entry[model]["steps"][1], "round_steps": meta["steps"],  # the lineage's steps, the round's
                 "train_tasks_seen": entry[model]["tasks_seen"],
                 "train_tasks_seen_note": "train-suite tasks the weights' lineage trained on: every shipped "
                                          "round's slice (scripts/grasp_round.py), plus the count its first "
                                          "checkpoint's JSON gave",
                 "rounds": lineage, "retrain": command, "round_record": "results/training/grasp-rounds/rounds.json",
                 "data_manifests": {k: {"sha256": v["sha256"], "tasks": v["tasks"]} for k, v in entry["labels"].items()
                                    if (k == "cgn_views") == (model == "cgn")},
                 "round_val": entry[model]["val"], "previous": {"sha256": entry[model]["init_from"]["sha256"],
                                                                "train_tasks_seen": entry[model]["init_from"]["tasks_seen"]},
                 "shipped_before": {"sha256": before["sha256"], "train_tasks_seen": lineage_tasks(before["meta"], model)}})
    return meta


# ----------------------------------------------------------------------------- the round
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--record", type=Path, default=RECORD, help="the rounds' record folder (rounds.json)")
    p.add_argument("--status", action="store_true", help="print where the rounds stand and exit")
    p.add_argument("--plot", type=Path, default=None, help="write the val curves PNG here and exit")
    p.add_argument("--costs", action="store_true", help="print the recorded label rates and stage times and exit")
    p.add_argument("--cores", type=int, default=16, help="--costs: cores of the node the estimate is for")
    p.add_argument("--work", type=Path, default=None, help="work folder (round_NN/ inside; re-running resumes)")
    p.add_argument("--tasks", type=int, default=300, help="train tasks this round takes, after the last round's")
    p.add_argument("--procs", type=int, default=os.cpu_count(), help="label and val worker processes")
    p.add_argument("--gpus", default="0", help="GPU indices (CGN trains on the first, the collision net on the last), "
                                               "or 'cpu'")
    p.add_argument("--cgn-steps", type=int, default=CGN_STEPS, help="CGN training steps this round")
    p.add_argument("--collision-steps", type=int, default=COLLISION_STEPS, help="collision-net steps this round")
    p.add_argument("--val-tasks", default=VAL_TASKS, help=f"val START:END of both models' val (at least {MIN_VAL_TASKS})")
    p.add_argument("--allow-small-val", action="store_true", help="fewer val tasks (tests; recorded as such)")
    p.add_argument("--skip-pretrained", action="store_true", help="do not judge the pretrained CGN weights (tests)")
    p.add_argument("--time-limit", type=float, default=600.0, help="s: a trainer's safety net (re-run to go on)")
    p.add_argument("--views-args", default="", help="more flags for task_views.py (tests: fewer points, grasps)")
    p.add_argument("--labels-args", default="", help="more flags for the collision labels.py (tests: --configs)")
    p.add_argument("--cgn-args", default="", help="more flags for the CGN train.py (tests: batch size)")
    p.add_argument("--collision-args", default="", help="more flags for the collision train.py (tests: --scenes)")
    p.add_argument("--ship", action="store_true", help="write the winners to assets/checkpoints/ (else only report)")
    args = p.parse_args(argv)
    record = load_record(args.record)
    if answer_report(args, record, lambda: costs(record, args.cores), status, plot):
        return 0
    if args.work is None:
        raise SystemExit("error: --work is needed to run a round (or --status / --plot / --costs)")
    if args.tasks < 1 or args.procs < 1 or args.cgn_steps < 1 or args.collision_steps < 1:
        raise SystemExit("error: --tasks, --procs, --cgn-steps and --collision-steps must be >= 1")
    gpus = None if args.gpus == "cpu" else args.gpus.split(",")
    if gpus is not None and not all(g.isdigit() for g in gpus):
        raise SystemExit(f"error: --gpus {args.gpus!r}: GPU indices (0 or 0,1) or 'cpu'")
    val = parse_slice(args.val_tasks, "--val-tasks", VAL_TASKS)
    if val[1] - val[0] < MIN_VAL_TASKS and not args.allow_small_val:
        raise SystemExit(f"error: --val-tasks {args.val_tasks}: at least {MIN_VAL_TASKS} val tasks choose the weights "
                         "(--allow-small-val for a test)")
    from fetchbench_ms.tasks.suite import load_suite

    number = len(record["rounds"]) + 1
    start, end = next_tasks(record, args.tasks)
    for suite, (a, b) in (("train", (start, end)), ("val", val)):
        size = len(load_suite(suite).ids())
        if b > size:
            raise SystemExit(f"error: {suite} tasks {a}:{b} run past the {suite} suite's {size} tasks")
    work = args.work / f"round_{number:02d}"
    log = round_log(work / "round.log")
    command = shlex.join(["python", "scripts/grasp_round.py", *(argv if argv is not None else sys.argv[1:])])
    log(f"round {number}: train tasks {start}:{end}, val tasks {args.val_tasks}; {command}")
    t0 = time.perf_counter()
    ship = stage(work, "shipped", shipped, log)  # (its "seconds" unused)
    init = stage(work, "init", lambda: starting_points(args.work, record, ship), log)
    for model in EXPORTS:
        if init[model]["round"] is not None:
            log(f"{model}: goes on from round {init[model]['round']}'s candidate (not shipped), {init[model]['path']}")
    labels = stage(work, "labels", lambda: label_stage(args, work, record, (start, end), val, gpus, log), log)
    training = stage(work, "training", lambda: train_stage(args, work, init, gpus, log), log)
    judged = stage(work, "val", lambda: val_stage(args, work, record, ship, val, gpus, log), log)

    # 4. choice, 5. record (and shipping)
    entry = {"round": number, "tasks": [start, end], "command": command, "procs": args.procs,
             "gpus": "cpu" if gpus is None else ",".join(gpus), "val_tasks": args.val_tasks,
             "small_val": val[1] - val[0] < MIN_VAL_TASKS,
             "seconds": {"labels": labels["seconds"], "training": training["seconds"], "val": judged["seconds"]},
             "labels": {k: v for k, v in labels.items() if k != "seconds"}}
    scores = {"cgn": cgn_score, "collision_net": lambda f: collision_score(f["network"])}
    for model in ("cgn", "collision_net"):
        figures = judged[model]
        choice = choose(figures["candidate"], figures.get("shipped"), scores[model])
        new_steps, start_from = training[model]["steps"], init[model]
        entry[model] = {"init_from": {"checkpoint": training[model]["init"], "sha256": start_from["sha256"],
                                      "steps": start_from["steps"], "tasks_seen": start_from["tasks_seen"],
                                      "rounds": start_from["rounds"], "candidate_of_round": start_from["round"]},
                        "steps": [start_from["steps"], start_from["steps"] + new_steps],
                        "tasks_seen": start_from["tasks_seen"] + (end - start),
                        **{k: v for k, v in training[model].items() if k not in ("init", "init_sha256", "steps")},
                        "val": figures["candidate"] if model == "cgn" else figures["candidate"]["network"],
                        "shipped_val": (figures.get("shipped") if model == "cgn"
                                        else (figures.get("shipped") or {}).get("network")),
                        "choice": choice, "shipped": bool(choice["ships"] and args.ship)}
        if model == "cgn":
            entry[model]["pretrained_val"] = figures.get("pretrained")
        else:
            entry[model]["decision_margin"] = figures["candidate"]["decision_margin"]
        log(f"{model}: {'ships' if choice['ships'] else 'stays'}: {choice['why']}")
    if entry["cgn"].get("pretrained_val") and not known_quality(record, entry["cgn"]["pretrained_val"]["checkpoint_sha256"],
                                                                 args.val_tasks):
        record.setdefault("pretrained_val", []).append(entry["cgn"]["pretrained_val"])
    for model, name, log_name in (("cgn", "cgn_ours", work / "export/cgn_ours.log"),
                                  ("collision_net", "collision_net", work / "runs/collision/log.txt")):
        if entry[model]["shipped"]:
            meta = ship_meta(work / "export" / f"{name}.json", ship[model], entry, model, number, record, command)
            ship_checkpoint(work / "export" / f"{name}.pt", meta, log_name, name, log)
    seconds = entry["seconds"]
    seconds["total"] = round(sum(seconds["labels"].values()) + seconds["training"] + seconds["val"], 1)
    record["rounds"].append(entry)
    archive_round(work, args.record / f"round_{number:02d}")
    atomic_write_text(args.record / "rounds.json", json.dumps(record, indent=1) + "\n")
    log(f"round {number} recorded in {args.record / 'rounds.json'} ({time.perf_counter() - t0:.0f} s in this call; "
        f"stages: {json.dumps(seconds)})")
    print(status(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
