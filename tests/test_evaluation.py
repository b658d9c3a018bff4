"""The evaluation runner: task isolation (exception, timeout, crash), resume, kill -9 and
restart, the Ray backend, and bad input. Tasks come from a tiny suite of sampled tasks;
the methods are cheap (``idle`` holds the arm; ``evaluation_faults:faulty`` injects faults)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fetchbench_ms.cli import main
from fetchbench_ms.evaluation import ResultsStore, evaluate
from fetchbench_ms.evaluation.methods import task_seed

REPO = Path(__file__).resolve().parents[1]
TIMING_FIELDS = ("wall_time", "computation_time")


def make_suite(path: Path, seeds) -> Path:
    from fetchbench_ms.tasks import sample_task
    from fetchbench_ms.tasks.suite import TaskSuite

    TaskSuite("tiny", {f"tiny/{i:04d}": sample_task(s) for i, s in enumerate(seeds)}).save(path)
    return path


@pytest.fixture(scope="module")
def tiny_suite(tmp_path_factory) -> Path:
    return make_suite(tmp_path_factory.mktemp("suite") / "tiny.json", range(4))


@pytest.fixture(scope="module")
def idle_reference(tiny_suite, tmp_path_factory) -> list[dict]:
    """An uninterrupted local run of ``idle`` over the tiny suite."""
    out = tmp_path_factory.mktemp("idle_ref")
    evaluate("idle", out, suite=str(tiny_suite), workers=2, progress=False)
    return comparable(ResultsStore(out).records())


def comparable(records: list[dict]) -> list[dict]:
    """Records without timings, in task order: what must not depend on how the run went."""
    return sorted(({k: v for k, v in r.items() if k not in TIMING_FIELDS} for r in records),
                  key=lambda r: r["task_id"])


def test_idle_records_every_task_once(idle_reference, tiny_suite):
    assert [r["task_id"] for r in idle_reference] == [f"tiny/{i:04d}" for i in range(4)]
    for r in idle_reference:
        assert r["method"] == "idle" and r["success"] is False and r["failure"] == "not_attempted"
        assert r["seed"] == task_seed(r["task_id"]) and "error" not in r
        assert r["scene_type"] and r["category"] in ("on_table", "on_shelf", "in_drawer", "in_basket")


def test_faults_are_isolated(tiny_suite, tmp_path, monkeypatch):
    """A task that raises, one that hangs past the limit and one that kills its worker each
    become an error record; the other task completes; the run finishes."""
    faults = {"tiny/0000": "raise", "tiny/0001": "hang", "tiny/0002": "crash"}
    monkeypatch.setenv("FETCHBENCH_TEST_FAULTS", json.dumps({str(task_seed(k)): v for k, v in faults.items()}))
    # The limit counts each method's run from its start in the worker: a worker's start-up
    # and env build, however slow on a loaded machine, are not in it.
    records = evaluate("evaluation_faults:faulty", tmp_path, suite=str(tiny_suite), workers=2, task_timeout=10,
                       progress=False)
    by_id = {r["task_id"]: r for r in records}
    assert sorted(by_id) == [f"tiny/{i:04d}" for i in range(4)]
    assert by_id["tiny/0000"]["error"]["kind"] == "exception"
    assert "injected failure" in by_id["tiny/0000"]["error"]["message"]
    assert "Traceback" in by_id["tiny/0000"]["error"]["traceback"]
    assert "evaluation_faults.py" in by_id["tiny/0000"]["error"]["traceback"]
    assert by_id["tiny/0001"]["error"]["kind"] == "timeout"
    assert by_id["tiny/0002"]["error"]["kind"] == "crash" and "exit code 11" in by_id["tiny/0002"]["error"]["message"]
    assert "error" not in by_id["tiny/0003"] and by_id["tiny/0003"]["failure"] == "not_attempted"
    for k in faults:  # a task stopped by the time limit is a timeout, the others errors
        assert by_id[k]["success"] is False
        assert by_id[k]["failure"] == ("timeout" if faults[k] == "hang" else "error")
        assert by_id[k]["scene_type"] and by_id[k]["category"]  # known from the task, even without a result
    assert len((tmp_path / "results.jsonl").read_text().splitlines()) == 4
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["all"]["errors"] == 3 and summary["all"]["timeouts"] == 1 and summary["all"]["tasks"] == 4


def children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (Linux /proc)."""
    out = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines() if ":\t" in line)
        except OSError:
            continue
        if int(fields.get("PPid", "0").strip()) == pid:
            out.append(int(status.parent.name))
    return out


def zombie(pid: int) -> bool:
    try:
        return "\nState:\tZ" in Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False


