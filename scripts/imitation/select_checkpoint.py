"""Choose an imitation checkpoint on val tasks, and write the choice with every candidate's figures.

Candidates are the trainers' ``--save-every`` exports (``<run>/candidates/step_NNNNNNN.pt``
with the export JSON beside each) or any exported ``imit_<kind>.pt``. Each is run by
``fetchbench eval --method M --suite val --tasks 0:N --policy-checkpoint CANDIDATE`` into
``OUT/<candidate>`` (resumable: the same command continues an interrupted selection), and
the candidate with the best val success rate is chosen; on a tie, the earlier step. The
chosen bytes are copied to ``--export-path`` (default ``assets/checkpoints/imit_<kind>.pt``)
with a JSON beside it: the candidate's export JSON plus ``checkpoint_sha256`` and
``selection`` (the rule, suite, tasks, method, policy stride, the chosen step and every
candidate's step, sha256 and val figures); ``OUT/selection.json`` holds the same record.

    # every 2,000 steps a candidate (trainer flag --save-every 2000), then on a 16-core GPU node:
    python scripts/imitation/select_checkpoint.py --candidates runs/imit/mlp/candidates --workers 16 \\
        --export-path build/imit/export/imit_mlp.pt
    # ship it (scripts/maint/ship_imitation.py keeps the selection record), the chosen run as its val figures
    python scripts/maint/ship_imitation.py --run build/imit --kinds mlp --retrain "..." \\
        --val-runs out/select/e2e-mlp/step_0012000

Choices are made on ``val`` only: the test suite is refused (exit 2, before anything runs or
is written), as is any other suite; fewer than 100 tasks are refused unless ``--allow-small``
(a warning then goes to stderr and into the record).
"""
from __future__ import annotations

import argparse
import json
import shlex
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Callable

from fetchbench_ms.tasks.splits import cli_guard, refuse_test
from fetchbench_ms.utils.io import atomic_write_text, sha256_file

MIN_TASKS = 100
SUITE = "val"
RULE = "the best success rate on the val tasks; on a tie, the earlier step"


def candidate_info(path: Path) -> dict:
    """A candidate's kind, step and frame stride: from the export JSON beside it, else from
    the checkpoint's own metadata."""
    side = path.with_suffix(".json")
    if side.is_file():
        meta = json.loads(side.read_text())
    else:
        import torch

        payload = torch.load(path, map_location="cpu", weights_only=False)
        meta = {"kind": payload.get("kind"), **payload.get("meta", {})}
    if meta.get("kind") is None or meta.get("step") is None:
        raise SystemExit(f"{path}: not an exported imitation checkpoint (no kind / step in {side.name} "
                         "or in its metadata)")
    return {"path": path, "file": path.name, "kind": meta["kind"], "step": int(meta["step"]),
            "frame_stride": int(meta.get("frame_stride", 1)), "sha256": sha256_file(path),
            "meta": meta if side.is_file() else None}


def find_candidates(paths: list[str]) -> list[dict]:
    """Every ``.pt`` named or in the named folders, one per content (sha256), by step."""
    files = []
    for p in map(Path, paths):
        if p.is_dir():
            files += sorted(p.glob("*.pt"))
        elif p.is_file():
            files.append(p)
        else:
            raise SystemExit(f"--candidates {p}: no such file or folder")
    seen, out = set(), []
    for info in sorted((candidate_info(f) for f in files), key=lambda c: (c["step"], str(c["path"]))):
        if info["sha256"] not in seen:
            seen.add(info["sha256"])
            out.append(info)
    if not out:
        raise SystemExit(f"no candidate checkpoints (*.pt) in {' '.join(paths)}; train with --save-every STEPS")
    kinds = sorted({c["kind"] for c in out})
    if len(kinds) > 1:
        raise SystemExit(f"the candidates are of several kinds ({', '.join(kinds)}): select one kind at a time")
    return out


