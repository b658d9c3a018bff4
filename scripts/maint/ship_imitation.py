"""Ship the imitation policies a training run trained (scripts/imitation/imitation_shard.sh, or one
trainer's run folder) as the package's checkpoints: ``assets/checkpoints/imit_<kind>.pt.planes.xz`` (the trainer's fp16 export,
packed losslessly: ``fetchbench_ms.utils.packed``), ``imit_<kind>.json`` beside it (the trainer's export JSON plus the one command that
retrains it, the converted data's manifest and the success on ``val`` tasks) and ``.log``
(the training log).

    python scripts/maint/ship_imitation.py --run build/h3 --retrain "STEPS_MLP=16000 ... bash scripts/imitation/imitation_shard.sh ..." \\
        --val-runs build/h4/evals/val-cgn-imit-mlp-0 build/h4/evals/val-e2e-mlp-0 ...

``--run`` is the folder of the training run: ``export/imit_<kind>.{pt,json}``,
``logs/train_<kind>.log``, ``data/manifest.json``; or one trainer's run folder
(``baselines/imitation/train_<kind>.py --run RUN --export``: ``RUN/export/imit_<kind>.{pt,json}``,
its ``log.txt``, and the manifest of the data its export JSON names); an export chosen by
``scripts/imitation/select_checkpoint.py`` keeps its ``selection`` record (every candidate's val
figures). A val run is an eval folder (``fetchbench eval --suite val``) of one method; the
checkpoint its records name must be the shipped one (by sha256), else it is refused; a run
of test tasks is refused (exit 2). Without ``--run`` the val runs are added to the
checkpoints already shipped (a run of the same method and folder name is replaced):

    python scripts/maint/ship_imitation.py --val-runs build/h5/runs/e2e-mlp-val16-k3 ...
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from fetchbench_ms.evaluation.metrics import summarize
from fetchbench_ms.method_spec import POLICY_KINDS, registry
from fetchbench_ms.policies.deploy import default_checkpoint
from fetchbench_ms.tasks.splits import cli_guard, refuse_test_results
from fetchbench_ms.utils.io import atomic_write_bytes, atomic_write_text, sha256_file
from fetchbench_ms.utils.packed import PLANES_SUFFIX, content_sha256, pack_planes, packed_or_plain

KINDS = tuple(POLICY_KINDS)  # every network the package has
#: The imitation methods and the kind of policy each runs.
POLICY_METHODS = {m.name: m.policy.name for m in registry().values() if m.policy is not None}


def read_records(run: Path) -> list[dict]:
    path = run / "results.jsonl"
    if not path.is_file():
        raise SystemExit(f"{run}: no results.jsonl (an eval folder of `fetchbench eval --out`)")
    cli_guard(refuse_test_results, run, "shipping's val figures")  # a test run: exit 2, nothing written
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    others = sorted({r["task_id"] for r in records if not str(r.get("task_id")).startswith("val/")})
    if others:
        raise SystemExit(f"{run}: val runs only (found {others[:3]}); test tasks never choose")
    return records


def val_figures(runs: list[Path], exported: dict[str, str]) -> dict[str, list[dict]]:
    """Per kind: each val run's method, tasks and success, checked against the exported bytes."""
    out: dict[str, list[dict]] = {k: [] for k in exported}
    for run in runs:
        records = read_records(run)
        method = records[0]["method"]
        kind = POLICY_METHODS.get(method)
        if kind is None:
            raise SystemExit(f"{run}: method {method!r} is not an imitation method; valid: {', '.join(POLICY_METHODS)}")
        if kind not in out:
            raise SystemExit(f"{run}: method {method!r} runs a policy of kind {kind!r}, and no imit_{kind}.pt is "
                             f"shipped here; these are: {', '.join(out)}")
        # Records name the checkpoint's sha256 (since 2026-11-24 evening); older ones only its path.
        used = {r.get("checkpoint_sha256") or Path(r["checkpoint"]).name for r in records}
        if used not in ({exported[kind]}, {f"imit_{kind}.pt"}):
            raise SystemExit(f"{run}: its records used checkpoint(s) {sorted(map(str, used))}, not the shipped "
                             f"imit_{kind}.pt ({exported[kind][:12]})")
        summary = summarize(records)["all"]
        tasks = sorted(r["task_id"] for r in records)
        # one stride per results folder (the store refuses to resume with another)
        out[kind].append({"method": method, "run": run.name, "policy_stride": int(records[0].get("policy_stride", 1)),
                          "tasks": len(records), "first_task": tasks[0],
                          "last_task": tasks[-1], "success_rate": summary["success_rate"],
                          "successes": sum(bool(r.get("success")) for r in records),
                          "checkpoint_checked_by": "sha256" if used == {exported[kind]} else "file name"})
    return out


