"""The valid-numbers ablation: every paper row's method in both pipelines, ours minus each
improvement, and the environment's factors, as ``fetchbench eval`` runs side by side.

    python scripts/maint/ablation.py --suite test --tasks 0:600 --out runs/ablation --jobs 8 --workers 8
    python scripts/maint/ablation.py --list                     # the runs, in the order they start
    python scripts/maint/ablation.py --only core --out ...      # a group: core, minus, env, rows, planner
    python scripts/maint/ablation.py --names ga-mesh-trajopt-paper,cgn-ptd-rrt-ours --out ...  # these runs, in this order
    fetchbench results table --runs-dir runs/ablation     # the tables (then `fetchbench results pack`)

Groups, in the order they start (the first matter most):
- ``core``: ``paper`` and ``ours`` for ga-mesh-rrt, ga-ptd-rrt, ga-ptd-trajopt, cgn-ptd-rrt,
  cgn-ptd-trajopt;
- ``minus``: ``ours`` minus each improvement for those five (``cgn_filter`` only where CGN
  predicts the grasps);
- ``env``: the paper pipeline of ga-ptd-rrt and cgn-ptd-trajopt with each env option of
  the original (physics at 60 Hz, the paper's camera placement);
- ``rows``: ``paper`` and ``ours`` for the paper's other planner rows (ga-mesh-trajopt,
  cgn-mesh-rrt, cgn-mesh-trajopt, cgn-ptd-mppi);
- ``planner``: the paper pipeline of cgn-ptd-mppi with each planner option of the ablation
  (MPPI's goal credit off).

Each run is ``fetchbench eval ... --out OUT/<name>`` (resumable: a second call finishes what is
missing). ``--gpus N`` gives run k the GPU k mod N (``CUDA_VISIBLE_DEVICES``), so the
trajectory optimiser, Contact-GraspNet and the renderer of parallel runs spread over the cards.
Runs go one per job slot, ``--workers`` processes each; a run's log is ``OUT/<name>.log``.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

CORE = ("ga-mesh-rrt", "ga-ptd-rrt", "ga-ptd-trajopt", "cgn-ptd-rrt", "cgn-ptd-trajopt")
OTHER_ROWS = ("ga-mesh-trajopt", "cgn-mesh-rrt", "cgn-mesh-trajopt", "cgn-ptd-mppi")
ENV_METHODS = ("ga-ptd-rrt", "cgn-ptd-trajopt")
ENV_FACTORS = ("sim_freq=60", "camera_placement=paper")
PLANNER_METHODS = ("cgn-ptd-mppi",)
PLANNER_FACTORS = ("mppi_goal_region=0",)
GROUPS = ("core", "minus", "env", "rows", "planner")


def runs() -> list[tuple[str, str, list[str]]]:
    """(group, name, fetchbench eval arguments) in the order they start."""
    from fetchbench_ms.method_spec import IMPROVEMENTS, method_spec

    out = []
    for method in CORE:
        out.append(("core", f"{method}-paper", ["--method", method, "--pipeline", "paper"]))
        out.append(("core", f"{method}-ours", ["--method", method, "--pipeline", "ours"]))
    for method in CORE:
        for improvement in IMPROVEMENTS:
            if improvement == "cgn_filter" and method_spec(method).grasps != "cgn":
                continue  # annotated grasps are not filtered by it: the run would be "ours" again
            out.append(("minus", f"{method}-ours-minus-{improvement}",
                        ["--method", method, "--pipeline", "ours", "--without", improvement]))
    for factor in ENV_FACTORS:
        for method in ENV_METHODS:
            key = factor.split("=")[0]
            out.append(("env", f"{method}-paper-{key}", ["--method", method, "--pipeline", "paper",
                                                         "--env-option", factor]))
    for method in OTHER_ROWS:
        out.append(("rows", f"{method}-paper", ["--method", method, "--pipeline", "paper"]))
        out.append(("rows", f"{method}-ours", ["--method", method, "--pipeline", "ours"]))
    for factor in PLANNER_FACTORS:
        for method in PLANNER_METHODS:
            out.append(("planner", f"{method}-paper-{factor.split('=')[0]}",
                        ["--method", method, "--pipeline", "paper", "--planner-option", factor]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="test")
    ap.add_argument("--tasks", default="0:600")
    ap.add_argument("--out", type=Path, default=Path("runs/ablation"))
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time")
    ap.add_argument("--workers", type=int, default=1, help="worker processes per run")
    ap.add_argument("--gpus", type=int, default=0, help="spread runs over this many GPUs (0: leave as is)")
    ap.add_argument("--only", default=None, help=f"comma-separated groups: {', '.join(GROUPS)}")
    ap.add_argument("--names", default=None,
                    help="comma-separated run names (see --list), started in the order given")
    ap.add_argument("--list", action="store_true", help="print the runs and their commands, run nothing")
    args = ap.parse_args(argv)
    only = set(GROUPS) if args.only is None else {g.strip() for g in args.only.split(",") if g.strip()}
    if not only or only - set(GROUPS):
        print(f"error: unknown group in --only {args.only!r}; valid: {', '.join(GROUPS)}", file=sys.stderr)
        return 2
    if args.jobs < 1 or args.workers < 1 or args.gpus < 0:
        print("error: --jobs and --workers must be >= 1, --gpus >= 0", file=sys.stderr)
        return 2
    todo = [(g, name, a) for g, name, a in runs() if g in only]
    if args.names is not None:
        by_name = {name: (g, name, a) for g, name, a in todo}
        names = [n.strip() for n in args.names.split(",") if n.strip()]
        unknown = [n for n in names if n not in by_name]
        if not names or unknown:
            print(f"error: unknown run name(s) in --names: {', '.join(unknown) or '(none given)'}; "
                  f"valid: {', '.join(by_name)}", file=sys.stderr)
            return 2
        todo = [by_name[n] for n in dict.fromkeys(names)]
    commands = [(name, [sys.executable, "-m", "fetchbench_ms", "eval", *a, "--suite", args.suite, "--tasks",
                        args.tasks, "--workers", str(args.workers), "--out", str(args.out / name)])
                for _, name, a in todo]
    if args.list:
        for name, cmd in commands:
            print(f"{name}: fetchbench {' '.join(cmd[3:])}")
        return 0
    args.out.mkdir(parents=True, exist_ok=True)
    running: list[tuple[str, subprocess.Popen]] = []
    failed = []
    for k, (name, cmd) in enumerate(commands):
        while len(running) >= args.jobs:
            running, done = _reap(running)
            failed += done
            time.sleep(2)
        env = dict(os.environ)
        if args.gpus:
            env["CUDA_VISIBLE_DEVICES"] = str(k % args.gpus)
        log = open(args.out / f"{name}.log", "ab")
        print(f"[ablation] start {name}", flush=True)
        running.append((name, subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)))
    while running:
        running, done = _reap(running)
        failed += done
        time.sleep(2)
    print(f"[ablation] {len(commands) - len(failed)} of {len(commands)} runs finished"
          + (f"; failed: {', '.join(failed)}" if failed else ""), flush=True)
    return 1 if failed else 0


def _reap(running):
    still, failed = [], []
    for name, proc in running:
        rc = proc.poll()
        if rc is None:
            still.append((name, proc))
        else:
            print(f"[ablation] {name} exited {rc}", flush=True)
            if rc != 0:
                failed.append(name)
    return still, failed


if __name__ == "__main__":
    sys.exit(main())