def run_fetchbench_eval(candidate: dict, out_dir: Path, settings: dict) -> list[dict]:
    """``fetchbench eval`` of one candidate on the selection's tasks; its records."""
    from fetchbench_ms.evaluation.store import ResultsStore

    command = [sys.executable, "-m", "fetchbench_ms", "eval", "--method", settings["method"],
               "--suite", settings["suite"], "--tasks", settings["tasks"], "--workers", str(settings["workers"]),
               "--policy-checkpoint", str(candidate["path"]), "--policy-stride", str(settings["policy_stride"]),
               "--out", str(out_dir), *shlex.split(settings.get("eval_args") or "")]
    print("$ " + " ".join(shlex.quote(c) for c in command), flush=True)
    code = subprocess.call(command)
    if code != 0:
        raise SystemExit(f"fetchbench eval of {candidate['path']} exited with {code}; re-run to resume")
    return ResultsStore(out_dir).records()


def val_figures(candidate: dict, records: list[dict], expected: list[str]) -> dict:
    """The candidate's figures on the selection's tasks, checked: every task, this checkpoint."""
    got = {r["task_id"]: r for r in records}
    missing = [t for t in expected if t not in got]
    if missing:
        raise SystemExit(f"{candidate['path']}: {len(missing)} of the {len(expected)} val tasks have no record "
                         f"(e.g. {missing[0]}); re-run to resume")
    rows = [got[t] for t in expected]
    used = {r.get("checkpoint_sha256") for r in rows} - {None}
    if used - {candidate["sha256"]}:
        raise SystemExit(f"{candidate['path']}: its eval records used checkpoint(s) {sorted(used)}, not these bytes "
                         f"({candidate['sha256'][:12]}): use another --out")
    successes = sum(bool(r.get("success")) for r in rows)
    return {"step": candidate["step"], "file": candidate["file"], "sha256": candidate["sha256"], "tasks": len(rows),
            "successes": successes, "success_rate": round(successes / len(rows), 4),
            "errors": sum(bool(r.get("error")) for r in rows)}


def choose(figures: list[dict]) -> dict:
    """The best success rate; on a tie, the earlier step."""
    return max(figures, key=lambda f: (f["successes"] / f["tasks"], -f["step"]))


def parse_args(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--candidates", nargs="+", required=True,
                   help="candidate checkpoints (.pt) or folders of them (a run's candidates/)")
    p.add_argument("--method", default=None, help="the eval method (default e2e-<kind> of the candidates)")
    p.add_argument("--suite", default=SUITE, help="the val suite (its name or file); test is refused")
    p.add_argument("--tasks", default=f"0:{MIN_TASKS}", help=f"START:END of the val tasks (default 0:{MIN_TASKS})")
    p.add_argument("--allow-small", action="store_true",
                   help=f"allow fewer than {MIN_TASKS} tasks (a warning is printed and recorded)")
    p.add_argument("--workers", type=int, default=1, help="fetchbench eval's worker processes")
    p.add_argument("--policy-stride", type=int, default=None,
                   help="control steps per observation (default: the candidates' frame stride)")
    p.add_argument("--eval-args", default="",
                   help="more `fetchbench eval` flags for every candidate, one string (e.g. '--pipeline ours' for a "
                        "cgn-imit method)")
    p.add_argument("--out", default=None, help="one eval folder per candidate (default out/select/<method>)")
    p.add_argument("--export-path", default=None, help="where the chosen checkpoint goes (default "
                                                        "assets/checkpoints/imit_<kind>.pt), its JSON beside it")
    return p, p.parse_args(argv)


