"""scripts/eval_queue.sh: runs every line of a queue once, in lanes (one a GPU; here on the
CPU), each run with its own --workers and --out, and says which failed."""
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "eval_queue.sh"
# Stands in for `python -m fetchbench_ms eval ARGS --workers W --out DIR`: writes its arguments
# (and $FETCHBENCH_TRAJOPT_DEVICE, when set) into DIR, and fails for a run whose arguments name --method broken.
FAKE_PYTHON = """#!/bin/sh
out=""; prev=""
for a in "$@"; do [ "$prev" = "--out" ] && out=$a; prev=$a; done
mkdir -p "$out" && echo "$@" > "$out/args.txt"
[ -n "${FETCHBENCH_TRAJOPT_DEVICE:-}" ] && echo "$FETCHBENCH_TRAJOPT_DEVICE" > "$out/device.txt"
case "$*" in *"--method broken"*) exit 3 ;; esac
"""


def _run(tmp_path, jobs_text, *extra, lanes="2"):
    fake = tmp_path / "python"
    fake.write_text(FAKE_PYTHON)
    fake.chmod(0o755)
    jobs = tmp_path / "jobs"
    jobs.write_text(jobs_text)
    env = {**os.environ, "PYTHON": str(fake), "LANES": lanes, "PATH": "/usr/bin:/bin"}  # no nvidia-smi
    return subprocess.run(["bash", str(SCRIPT), str(jobs), str(tmp_path / "out"), *extra], capture_output=True,
                          text=True, env=env, timeout=120)


def test_every_run_of_the_queue_runs_once_with_its_workers_and_out(tmp_path):
    lines = [f"run-{k} --method ga-mesh-rrt --suite val --tasks {k}:{k + 1}" for k in range(5)]
    done = _run(tmp_path, "# a comment\n" + "\n".join(lines) + "\n\n", "3")
    assert done.returncode == 0, done.stderr
    out = tmp_path / "out"
    for k in range(5):
        args = (out / f"run-{k}" / "args.txt").read_text().split()
        assert args[:2] == ["-m", "fetchbench_ms"] and args[2] == "eval"
        assert args[3:9] == ["--method", "ga-mesh-rrt", "--suite", "val", "--tasks", f"{k}:{k + 1}"]
        assert args[9:] == ["--workers", "3", "--out", str(out / f"run-{k}")]
    times = (out / "logs" / "times.txt").read_text().splitlines()
    assert sorted(t.split()[0] for t in times) == [f"run-{k}" for k in range(5)]
    assert {t.split()[1] for t in times} <= {"lane=0", "lane=1"} and all(t.endswith("rc=0") for t in times)
    assert (out / "queue").read_text() == "" and "0 failed" in done.stdout


def test_a_failed_run_fails_the_queue_and_bad_input_is_one_line(tmp_path):
    done = _run(tmp_path, "good --method ga-mesh-rrt\nbad --method broken\n", lanes="1")
    assert done.returncode == 1 and "1 failed" in done.stdout
    assert "bad lane=0" in (tmp_path / "out" / "logs" / "times.txt").read_text()
    nothing = _run(tmp_path, "# only a comment\n")
    assert nothing.returncode == 1 and "has no run to do" in nothing.stderr
    usage = subprocess.run(["bash", str(SCRIPT), str(tmp_path / "missing"), str(tmp_path / "o")], capture_output=True,
                           text=True, timeout=60)
    assert usage.returncode == 2 and usage.stderr.startswith("usage: ") and len(usage.stderr.splitlines()) == 1
    workers = _run(tmp_path, "a --method ga-mesh-rrt\n", "0")
    assert workers.returncode == 2 and "WORKERS_PER_LANE must be a whole number" in workers.stderr


def test_assignments_before_the_arguments_set_only_their_runs_environment(tmp_path):
    done = _run(tmp_path, "on-cpu FETCHBENCH_TRAJOPT_DEVICE=cpu --method ga-mesh-trajopt --tasks 0:2\n"
                          "default --method ga-mesh-trajopt --tasks 0:2\n", "2", lanes="1")
    assert done.returncode == 0, done.stderr
    out = tmp_path / "out"
    assert (out / "on-cpu" / "device.txt").read_text().strip() == "cpu"
    assert (out / "on-cpu" / "args.txt").read_text().split()[3:7] == ["--method", "ga-mesh-trajopt", "--tasks", "0:2"]
    assert not (out / "default" / "device.txt").exists()


def test_help_prints_the_header_and_no_code():
    out = subprocess.run(["bash", str(SCRIPT), "--help"], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0
    assert out.stdout.startswith("Many evaluations on one machine") and "MEMLOG_SECONDS" in out.stdout
    assert out.stdout.rstrip().endswith("(default python3).") and "set -euo" not in out.stdout