def test_kill_9_and_restart_gives_the_uninterrupted_results(tiny_suite, idle_reference, tmp_path):
    out = tmp_path / "run"
    command = [sys.executable, "-m", "fetchbench_ms", "eval", "--method", "idle", "--suite", str(tiny_suite),
               "--workers", "1", "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    results = out / "results.jsonl"
    deadline = time.monotonic() + 150
    while time.monotonic() < deadline and not (results.exists() and results.read_text().count("\n") >= 1):
        assert proc.poll() is None, "the run ended before it could be killed"
        time.sleep(0.2)
    workers = children(proc.pid)
    assert workers, "the run has no worker process"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    deadline = time.monotonic() + 20
    while any(Path(f"/proc/{pid}").exists() and not zombie(pid) for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not [pid for pid in workers if Path(f"/proc/{pid}").exists() and not zombie(pid)], \
        "worker processes outlived the killed run"
    # A half-written last line, as a kill in the middle of an append would leave.
    with open(results, "ab") as f:
        f.write(b'{"task_id":"tiny/00')
    before = results.read_text().splitlines()[:-1]
    assert 1 <= len(before) < 4, "the kill did not land mid-run"
    assert subprocess.run(command, env=env, stdout=subprocess.DEVNULL).returncode == 0
    lines = results.read_text().splitlines()
    assert lines[:len(before)] == before  # finished tasks were skipped, not run again
    assert len(lines) == 4 and len({json.loads(x)["task_id"] for x in lines}) == 4  # none lost, none doubled
    assert comparable(ResultsStore(out).records()) == idle_reference
    # Nothing left: another run starts no worker and writes nothing.
    records = evaluate("idle", out, suite=str(tiny_suite), progress=False)
    assert results.read_text().splitlines() == lines and len(records) == 4
    with pytest.raises(ValueError, match="another run"):
        evaluate("evaluation_faults:faulty", out, suite=str(tiny_suite), progress=False)


def test_ray_backend_gives_the_same_records(tiny_suite, idle_reference, tmp_path):
    records = evaluate("idle", tmp_path, suite=str(tiny_suite), workers=2, backend="ray", progress=False)
    assert comparable(records) == idle_reference


def test_seed_mode_runs_env_seeds(monkeypatch):
    """``--env ID --episodes N --seed S``: the env samples the task from each seed (run here
    in-process, as a worker runs it)."""
    from fetchbench_ms.evaluation.methods import TaskRunner, resolve_run
    from fetchbench_ms.evaluation.runner import seed_items
    from fetchbench_ms.objects.loading import object_ids

    monkeypatch.setenv("FETCHBENCH_TEST_FAULTS", "{}")
    items = seed_items("FetchBench-Shelf-v0", 2, 7)
    assert [i.task_id for i in items] == ["FetchBench-Shelf-v0/seed-7", "FetchBench-Shelf-v0/seed-8"]
    runner = TaskRunner(resolve_run("evaluation_faults:numpy_record"))
    try:
        record = runner(items[1])
        task = runner.envs[("FetchBench-Shelf-v0", "none")].unwrapped.tasks[0]
        assert task.seed == 8
        # Sampled tasks are an evaluation: test objects, although the env's default is train.
        test_objects = set(object_ids("test"))
        assert task.objects and all(o.object_id in test_objects for o in task.objects)
        odd = runner(seed_items("FetchBench-Shelf-v0", 1, 7)[0])
    finally:
        runner.close()
    assert record["seed"] == 8 and record["category"] == "on_shelf" and record["env_id"] == "FetchBench-Shelf-v0"
    # numpy values come back as plain JSON values; a record without success is an error.
    assert record["success"] is False and record["computation_time"] == 0.5 and record["phases"]["ik_found"] is True
    assert odd["error"]["kind"] == "exception" and "no boolean 'success'" in odd["error"]["message"]


def test_planner_options_are_recorded_and_reach_the_solver(tmp_path, monkeypatch):
    """``--planner-option`` is checked, reaches the method's SolveConfig and is recorded in
    run.json's method_options and every record (and in the default folder's name); a run
    without one records no key. The solver and the worker pool are stand-ins here: the runner
    runs in this process, and ``solve`` returns the goal region it was given."""
    from fetchbench_ms.evaluation import local
    from fetchbench_ms.evaluation.methods import TaskRunner
    from fetchbench_ms.solutions import sense_plan_act

    def solve(env, seed, method, config, **kwargs):
        return {"success": False, "failure": "motion_planning_failure", "computation_time": 0.0,
                "cspace_length": 0.0, "phases": {}, "solver_goal_region": config.mppi_goal_region}

    def run_local(spec, todo, on_record, **kwargs):
        runner = TaskRunner(spec)
        try:
            for item in todo:
                on_record(runner(item))
        finally:
            runner.close()

    monkeypatch.setattr(sense_plan_act, "solve", solve)
    monkeypatch.setattr(local, "run_local", run_local)
    monkeypatch.chdir(tmp_path)
    argv = ["eval", "--method", "ga-mesh-mppi", "--suite", "smoke", "--tasks", "0:1"]
    assert main(argv + ["--planner-option", "mppi_goal_region=0.0"]) == 0
    store = ResultsStore(tmp_path / "out" / "eval" / "ga-mesh-mppi-paper-mppi_goal_region=0")
    assert store.manifest()["method_options"]["planner_options"] == {"mppi_goal_region": 0}
    [record] = store.records()
    assert record["planner_options"] == {"mppi_goal_region": 0} and record["solver_goal_region"] == 0
    assert main(argv) == 0
    store = ResultsStore(tmp_path / "out" / "eval" / "ga-mesh-mppi-paper")
    [record] = store.records()
    assert "planner_options" not in store.manifest()["method_options"] and "planner_options" not in record
    assert record["solver_goal_region"] is None  # MppiConfig's default


@pytest.mark.parametrize("argv, message", [
    (["eval", "--method", "cgn-rrt", "--suite", "smoke"], "valid: ga-mesh-rrt, ga-ptd-rrt, cgn-ptd-rrt, cgn-mesh-rrt, ga-mesh-trajopt, ga-ptd-trajopt, cgn-ptd-trajopt, cgn-mesh-trajopt, cgn-ptd-mppi, ga-ptd-mppi, ga-mesh-mppi, e2e-mlp, e2e-transformer, e2e-diffusion, e2e-act, twostage-mlp, twostage-transformer, twostage-diffusion, twostage-act, cgn-imit-mlp, cgn-imit-transformer, cgn-imit-diffusion, cgn-imit-act, idle"),
    (["eval", "--method", "idle", "--suite", "no-such-suite"], "unknown task suite 'no-such-suite'; valid:"),
    (["eval", "--method", "idle", "--suite", "SUITE", "--tasks", "3-9"], "--tasks takes START:END"),
    (["eval", "--method", "idle", "--suite", "SUITE", "--tasks", "2:99"], "need 0 <= START < END <= 4"),
    (["eval", "--method", "idle", "--suite", "SUITE", "--backend", "slurm"], "valid: local, ray"),
    (["eval", "--method", "idle", "--env", "FetchBench-Shelves-v0"], "unknown env id 'FetchBench-Shelves-v0'"),
    (["eval", "--method", "no_such_module:run"], "cannot import"),
    (["eval", "--method", "ga-mesh-mppi", "--suite", "SUITE", "--planner-option", "mppi_cost=network"],
     "ga-mesh-mppi plans in the meshes, and the network cost reads an observed point cloud: valid mppi_cost there: "
     "distance"),
    (["report", "NO_DIR"], "does not exist"),
])
def test_bad_input_is_a_clear_error(argv, message, tiny_suite, tmp_path, capsys):
    argv = [str(tiny_suite) if a == "SUITE" else str(tmp_path / "missing") if a == "NO_DIR" else a for a in argv]
    if argv[0] == "eval":
        argv += ["--out", str(tmp_path / "out")]
    assert main(argv) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out" / "results.jsonl").exists()


@pytest.mark.parametrize("flag, value, valid", [
    ("--workers", "0", "workers (--workers) must be a whole number >= 1 (worker processes), got 0"),
    ("--retries", "0", "retries (--retries) must be a whole number >= 1 (tries per task), got 0"),
    ("--task-timeout", "0", "task_timeout (--task-timeout) must be a number of seconds > 0, got 0.0"),
    ("--task-timeout", "nan", "task_timeout (--task-timeout) must be a number of seconds > 0, got nan"),
    ("--policy-stride", "0", "policy_stride (--policy-stride) must be a whole number >= 1"),
])
def test_numbers_out_of_range_stop_before_anything_is_written(flag, value, valid, tiny_suite, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["eval", "--method", "idle", "--suite", str(tiny_suite), "--out", str(out), flag, value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and valid in err[0], err
    assert not out.exists()


def test_a_folder_with_a_manifest_and_no_records_takes_another_run(tmp_path):
    """A run that stopped before its first record left only run.json: that is no run, and
    another method may use the folder; once it holds records, another run is refused."""
    store = ResultsStore(tmp_path / "out")
    store.open_run({"method": "ga-mesh-rrt", "source": "suite-a", "method_options": {}})
    store.open_run({"method": "idle", "source": "suite-a", "method_options": {}})
    assert store.manifest()["method"] == "idle"
    store.append({"task_id": "tiny/0000", "success": False})
    with pytest.raises(ValueError, match="holds results of another run"):
        store.open_run({"method": "ga-mesh-rrt", "source": "suite-a", "method_options": {}})


def test_report_of_a_folder_that_is_not_a_results_dir(tmp_path, capsys):
    assert main(["report", str(tmp_path)]) == 2
    assert "not a results directory" in capsys.readouterr().err


def test_videos_of_failed_tasks(tmp_path):
    """With a video folder, a failed task leaves a GIF: the start, a frame every 8 control
    steps of the method, the end; the env's own stepping is restored afterwards."""
    from PIL import Image

    from fetchbench_ms.evaluation.methods import VIDEO_EVERY, TaskRunner, resolve_run
    from fetchbench_ms.evaluation.runner import seed_items

    runner = TaskRunner(resolve_run("evaluation_faults:wiggle", video_dir=str(tmp_path)))
    try:
        record = runner(seed_items("FetchBench-Table-v0", 1, 4)[0])
        env = runner.envs[("FetchBench-Table-v0", "none")].unwrapped
        assert "_step_action" not in vars(env)
    finally:
        runner.close()
    assert "error" not in record
    gif = Image.open(tmp_path / "FetchBench-Table-v0_seed-4.gif")
    assert gif.size == (256, 256)
    # GIF merges repeated frames (the arm held still) into longer ones: count time, not frames.
    total_ms = 0
    for k in range(gif.n_frames):
        gif.seek(k)
        total_ms += gif.info["duration"]
    assert total_ms == (1 + 16 // VIDEO_EVERY + 1) * 1000 * VIDEO_EVERY // 20


def test_ray_backend_isolates_faults(tiny_suite, tmp_path, monkeypatch):
    faults = {"tiny/0000": "raise", "tiny/0001": "hang", "tiny/0002": "crash"}
    monkeypatch.setenv("FETCHBENCH_TEST_FAULTS", json.dumps({str(task_seed(k)): v for k, v in faults.items()}))
    # The limit counts from each method's start in its actor (actor start-up and env build
    # are not in it), so a short one cuts the hang and leaves the other outcomes to the tasks.
    records = evaluate("evaluation_faults:faulty", tmp_path, suite=str(tiny_suite), workers=2, backend="ray",
                       task_timeout=10, progress=False)
    kinds = {r["task_id"]: (r.get("error") or {}).get("kind") for r in records}
    assert kinds == {"tiny/0000": "exception", "tiny/0001": "timeout", "tiny/0002": "crash", "tiny/0003": None}
    assert "injected failure" in records[0]["error"]["traceback"]


@pytest.mark.parametrize("backend", ["local", "ray"])
def test_a_slow_env_build_does_not_turn_a_task_into_a_timeout(backend, tiny_suite, tmp_path, monkeypatch):
    """Each task's env takes 6 s, twice the 3 s limit, as a loaded machine's env build may:
    the limit counts the method's run from its start in the worker, so the raising task is
    an exception, the quick one a result, and the hanging method still a timeout."""
    faults = {"tiny/0000": "raise", "tiny/0001": "hang"}
    monkeypatch.setenv("FETCHBENCH_TEST_FAULTS", json.dumps({str(task_seed(k)): v for k, v in faults.items()}))
    monkeypatch.setenv("FETCHBENCH_TEST_SLOW_ENV", "6")
    records = evaluate("evaluation_faults:faulty", tmp_path, suite=str(tiny_suite), tasks="0:3", workers=1,
                       backend=backend, task_timeout=3, progress=False)
    kinds = {r["task_id"]: (r.get("error") or {}).get("kind") for r in records}
    assert kinds == {"tiny/0000": "exception", "tiny/0001": "timeout", "tiny/0002": None}
    assert records[1]["error"]["message"] == "ran past the task time limit of 3 s"
    assert records[1]["wall_time"] >= 6 + 3


def test_eval_help_shows_the_numeric_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["eval", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for default in ("one core each (default 1)", "number of seeds (default 10)", "first seed (default 0)",
                    "'timeout' (default 600.0)", "tries per task (default 1;"):
        assert default in text


def test_demo_sets_an_outdated_run_aside_and_starts_afresh(tiny_suite, idle_reference, tmp_path, capsys):
    # A results folder left by an earlier install (another suite content) must neither
    # stop the main job nor be deleted.
    from fetchbench_ms.demo import run_demo

    out = tmp_path / "demo"
    old = make_suite(tmp_path / "old.json", [11])
    evaluate("idle", out / "results", suite=str(old), workers=1, progress=False)
    old_lines = (out / "results" / "results.jsonl").read_text()
    assert run_demo(out, method="idle", suite=str(tiny_suite), workers=2, render=False) == 0
    assert (out / "results.previous-1" / "results.jsonl").read_text() == old_lines
    assert comparable(ResultsStore(out / "results").records()) == idle_reference
    assert (out / "report" / "index.html").exists()
    assert "starts afresh" in capsys.readouterr().out