def main(argv=None, evaluate: Callable[[dict, Path, dict], list[dict]] = run_fetchbench_eval) -> int:
    """``evaluate(candidate, out_dir, settings) -> records``: how a candidate is run (tests
    pass a stand-in; the default runs ``fetchbench eval``)."""
    p, args = parse_args(argv)
    cli_guard(refuse_test, args.suite, "checkpoint selection")  # exit 2 before anything runs

    from fetchbench_ms.evaluation.runner import parse_range
    from fetchbench_ms.method_spec import registry
    from fetchbench_ms.policies.deploy import default_checkpoint
    from fetchbench_ms.tasks.suite import load_suite, suite_file_sha256, suite_path

    try:
        suite = load_suite(args.suite)
        picked = parse_range(args.tasks, len(suite))
    except (ValueError, FileNotFoundError) as error:
        p.error(str(error))
    if suite.name != SUITE:
        p.error(f"checkpoint selection uses the val suite (choices are made on val only), got suite {suite.name!r}")
    warning = None
    if len(picked) < MIN_TASKS:
        if not args.allow_small:
            p.error(f"--tasks {args.tasks} is {len(picked)} val tasks; a checkpoint is chosen on >= {MIN_TASKS} "
                    f"(fewer: the difference is noise); --allow-small chooses anyway, with a recorded warning")
        warning = (f"chosen on {len(picked)} val tasks (< {MIN_TASKS}, --allow-small): success rates this close "
                   "are noise; choose again on more tasks")
        print(f"warning: {warning}", file=sys.stderr, flush=True)
    candidates = find_candidates(args.candidates)
    kind = candidates[0]["kind"]
    method = args.method or f"e2e-{kind}"
    runs_kind = [m.name for m in registry().values() if m.policy is not None and m.policy.name == kind]
    if method not in runs_kind:
        p.error(f"--method {method!r} does not run a {kind} policy; valid: {', '.join(runs_kind)}")
    strides = {c["frame_stride"] for c in candidates}
    if args.policy_stride is None and len(strides) > 1:
        p.error(f"the candidates were trained at frame strides {sorted(strides)}: give --policy-stride")
    settings = {"method": method, "suite": args.suite, "tasks": args.tasks, "workers": args.workers,
                "policy_stride": args.policy_stride or strides.pop(), "eval_args": args.eval_args}
    out = Path(args.out or f"out/select/{method}")
    expected = [suite.ids()[k] for k in picked]
    stems = [c["path"].stem for c in candidates]  # one results folder each (the sha256 where names repeat)
    folders = [out / (stem if stems.count(stem) == 1 else f"{stem}-{c['sha256'][:12]}")
               for stem, c in zip(stems, candidates)]

    figures = []
    for c, folder in zip(candidates, folders):
        records = evaluate(c, folder, settings)
        figures.append({**val_figures(c, records, expected), "results": str(folder)})
        f = figures[-1]
        print(f"step {f['step']}: {f['successes']}/{f['tasks']} val tasks ({f['success_rate']:.3f}), "
              f"{f['errors']} errors", flush=True)
    best = choose(figures)
    chosen = next(c for c in candidates if c["sha256"] == best["sha256"])
    selection = {"rule": RULE, "suite": suite.name, "suite_sha256": suite_file_sha256(suite_path(args.suite)),
                 "tasks": args.tasks, "task_count": len(expected), "method": method,
                 "policy_stride": settings["policy_stride"], "eval_args": args.eval_args,
                 "chosen_step": best["step"], "chosen_sha256": best["sha256"], "candidates": figures,
                 "command": " ".join(shlex.quote(a) for a in ["python", "scripts/imitation/select_checkpoint.py",
                                                                *(sys.argv[1:] if argv is None else argv)])}
    if warning:
        selection["warning"] = warning

    target = Path(args.export_path) if args.export_path else default_checkpoint(kind)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(target.name + ".tmp")
    shutil.copyfile(chosen["path"], tmp)  # the bytes the val runs used
    tmp.replace(target)
    meta = dict(chosen["meta"] or {"kind": kind, "step": chosen["step"], "frame_stride": chosen["frame_stride"]})
    meta.update({"checkpoint_sha256": chosen["sha256"], "selection": selection})
    atomic_write_text(target.with_suffix(".json"), json.dumps(meta, indent=1))
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "selection.json", json.dumps(selection, indent=1))
    print(f"chose step {best['step']} ({best['successes']}/{best['tasks']} val tasks) of {len(figures)} candidates "
          f"-> {target} and {target.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
