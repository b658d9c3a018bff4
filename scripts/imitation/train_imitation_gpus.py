"""The four imitation trainers at once, each on a GPU of its own, from one command.

    python scripts/imitation/train_imitation_gpus.py --data ROOT/data --runs ROOT/runs --gpus 0,1,2,3 \
        [--kinds act,diffusion,transformer,mlp] [--steps 30000] [--save-every 6000] [--time-limit 1500] \
        [--trainer-args "--eval-every 0"] [--kind-args act="--chunk 16"]

Starts each kind's trainer (its ``method_spec.POLICY_KINDS`` row names it:
``baselines/imitation/train_<kind>.py``) with ``--data DATA --run RUNS/<kind> --device cuda``, each
with ``CUDA_VISIBLE_DEVICES`` set to its GPU (kinds and GPUs paired in order), logs
each to ``RUNS/<kind>.log``, waits for all and exits non-zero, naming them, if any failed. Each
trainer resumes its run folder, so the same command goes on after an interruption; with
``--save-every`` each writes a candidate export every N steps (``RUNS/<kind>/candidates/``), to
be chosen on >= 100 val tasks by ``scripts/imitation/select_checkpoint.py``. The trainers read the
training files' obs mode (``compact_pointcloud`` or ``policy_pointcloud``) and record it in their
checkpoints. ``--gpus cpu`` runs them all on the CPU (tests).
"""
from __future__ import annotations

import argparse
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

from fetchbench_ms.method_spec import POLICY_KINDS

ROOT = Path(__file__).resolve().parents[2]
KINDS = ("act", "diffusion", "transformer", "mlp")  # the default: the shipped kinds, the slowest first


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, help="the training files' folder (scripts/imitation/build_imitation_data.py)")
    p.add_argument("--runs", required=True, help="RUNS/<kind>: each trainer's run folder")
    p.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated, of {', '.join(POLICY_KINDS)}")
    p.add_argument("--gpus", default="0,1,2,3", help="one GPU index per kind, in order; or 'cpu'")
    p.add_argument("--steps", type=int, default=None, help="each trainer's --steps (default: its own)")
    p.add_argument("--save-every", type=int, default=None, help="each trainer's --save-every")
    p.add_argument("--time-limit", type=float, default=None, help="each trainer's --time-limit (s)")
    p.add_argument("--trainer-args", default="", help="more flags for every trainer (one shell-quoted string)")
    p.add_argument("--kind-args", action="append", default=[], metavar="KIND=FLAGS",
                   help="more flags for one kind's trainer (repeatable)")
    args = p.parse_args(argv)
    kinds = [k for k in args.kinds.split(",") if k]
    unknown = [k for k in kinds if k not in POLICY_KINDS]
    if unknown or not kinds or len(set(kinds)) != len(kinds):
        p.error(f"--kinds {args.kinds!r}: give distinct kinds of {', '.join(POLICY_KINDS)}")
    gpus = None if args.gpus == "cpu" else [g for g in args.gpus.split(",") if g]
    if gpus is not None and (len(gpus) != len(kinds) or not all(g.isdigit() for g in gpus)):
        p.error(f"--gpus {args.gpus!r}: one GPU index per kind ({len(kinds)}: {', '.join(kinds)}), or 'cpu'")
    per_kind = {}
    for item in args.kind_args:
        kind, sep, flags = item.partition("=")
        if not sep or kind not in kinds:
            p.error(f"--kind-args {item!r}: KIND=FLAGS with KIND one of {', '.join(kinds)}")
        per_kind[kind] = shlex.split(flags)
    if not Path(args.data).is_dir():
        p.error(f"--data {args.data}: no such folder (make it with scripts/imitation/build_imitation_data.py)")
    runs = Path(args.runs)
    runs.mkdir(parents=True, exist_ok=True)
    common = shlex.split(args.trainer_args)
    for flag, value in (("--steps", args.steps), ("--save-every", args.save_every), ("--time-limit", args.time_limit)):
        if value is not None:
            common += [flag, str(value)]
    processes = {}
    for i, kind in enumerate(kinds):
        env = dict(os.environ)
        if gpus is not None:
            env["CUDA_VISIBLE_DEVICES"] = gpus[i]
        command = [sys.executable, str(ROOT / POLICY_KINDS[kind].trainer), "--data", args.data,
                   "--run", str(runs / kind), "--device", "cpu" if gpus is None else "cuda",
                   *common, *per_kind.get(kind, [])]
        log = open(runs / f"{kind}.log", "a")
        log.write(f"$ {'CUDA_VISIBLE_DEVICES=' + gpus[i] + ' ' if gpus else ''}{shlex.join(command)}\n")
        log.flush()
        processes[kind] = (subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env), log,
                           time.perf_counter())
        print(f"{kind}: {'GPU ' + gpus[i] if gpus else 'CPU'}, log {runs / f'{kind}.log'}", flush=True)
    failed = []
    try:
        for kind, (process, log, started) in processes.items():
            code = process.wait()
            log.close()
            print(f"{kind}: exit {code} after {time.perf_counter() - started:.0f} s", flush=True)
            if code != 0:
                failed.append(f"{kind} (exit {code}, see {runs / f'{kind}.log'})")
    finally:  # stopped (a signal, ^C): the trainers stop too; each resumes its checkpoint next time
        for process, _, _ in processes.values():
            if process.poll() is None:
                process.terminate()
    if failed:
        print(f"trainers failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))
    sys.exit(main())
