"""Background jobs on the borrowed GPU machine, started from a copy of the tree.

The device tool re-sends the working tree on every call, replacing its files, and kills
what a call leaves running unless it started a new process session. So a long job
(a suite build, demo generation, training) runs from a copy of the tree in its own
session, and later calls look at it, stop it, and pack what must come back into $OUT
(at most 8 files of 16 MiB, no deeper than two folders). Standard library only: it runs
before anything is installed.

    python3 scripts/maint/device_jobs.py start --root /tmp/fb \\
        --job suite='python3 scripts/build/build_suite.py --suite train --workers 10' \\
        --job cgn='python3 baselines/contact_graspnet/train.py --run /tmp/cgn ...'
    python3 scripts/maint/device_jobs.py status                   # running / exit code, log tails
    python3 scripts/maint/device_jobs.py stop suite               # SIGTERM to the job's process group
    python3 scripts/maint/device_jobs.py collect --out $OUT --path suite=build/suites/train --path cgn=/tmp/cgn/export

``start`` copies the current directory to ``--root`` once (an existing root is reused, so a
second ``start`` adds jobs to the same copy); each job runs ``bash -c COMMAND`` in the root
with its output in ``<state>/NAME.log``. ``collect`` writes one ``NAME.tar.gz`` per path
(relative paths are taken in the root) and ``jobs.tar.gz`` with every log and exit code.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tarfile
import time
from pathlib import Path

STATE = Path(os.environ.get("FETCHBENCH_JOBS_STATE", "/tmp/fetchbench-jobs"))
MAX_FILES = 8  # what the device tool brings back from $OUT
MAX_BYTES = 16 * 2 ** 20


def _jobs() -> dict:
    path = STATE / "jobs.json"
    return json.loads(path.read_text()) if path.exists() else {}


def _save(jobs: dict) -> None:
    STATE.mkdir(parents=True, exist_ok=True)
    tmp = STATE / "jobs.json.tmp"
    tmp.write_text(json.dumps(jobs, indent=1, sort_keys=True))
    os.replace(tmp, STATE / "jobs.json")


def _parse_pairs(pairs: list[str], what: str) -> dict[str, str]:
    out = {}
    for pair in pairs:
        name, sep, value = pair.partition("=")
        if not sep or not name or not value or not name.replace("-", "").replace("_", "").isalnum():
            raise SystemExit(f"{what} must be NAME=VALUE with NAME of letters, digits, - and _; got {pair!r}")
        if name in out:
            raise SystemExit(f"{what} name {name!r} given twice")
        out[name] = value
    return out


def _running(job: dict) -> bool:
    if "rc" in job:
        return False
    try:
        os.kill(job["pid"], 0)
    except ProcessLookupError:
        return False
    return True


def _exit_code(name: str) -> str | None:
    path = STATE / f"{name}.rc"
    return path.read_text().strip() if path.exists() else None


def start(root: Path, jobs_wanted: dict[str, str]) -> None:
    if not root.exists():
        shutil.copytree(".", root, symlinks=True, ignore=shutil.ignore_patterns(".whl", ".gl", "__pycache__"))
        print(f"copied {Path.cwd()} to {root}")
    jobs = _jobs()
    for name, command in jobs_wanted.items():
        if name in jobs and _running(jobs[name]):
            raise SystemExit(f"job {name!r} is still running (pid {jobs[name]['pid']}); stop it first")
        log = STATE / f"{name}.log"
        (STATE / f"{name}.rc").unlink(missing_ok=True)
        STATE.mkdir(parents=True, exist_ok=True)
        # The exit code is written by the job's own shell, so it is known after this tool's
        # call has returned (the job is not our child then).
        wrapped = f"{command}\necho $? > {STATE / (name + '.rc')}"
        with open(log, "ab") as out:
            proc = subprocess.Popen(["bash", "-c", wrapped], cwd=root, stdout=out, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, start_new_session=True)
        jobs[name] = {"pid": proc.pid, "command": command, "root": str(root), "started": time.time()}
        print(f"started {name} (pid {proc.pid}): {command}")
    _save(jobs)


def status(tail: int) -> None:
    jobs = _jobs()
    if not jobs:
        print("no jobs")
    for name, job in jobs.items():
        rc = _exit_code(name)
        state = (f"exited {rc}" if rc is not None else "stopped" if "stopped" in job
                 else "running" if _running(job) else "gone")
        print(f"== {name}: {state}, {time.time() - job['started']:.0f} s since start")
        log = STATE / f"{name}.log"
        if log.exists() and tail:
            lines = log.read_text(errors="replace").splitlines()[-tail:]
            print("\n".join("   " + line for line in lines))


def stop(names: list[str]) -> None:
    jobs = _jobs()
    unknown = [n for n in names if n not in jobs]
    if unknown:
        raise SystemExit(f"unknown job(s) {unknown}; jobs: {', '.join(jobs) or 'none'}")
    for name in names:
        if _running(jobs[name]):
            os.killpg(jobs[name]["pid"], signal.SIGTERM)
            jobs[name]["stopped"] = time.time()
            print(f"stopped {name}")
        else:
            print(f"{name} had already ended")
    _save(jobs)


def collect(out: Path, paths: dict[str, str]) -> None:
    jobs = _jobs()
    if len(paths) + 1 > MAX_FILES:
        raise SystemExit(f"at most {MAX_FILES - 1} paths (the logs take one file of {MAX_FILES})")
    roots = {job["root"] for job in jobs.values()}
    root = Path(roots.pop()) if len(roots) == 1 else Path.cwd()
    out.mkdir(parents=True, exist_ok=True)
    with tarfile.open(out / "jobs.tar.gz", "w:gz") as tar:
        for item in sorted(STATE.glob("*")):
            tar.add(item, arcname=f"jobs/{item.name}")
    for name, path in paths.items():
        source = Path(path) if Path(path).is_absolute() else root / path
        if not source.exists():
            print(f"{name}: {source} does not exist, skipped")
            continue
        target = out / f"{name}.tar.gz"
        with tarfile.open(target, "w:gz") as tar:
            tar.add(source, arcname=source.name)
        size = target.stat().st_size
        print(f"{target.name}: {size / 2 ** 20:.1f} MiB" + ("  (OVER 16 MiB: will not come back)" if size > MAX_BYTES else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="verb", required=True)
    s = sub.add_parser("start")
    s.add_argument("--root", default="/tmp/fb", help="where the tree is copied and the jobs run")
    s.add_argument("--job", action="append", default=[], metavar="NAME=COMMAND", required=True)
    st = sub.add_parser("status")
    st.add_argument("--tail", type=int, default=3)
    sp = sub.add_parser("stop")
    sp.add_argument("names", nargs="+")
    c = sub.add_parser("collect")
    c.add_argument("--out", default=os.environ.get("OUT"), help="default $OUT")
    c.add_argument("--path", action="append", default=[], metavar="NAME=PATH")
    args = ap.parse_args(argv)
    if args.verb == "start":
        start(Path(args.root), _parse_pairs(args.job, "--job"))
    elif args.verb == "status":
        status(args.tail)
    elif args.verb == "stop":
        stop(args.names)
    else:
        if not args.out:
            raise SystemExit("collect needs --out (or $OUT set)")
        collect(Path(args.out), _parse_pairs(args.path, "--path"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