def add_val_runs(runs: list[Path]) -> int:
    """Add val runs to the shipped checkpoints' JSON, checked against their bytes."""
    shipped = {k: content_sha256(packed_or_plain(default_checkpoint(k))) for k in KINDS
               if packed_or_plain(default_checkpoint(k)).is_file()}
    val = val_figures(runs, shipped)
    for kind in shipped:
        if not val[kind]:
            continue
        path = default_checkpoint(kind).with_suffix(".json")
        meta = json.loads(path.read_text())
        if meta.get("checkpoint_sha256") != shipped[kind]:
            raise SystemExit(f"{path} describes checkpoint {str(meta.get('checkpoint_sha256'))[:12]}, not the shipped "
                             f"bytes ({shipped[kind][:12]}): ship the run again with --run")
        new = {(v["method"], v["run"]) for v in val[kind]}
        meta["validation_success"] = [v for v in meta.get("validation_success", [])
                                      if (v["method"], v["run"]) not in new] + val[kind]
        atomic_write_text(path, json.dumps(meta, indent=1))
        print(f"{path}: val {[(v['method'], v['successes'], v['tasks']) for v in meta['validation_success']]}")
    return 0


def _manifest(run: Path, export_meta: dict, cache: dict) -> dict:
    """The training data's manifest: the run's ``data/manifest.json``, or (a trainer's run
    folder) the one in the data folder its export JSON names."""
    path = run / "data" / "manifest.json"
    if not path.is_file():
        path = Path(export_meta.get("args", {}).get("data", "")) / "manifest.json"
    if not path.is_file():
        raise SystemExit(f"{run}: no data/manifest.json, and its export names no data folder holding one ({path})")
    if path not in cache:
        cache[path] = json.loads(path.read_text())
    return cache[path]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", metavar="RUN", help="the training run's folder: export/, logs/, data/manifest.json (without it: "
                                                 "add --val-runs to the shipped checkpoints)")
    p.add_argument("--retrain", help="the one command that retrains them (into the JSON; with --run)")
    p.add_argument("--kinds", default="mlp,transformer,diffusion",
                   help=f"the run's kinds to ship, comma-separated (default mlp,transformer,diffusion; of {', '.join(KINDS)})")
    p.add_argument("--val-runs", nargs="*", default=[], help="eval folders of val runs with these checkpoints")
    p.add_argument("--note", default="", help="a line on what limits these checkpoints (into the JSON)")
    args = p.parse_args(argv)
    if args.run is None:
        if not args.val_runs:
            p.error("give --run (ship a run's checkpoints) or --val-runs (add val runs to the shipped ones)")
        return add_val_runs([Path(r) for r in args.val_runs])
    if not args.retrain:
        p.error("--run needs --retrain (the one command that retrains them)")
    kinds = [k for k in args.kinds.split(",") if k]
    bad = sorted(set(kinds) - set(KINDS))
    if bad or not kinds:
        p.error(f"--kinds {args.kinds!r}: unknown {', '.join(bad) or '(none given)'}; valid: {', '.join(KINDS)}")
    run = Path(args.run)
    missing = [k for k in kinds if not (run / "export" / f"imit_{k}.pt").is_file()]
    if missing:
        raise SystemExit(f"{run}: no export/imit_<kind>.pt for {', '.join(missing)} (--kinds {args.kinds})")
    manifests = {}
    exported = {k: sha256_file(run / "export" / f"imit_{k}.pt") for k in kinds}
    val = val_figures([Path(r) for r in args.val_runs], exported)
    for kind in kinds:
        meta = json.loads((run / "export" / f"imit_{kind}.json").read_text())
        manifest = _manifest(run, meta, manifests)
        target = default_checkpoint(kind)
        atomic_write_bytes(target.with_name(target.name + PLANES_SUFFIX),
                           pack_planes((run / "export" / f"imit_{kind}.pt").read_bytes()))
        target.unlink(missing_ok=True)  # a plain copy would be read instead of the packed one
        meta.update({
            "checkpoint_sha256": exported[kind],
            "retrain_command": args.retrain,
            "data_manifest": {"settings": {k: v for k, v in manifest["settings"].items() if k != "source"},
                              "totals": manifest["totals"], "chunks": manifest["chunks"]},
            "validation_success": val[kind],
            "note": args.note,
        })
        atomic_write_text(target.with_suffix(".json"), json.dumps(meta, indent=1))
        log = run / "logs" / f"train_{kind}.log"
        shutil.copyfile(log if log.is_file() else run / "log.txt", target.with_suffix(".log"))
        chosen = meta.get("selection")  # scripts/imitation/select_checkpoint.py's record, kept as it is
        print(f"{target}: step {meta['step']}, {manifest['totals']['demos']} demos, sha256 {exported[kind][:12]}, "
              f"val {[(v['method'], v['successes'], v['tasks']) for v in val[kind]]}"
              + (f"; chosen on val from {len(chosen['candidates'])} candidates" if chosen else "; no selection record"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
