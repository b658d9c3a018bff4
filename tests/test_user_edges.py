"""The user's edges (issue 40): bad files and paths end in one line and exit 2, never in a
traceback or a success; the demos' .h5/.json pair is consistent for readers even across a
kill; written files follow the umask."""
from __future__ import annotations

import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from fetchbench_ms.cli import main

REPO = Path(__file__).resolve().parent.parent
SAMPLE = REPO / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
ENV = {**os.environ, "PYTHONPATH": str(REPO)}


def _one_error_line(err: str, prefix: str = "fetchbench: error: ") -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert "Traceback" not in err, err[-3000:]
    assert len(lines) == 1 and lines[0].startswith(prefix), err[-3000:]
    return lines[0]


def _cli(*args, without_root_powers=False, timeout=300):
    """``python -m fetchbench_ms ARGS`` in a fresh process. ``without_root_powers``: as root,
    without the capabilities that let root write where permissions say no (file modes bind)."""
    prefix = []
    if without_root_powers and os.geteuid() == 0:
        prefix = ["setpriv", "--bounding-set=-dac_override,-dac_read_search"]
    return subprocess.run([*prefix, sys.executable, "-m", "fetchbench_ms", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, env=ENV, cwd=REPO)


def _copy_sample(folder: Path, name: str = "sample") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for suffix in (".h5", ".json"):
        shutil.copy(SAMPLE.with_suffix(suffix), folder / f"{name}{suffix}")
    return folder / f"{name}.h5"


@pytest.fixture
def truncated(tmp_path) -> Path:
    """The shipped sample with its .h5 cut to half its size (its .json intact)."""
    path = _copy_sample(tmp_path / "trunc")
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size // 2)
    return path


# ----------------------------------------------------------------------------- demos: paths
def test_record_dir_that_is_a_file(tmp_path, capsys):
    target = tmp_path / "afile"
    target.write_text("x")
    assert main(["demos", "run", "--record-dir", str(target), "-n", "1", "--no-progress"]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "is a file" in line and "valid: a folder" in line
    assert target.read_text() == "x"


def test_record_dir_without_write_permission(tmp_path):
    folder = tmp_path / "locked"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        out = _cli("demos", "run", "--record-dir", folder, "-n", "1", "--no-progress", without_root_powers=True)
    finally:
        folder.chmod(0o755)
    assert out.returncode == 2, out.stderr[-3000:]
    line = _one_error_line(out.stderr)
    assert "not writable" in line and "Permission denied" in line
    assert list(folder.iterdir()) == []


# ----------------------------------------------------------------------------- demos: files
def test_stats_checks_the_h5_itself(truncated, tmp_path, capsys):
    assert main(["demos", "stats", str(SAMPLE)]) == 0  # the intact sample passes
    capsys.readouterr()
    assert main(["demos", "stats", str(truncated)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "is not a readable trajectory file" in line and "truncated" in line
    fake = _copy_sample(tmp_path / "fake")
    fake.write_text("not an HDF5 file\n")
    assert main(["demos", "stats", str(fake)]) == 2
    assert "is not a readable trajectory file" in _one_error_line(capsys.readouterr().err)


def test_stats_refuses_an_h5_that_lacks_listed_trajectories(tmp_path, capsys):
    path = _copy_sample(tmp_path / "cut")
    with h5py.File(path, "a") as f:
        del f["traj_3"]
    assert main(["demos", "stats", str(path)]) == 2
    assert "traj_3" in _one_error_line(capsys.readouterr().err)


def test_show_on_a_truncated_file(truncated, tmp_path, capsys):
    assert main(["demos", "show", str(truncated), "--out", str(tmp_path / "v.gif")]) == 2
    assert "is not a readable trajectory file" in _one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "v.gif").exists()


def test_replay_tool_on_a_truncated_file(truncated):
    out = subprocess.run([sys.executable, "-m", "fetchbench_ms.replay_trajectory", "--traj-path", str(truncated),
                          "-o", "state", "--save-traj"], capture_output=True, text=True, timeout=300, env=ENV)
    assert out.returncode == 2, out.stderr[-3000:]
    assert "is not a readable trajectory file" in _one_error_line(out.stderr, "replay_trajectory: error: ")


# ----------------------------------------------------------------------------- demos: the pair under a kill
def _fake_parts(record_dir: Path, seeds: range) -> None:
    """Finished generator parts (one per task seed) cut from the shipped sample's trajectories."""
    from fetchbench_ms.demos.generate import parts_dir, part_path

    meta = json.loads(SAMPLE.with_suffix(".json").read_text())
    parts = parts_dir(record_dir, "FetchBench-v0", "trajectory")
    parts.mkdir(parents=True, exist_ok=True)
    with h5py.File(SAMPLE, "r") as source:
        for seed in seeds:
            episode = {**meta["episodes"][seed], "episode_id": 0}
            path = part_path(parts, seed)
            with h5py.File(path, "w") as f:
                source.copy(f"traj_{seed}", f, "traj_0")
            summary = {"seed": seed, "task_id": episode.get("task_id"), "tries": 1, "successes": 1,
                       "frames": episode["elapsed_steps"], "failures": {}}
            path.with_suffix(".json").write_text(json.dumps({
                "env_info": meta["env_info"], "source_type": meta.get("source_type"),
                "source_desc": meta.get("source_desc"), "episodes": [episode],
                "fetchbench": {"summary": summary}}))


KILLED_MERGE = textwrap.dedent("""
    import importlib, os, signal, sys
    generate = importlib.import_module("fetchbench_ms.demos.generate")
    real = os.replace
    def replace(src, dst):
        real(src, dst)
        if str(dst).endswith("trajectory.h5"):  # the .h5 is in, its .json not yet
            os.kill(os.getpid(), signal.SIGKILL)
    generate.os.replace = replace
    generate.merge(sys.argv[1], "FetchBench-v0", "trajectory", int(sys.argv[2]))
""")


def test_demos_pair_stays_consistent_for_readers_across_a_kill(tmp_path, capsys):
    from fetchbench_ms.demos.generate import merge
    from fetchbench_ms.demos.stats import check_trajectory_file, demo_stats

    record_dir = tmp_path / "demos"
    _fake_parts(record_dir, range(3))
    out = merge(record_dir, "FetchBench-v0", "trajectory", 3)
    assert demo_stats(out)["trajectories"] == 3
    _fake_parts(record_dir, range(3, 6))
    killed = subprocess.run([sys.executable, "-c", KILLED_MERGE, str(record_dir), "6"], capture_output=True,
                            text=True, timeout=300, env=ENV)
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-3000:]
    with h5py.File(out, "r") as f:  # the kill came between the renames: a new .h5 beside the old .json
        assert len([k for k in f if k.startswith("traj_")]) == 6
    assert len(json.loads(out.with_suffix(".json").read_text())["episodes"]) == 3
    with pytest.raises(ValueError, match="were not written together"):
        check_trajectory_file(out)
    assert main(["demos", "stats", str(out)]) == 2
    assert "were not written together" in _one_error_line(capsys.readouterr().err)
    merge(record_dir, "FetchBench-v0", "trajectory", 6)  # what a rerun of `demos run` does last
    assert demo_stats(out)["trajectories"] == 6


# ----------------------------------------------------------------------------- eval: a bad checkpoint
def test_eval_with_a_truncated_policy_checkpoint_fails_before_any_task(tmp_path):
    from fetchbench_ms.utils.packed import file_bytes, packed_or_plain

    checkpoint = tmp_path / "policy.pt"
    data = file_bytes(packed_or_plain(REPO / "assets/checkpoints/imit_mlp.pt"))
    checkpoint.write_bytes(data[: len(data) // 2])
    t0 = time.perf_counter()
    out = _cli("eval", "--method", "e2e-mlp", "--suite", "smoke", "--tasks", "0:2", "--workers", "1",
               "--policy-checkpoint", checkpoint, "--out", tmp_path / "eval")
    assert out.returncode == 2, (out.stdout[-2000:], out.stderr[-3000:])
    line = _one_error_line(out.stderr)
    assert "is not a readable policy checkpoint" in line and str(checkpoint) in line
    assert not (tmp_path / "eval" / "results.jsonl").exists()
    assert time.perf_counter() - t0 < 120


# ----------------------------------------------------------------------------- envs: one vocabulary or the other
def test_env_category_accepts_both_vocabularies():
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401

    for env_id, category in (("FetchBench-v0", "on_shelf"), ("FetchBench-Shelf-v0", "on_shelf"),
                             ("FetchBench-v0", "Shelf")):
        env = gym.make(env_id, category=category, obs_mode="none", render_backend="none")
        try:
            env.reset(seed=3)
            assert env.unwrapped.category == "Shelf" and env.unwrapped._tasks[0].target_label == "on_shelf"
        finally:
            env.close()
    with pytest.raises(ValueError, match="make FetchBench-Table-v0 or FetchBench-v0 with category='Table'"):
        gym.make("FetchBench-Shelf-v0", category="on_table", obs_mode="none", render_backend="none")
    with pytest.raises(ValueError, match="valid: Table, Shelf, Drawer, Basket .or the target labels on_table"):
        gym.make("FetchBench-v0", category="shelves", obs_mode="none", render_backend="none")


# ----------------------------------------------------------------------------- permissions
@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_written_files_follow_the_umask(tmp_path, umask):
    from fetchbench_ms.utils.io import atomic_write_bytes, atomic_write_text

    old = os.umask(umask)
    try:
        atomic_write_bytes(tmp_path / "a.png", b"png")
        atomic_write_text(tmp_path / "job.json", "{}")
    finally:
        os.umask(old)
    for name in ("a.png", "job.json"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o666 & ~umask, name


def test_report_shows_paper_rows_and_no_absolute_paths(tmp_path):
    from fetchbench_ms.evaluation import ResultsStore
    from fetchbench_ms.evaluation.report import build_report

    def run(folder, method, pipeline):
        store = ResultsStore(tmp_path / folder)
        store.open_run({"method": method, "source": "/home/someone/fetchbench/assets/suites/test.json.gz",
                        "source_sha256": "0123456789abcdef" * 4,
                        "method_options": {"retries": 1, "pipeline": pipeline}, "selection": {"suite": "test",
                                                                                             "tasks": "0:2"}})
        for i in range(2):
            store.append({"task_id": f"test/{i:04d}", "seed": i, "env_id": "FetchBench-v0", "method": method,
                          "success": i == 0, "failure": None if i == 0 else "grasp_failure", "category": "on_shelf",
                          "scene_type": "LargeShelf", "computation_time": 1.0, "cspace_length": 2.0,
                          "phases": {"pregrasp_plan": True, "approach_reached": True}})
        return tmp_path / folder

    old = os.umask(0o022)
    try:
        page = build_report([run("paper", "ga-mesh-rrt", "paper"), run("ours", "ga-mesh-rrt", "ours")],
                            tmp_path / "report", render=False)
    finally:
        os.umask(old)
    text = page.read_text()
    assert "/home/someone" not in text and str(tmp_path) not in text
    assert "suite test (sha256 0123456789ab)" in text and "../paper" in text
    # one paper row, for the paper variant only: 52.9 % (GA-Mesh-RRTConnect), its funnel 94.7 / 90.3 / 68.1 %
    assert text.count("FetchBench paper: ga-mesh-rrt") == 2  # the success table and the funnel
    assert "52.9%" in text and "94.7%" in text and "68.1%" in text
    for path in page.parent.iterdir():
        assert stat.S_IMODE(path.stat().st_mode) == 0o644, path


# ----------------------------------------------------------------------------- runs that do nothing
def _load_script(path: Path, name: str):
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_ppo_time_limit_counts_training_only_and_a_run_with_nothing_to_train_fails(tmp_path):
    """Start-up (env workers, first reset) takes seconds, far past a 1 ms limit: the run still
    trains (one iteration, then the limit stops it). Resuming a finished run trains nothing:
    one line and exit 1, before any env starts. rl_curve plots that short run where it ended
    and refuses an empty one."""
    ppo = _load_script(REPO / "baselines/ppo/ppo.py", "ppo")
    args = ppo.Args(out_dir=str(tmp_path / "run"), num_envs=2, num_eval_envs=1, num_eval_episodes=1, num_steps=8,
                    num_minibatches=2, update_epochs=1, total_timesteps=48, eval_freq=0, max_episode_steps=6,
                    cuda=False, hidden=32, time_limit=0.001)
    result = ppo.main(args)
    assert result["trained_iterations"] == 1 and result["stopped_by_time"]
    assert result["state"]["global_step"] == 16
    flags = ["--out-dir", str(tmp_path / "run"), "--num-envs", "2", "--num-steps", "8", "--num-minibatches", "2",
             "--total-timesteps", "16", "--no-cuda"]
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, str(REPO / "baselines/ppo/ppo.py"), *flags], capture_output=True, text=True,
                         timeout=300, env=ENV, cwd=REPO)
    assert out.returncode == 1, out.stderr[-3000:]
    assert "trained 0 iterations" in out.stderr and "already at iteration 1 of 1" in out.stderr
    assert time.perf_counter() - t0 < 60  # no env was started

    curve = _load_script(REPO / "scripts/rl_curve.py", "rl_curve")
    train = curve.read(tmp_path / "run" / "train.csv")
    assert [b["steps"] for b in curve.binned(train, 10_000)] == [16]  # where the run ended, not 10,000
    assert curve.main([str(tmp_path / "run"), "--png", str(tmp_path / "curve.png")]) == 0
    assert (tmp_path / "curve.png").stat().st_size > 1000
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "train.csv").write_text(",".join(ppo.TRAIN_FIELDS) + "\n")
    assert curve.main([str(empty), "--png", str(tmp_path / "empty.png")]) == 2
    assert not (tmp_path / "empty.png").exists()


# ----------------------------------------------------------------------------- docs run as pasted
def _doc_block(doc: Path, heading: str) -> str:
    """The first ```python block after ``heading`` in ``doc``."""
    text = doc.read_text()
    rest = text[text.index(heading):]
    start = rest.index("```python\n") + len("```python\n")
    return rest[start: rest.index("```", start)]


def test_make_vec_env_example_of_docs_envs_runs_as_pasted(tmp_path):
    script = tmp_path / "vec_example.py"
    script.write_text(_doc_block(REPO / "docs/envs.md", "## Many environments on the CPU")
                      + "    print('ok', obs.shape, reward.shape)\n")
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600, env=ENV,
                         cwd=tmp_path)
    assert out.returncode == 0 and "ok (2," in out.stdout, out.stderr[-3000:]
    assert "Traceback" not in out.stderr


def test_fetch_clouds_reads_compact_pointcloud_obs():
    import gymnasium as gym

    import fetchbench_ms

    env = gym.make("FetchBench-v0", obs_mode="compact_pointcloud")
    try:
        obs, _ = env.reset(seed=3)
    finally:
        env.close()
    clouds = fetchbench_ms.envs.fetch_clouds(obs)
    seg = obs["pointcloud"]["seg"][0].cpu().numpy()
    from fetchbench_ms.envs.pointcloud import COMPACT_SIZES, LABEL_TARGET

    assert len(clouds.target) == COMPACT_SIZES["target"] == int((seg == LABEL_TARGET).sum())
    assert len(clouds.scene) > 0 and len(clouds.robot) > 0 and clouds.scene.dtype == np.float32
    assert clouds.target_segmentation_id == int(obs["extra"]["target_segmentation_id"][0])
    with pytest.raises(ValueError, match="obs_mode='pointcloud' or 'compact_pointcloud'"):
        fetchbench_ms.envs.fetch_clouds({"agent": {}})


def test_grasps_predict_writes_the_grasps_and_the_inference_time(tmp_path, capsys):
    old = os.umask(0o022)
    try:
        assert main(["grasps", "predict", "smoke/0003", "--grasp-model", "ours", "--out", str(tmp_path / "g.png"),
                     "--grasps-out", str(tmp_path / "g.json")]) == 0
    finally:
        os.umask(old)
    out = capsys.readouterr().out
    assert "inference" in out and "model load" in out
    body = json.loads((tmp_path / "g.json").read_text())
    n = body["grasps"]
    assert n > 0 and len(body["T_base_hand"]) == len(body["widths"]) == len(body["scores"]) == n
    assert np.asarray(body["T_base_hand"]).shape == (n, 4, 4) and body["scores"] == sorted(body["scores"], reverse=True)
    for name in ("g.png", "g.json"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == 0o644
    assert main(["grasps", "predict", "smoke/0003", "--out", str(tmp_path / "h.png"), "--grasps-out",
                 str(tmp_path / "h.csv")]) == 2
    assert "valid: .npz, .json" in _one_error_line(capsys.readouterr().err)


# ----------------------------------------------------------------------------- long silences
def test_a_long_evaluation_task_reports_its_control_steps():
    from fetchbench_ms.evaluation.local import PROGRESS_AFTER, run_local
    from fetchbench_ms.evaluation.methods import resolve_run
    from fetchbench_ms.evaluation.runner import open_suite, suite_items

    suite, _, _ = open_suite("smoke")
    items = suite_items(suite, range(1))
    records, news = [], []
    run_local(resolve_run("evaluation_faults:slow_steps"), items, records.append, workers=1, task_timeout=300,
              on_progress=lambda task_id, steps, seconds: news.append((task_id, steps, seconds)))
    assert len(records) == 1 and not records[0].get("error"), records
    assert news and all(t == items[0].task_id and s >= PROGRESS_AFTER for t, _, s in news)
    steps = [n for _, n, _ in news]
    assert steps == sorted(steps) and steps[-1] > 0  # the episode's control steps, growing


MAKE_TWO_ENVS = textwrap.dedent("""
    import gymnasium as gym, fetchbench_ms
    for seed in range(2):
        env = gym.make("FetchBench-v0", obs_mode="rgb")
        env.reset(seed=seed)
        env.close()
""")


def test_expected_cpu_machine_warnings_are_one_line(tmp_path):
    """ManiSkill's 'CUDA device was not found' (each env), 'not installed with git' (each
    recorder) and 'does not support rendering' (each env without a renderer): on a CPU machine
    one line says what renders; a replay says nothing of them."""
    from fetchbench_ms.utils.sapien_device import render_device

    out = subprocess.run([sys.executable, "-c", MAKE_TWO_ENVS], capture_output=True, text=True, timeout=600,
                         env=ENV, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "CUDA device was not found" not in out.stderr
    assert out.stderr.count("fetchbench: no CUDA device here") == (0 if render_device().is_cuda() else 1)
    path = _copy_sample(tmp_path / "replay")
    out = subprocess.run([sys.executable, "-m", "fetchbench_ms.replay_trajectory", "--traj-path", str(path), "-o",
                          "state", "--count", "1", "--save-traj"], capture_output=True, text=True, timeout=600, env=ENV)
    assert out.returncode == 0 and "1/1" in out.stdout + out.stderr, out.stderr[-3000:]
    for noise in ("not installed with git", "does not support rendering", "CUDA device was not found"):
        assert noise not in out.stdout + out.stderr, noise


BAD_FLAGS = textwrap.dedent("""
    import sys
    from fetchbench_ms.cli import main
    codes = []
    for argv in (["eval", "--bogus"], ["eval", "--pipeline", "nope"], ["demos", "run", "--num-procs", "x"],
                 ["demos", "stats", "/no/such/file.h5"], ["scenes", "nope"]):
        try:
            codes.append(main(argv))
        except SystemExit as exit:
            codes.append(exit.code)
    heavy = sorted(m for m in ("torch", "mani_skill", "sapien", "trimesh") if m in sys.modules)
    print(codes, heavy)
""")


def test_bad_flags_are_answered_before_torch_and_the_simulator_load():
    out = subprocess.run([sys.executable, "-c", BAD_FLAGS], capture_output=True, text=True, timeout=120, env=ENV)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.strip() == "[2, 2, 2, 2, 2] []", out.stdout


PLANNER_OPTION_ERRORS = textwrap.dedent("""
    import contextlib, io, json, sys
    from fetchbench_ms.cli import main
    answers = []
    for method, option in (("cgn-ptd-mppi", "mppi_goal_radius=0"), ("cgn-ptd-mppi", "mppi_goal_region=-1"),
                           ("ga-ptd-mppi", "mppi_cost=nets"), ("ga-mesh-rrt", "mppi_goal_region=0"),
                           ("ga-mesh-trajopt", "trajopt_counts=8x40"), ("cgn-imit-mlp", "trajopt_counts=8x0x2"),
                           ("ga-mesh-rrt", "trajopt_counts=8x40x2"), ("ga-ptd-trajopt", "trajopt_loop=compiled"),
                           ("ga-mesh-trajopt", "trajopt_certify=0"), ("cgn-ptd-trajopt", "trajopt_certify=on")):
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            code = main(["eval", "--method", method, "--suite", "val", "--tasks", "0:100",
                         "--planner-option", option, "--out", sys.argv[1]])
        answers.append([code, err.getvalue()])
    heavy = sorted(m for m in ("torch", "mani_skill", "sapien", "trimesh") if m in sys.modules)
    print(json.dumps([answers, heavy]))
""")


def test_bad_planner_options_are_one_line_before_torch_loads(tmp_path):
    """An unknown key, a bad value, a key for a method it does not apply to: exit 2 and one
    line that names the valid choices, before torch and the simulator load; nothing written."""
    out = subprocess.run([sys.executable, "-c", PLANNER_OPTION_ERRORS, str(tmp_path / "eval")], capture_output=True,
                         text=True, timeout=120, env=ENV)
    assert out.returncode == 0, out.stderr[-3000:]
    answers, heavy = json.loads(out.stdout)
    assert heavy == []
    assert [code for code, _ in answers] == [2] * 10
    lines = [_one_error_line(err) for _, err in answers]
    valid = ("valid: mppi_goal_region=RAD (>= 0; 0 switches the goal credit off); mppi_cost=network|distance; "
             "trajopt_counts=SEEDSxITERSxSUBSTEPS (whole counts >= 1, e.g. 16x80x3); trajopt_loop=eager|graph|grid|cpu; "
             "trajopt_certify=RAD (> 0, the bisection floor)|off")
    assert "unknown planner option 'mppi_goal_radius'" in lines[0] and lines[0].endswith(valid)
    assert "mppi_goal_region=-1: bad value" in lines[1] and lines[1].endswith(valid)
    assert "mppi_cost=nets: bad value" in lines[2] and lines[2].endswith(valid)
    assert lines[3].endswith("'mppi_goal_region' applies to cgn-ptd-mppi, ga-ptd-mppi, ga-mesh-mppi, not ga-mesh-rrt")
    assert "trajopt_counts=8x40: bad value" in lines[4] and lines[4].endswith(valid)
    assert "trajopt_counts=8x0x2: bad value" in lines[5] and lines[5].endswith(valid)  # the hybrids take it
    assert "'trajopt_counts' applies to ga-mesh-trajopt, " in lines[6] and ", cgn-imit-mlp, " in lines[6]
    assert lines[6].endswith("not ga-mesh-rrt")
    assert "trajopt_loop=compiled: bad value" in lines[7] and lines[7].endswith(valid)
    assert "trajopt_certify=0: bad value" in lines[8] and lines[8].endswith(valid)
    assert "trajopt_certify=on: bad value" in lines[9] and lines[9].endswith(valid)
    assert not (tmp_path / "eval").exists()


def test_planner_options_spell_the_planners_methods_costs_and_fields():
    """solutions.planner_options spells out what torch-loading modules define."""
    import dataclasses

    from fetchbench_ms.planning.mppi import COSTS
    from fetchbench_ms.planning.trajopt import COUNT_FIELDS, FULL_COUNTS, LOOPS, TrajoptConfig, counts_config, counts_of
    from fetchbench_ms.method_spec import PLANNERS
    from fetchbench_ms.solutions.planner_options import (MPPI_COSTS, PLANNER_OPTIONS, TRAJOPT_LOOPS,
                                                         check_trajopt_certify, check_trajopt_counts,
                                                         check_trajopt_loop)
    from fetchbench_ms.solutions.sense_plan_act import SolveConfig

    assert {o for p in PLANNERS.values() for o in p.options} <= set(PLANNER_OPTIONS)
    assert MPPI_COSTS == tuple(COSTS)
    assert set(PLANNER_OPTIONS) <= {f.name for f in dataclasses.fields(SolveConfig)}
    # trajopt_counts names TrajoptConfig's count fields, in order, written plainly
    assert set(COUNT_FIELDS) <= {f.name for f in dataclasses.fields(TrajoptConfig)} and set(FULL_COUNTS) == set(COUNT_FIELDS)
    counts = check_trajopt_counts(" 016x80 x3")
    assert counts == "16x80x3" and counts_config(counts) == TrajoptConfig(**FULL_COUNTS)
    default = TrajoptConfig()
    assert check_trajopt_counts(counts_of(default)) == counts_of(default) == "8x40x2"
    assert counts_config(None) == default
    # trajopt_loop names the loops of trajopt.LOOPS, each a set of TrajoptConfig fields
    assert TRAJOPT_LOOPS == tuple(LOOPS) and check_trajopt_loop(" graph ") == "graph"
    assert all(TrajoptConfig(**fields) for fields in LOOPS.values()) and LOOPS["eager"] == {}
    # trajopt_certify is TrajoptConfig.certify's floor, a float (folder names read 0.005), or off
    assert check_trajopt_certify(" 0.005 ") == 0.005 and check_trajopt_certify(" off") == "off"
    assert TrajoptConfig(certify=check_trajopt_certify("1e-3")).certify == 0.001


def test_ppo_bad_flags_are_one_line_before_torch_loads():
    probe = textwrap.dedent("""
        import runpy, sys
        sys.argv = ["ppo.py", "--num-minibatches", "3"]
        try:
            runpy.run_path("baselines/ppo/ppo.py", run_name="__main__")
        except SystemExit as exit:
            print("exit", exit.code, "torch" in sys.modules, "mani_skill" in sys.modules)
    """)
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, env=ENV,
                         cwd=REPO)
    assert out.stdout.strip() == "exit 2 False False", (out.stdout, out.stderr[-2000:])
    assert "not divisible by num_minibatches 3" in _one_error_line(out.stderr, "ppo.py: error: ")


# ----------------------------------------------------------------------------- ManiSkill's own baselines
MANISKILL_EVAL_CONTRACT = textwrap.dedent("""
    # What ManiSkill's examples/baselines (bc.py, diffusion_policy/train.py, act/train.py) do with
    # the env and the demos on the CPU, step for step:
    # - read the converted demos: the control mode from the JSON's env kwargs, then per trajectory
    #   obs (one more than actions), actions and success;
    # - make the evaluation envs as their make_eval_envs() does: gym.make(env_id,
    #   reconfiguration_freq=1, control_mode, reward_mode="sparse", obs_mode="state",
    #   render_mode="rgb_array", max_episode_steps[, human_render_camera_configs]), diffusion
    #   policy's FrameStack, CPUGymWrapper(ignore_terminations=True, record_metrics=True),
    #   RecordEpisode with info on the video on env 0, spaces seeded, in a plain gymnasium vector
    #   env (no autoreset argument): SyncVectorEnv for one env, AsyncVectorEnv on forkserver
    #   workers for more;
    # - size the policy from the env's spaces and train it on the demos (same dims), diffusion
    #   policy asserting actions in [-1, 1];
    # - evaluate: step until truncation, ACT counting each episode's steps to index its action
    #   table, then read info["final_info"]: one dict per env with its "episode" metrics.
    import json
    import sys

    import gymnasium as gym
    import h5py
    import numpy as np
    from mani_skill.utils.wrappers import CPUGymWrapper, FrameStack, RecordEpisode

    MAX_STEPS = 3


    def make_thunk(env_id, seed, env_kwargs, video_dir, obs_horizon):
        def thunk():
            env = gym.make(env_id, reconfiguration_freq=1, **env_kwargs)
            if obs_horizon:
                env = FrameStack(env, num_stack=obs_horizon)
            env = CPUGymWrapper(env, ignore_terminations=True, record_metrics=True)
            if video_dir:
                env = RecordEpisode(env, output_dir=video_dir, save_trajectory=False, info_on_video=True,
                                    source_type="contract", source_desc="evaluation rollout")
            env.action_space.seed(seed)
            env.observation_space.seed(seed)
            return env
        return thunk


    if __name__ == "__main__":
        demo_path, num_envs, obs_horizon, video_dir = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
        meta = json.load(open(demo_path[:-2] + "json"))
        env_info = meta["env_info"]
        # the scripts' --env-id: the file's id, or the one a user types (argv 5)
        env_id = sys.argv[5] if len(sys.argv) > 5 else env_info["env_id"]
        control_mode = env_info["env_kwargs"]["control_mode"]
        with h5py.File(demo_path, "r") as f:
            traj = f[f"traj_{meta['episodes'][0]['episode_id']}"]
            obs, actions, success = traj["obs"][:], traj["actions"][:], traj["success"][:]
        assert len(obs) == len(actions) + 1 and len(success) == len(actions), (obs.shape, actions.shape)

        env_kwargs = dict(control_mode=control_mode, reward_mode="sparse", obs_mode="state", render_mode="rgb_array",
                          max_episode_steps=MAX_STEPS)
        if obs_horizon:
            env_kwargs["human_render_camera_configs"] = dict(shader_pack="default")
        thunks = [make_thunk(env_id, seed, env_kwargs, video_dir if seed == 0 else None, obs_horizon)
                  for seed in range(num_envs)]
        envs = (gym.vector.SyncVectorEnv(thunks) if num_envs == 1
                else gym.vector.AsyncVectorEnv(thunks, context="forkserver"))
        space, action_space = envs.single_observation_space, envs.single_action_space
        assert space.shape == (obs_horizon,) * bool(obs_horizon) + obs.shape[1:], (space.shape, obs.shape)
        assert action_space.shape == actions.shape[1:], (action_space.shape, actions.shape)
        assert (action_space.high == 1).all() and (action_space.low == -1).all()
        assert np.abs(actions).max() <= 1

        envs.reset(seed=1)
        lengths, metrics, step = [], {}, 0
        while len(lengths) < 2 * num_envs:
            o, _, _, truncated, info = envs.step(np.repeat(actions[step][None], num_envs, axis=0))
            step += 1
            assert o.shape == (num_envs,) + space.shape
            if truncated.any():
                assert truncated.all() and step == MAX_STEPS, (truncated, step)
                finals = info["final_info"]
                assert len(finals) == num_envs
                for final in finals:
                    for k, v in final["episode"].items():
                        metrics.setdefault(k, []).append(float(v))
                    lengths.append(int(final["episode"]["episode_len"]))
                step = 0
        envs.close()
        print("episode lengths", lengths)
        print("metrics", sorted(metrics), {k: float(np.mean(v)) for k, v in metrics.items()})
""")


@pytest.fixture(scope="module")
def converted_sample(tmp_path_factory) -> Path:
    """The sample's first demo converted as docs/demos.md tells a user (state, pd_joint_delta_pos)."""
    path = _copy_sample(tmp_path_factory.mktemp("baselines-demos"))
    out = subprocess.run([sys.executable, "-m", "fetchbench_ms.replay_trajectory", "--traj-path", str(path), "-o",
                          "state", "-c", "pd_joint_delta_pos", "--save-traj", "--count", "1"],
                         capture_output=True, text=True, timeout=600, env=ENV)
    assert out.returncode == 0, out.stderr[-3000:]
    converted = path.with_name("sample.state.pd_joint_delta_pos.physx_cpu.h5")
    assert converted.is_file() and converted.with_suffix(".json").is_file()
    return converted


@pytest.mark.parametrize("num_envs, obs_horizon", [(1, 0), (2, 2)], ids=["bc-act", "diffusion-policy-2-envs"])
def test_maniskill_baselines_launcher_runs_their_evaluation_on_the_converted_demos(tmp_path, converted_sample,
                                                                                   num_envs, obs_horizon):
    script = tmp_path / "evaluate_like_maniskill.py"
    script.write_text(MANISKILL_EVAL_CONTRACT)
    videos = tmp_path / "videos"
    out = subprocess.run([sys.executable, "-m", "fetchbench_ms.maniskill_baselines", str(script), str(converted_sample),
                          str(num_envs), str(obs_horizon), str(videos)],
                         capture_output=True, text=True, timeout=600, env=ENV, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-3000:]
    # two episodes an env, each ended at max_episode_steps in the step that truncated it
    assert f"episode lengths {[3] * 2 * num_envs}" in out.stdout, out.stdout[-2000:]
    # what bc/diffusion policy/ACT print and keep the best checkpoint by
    assert "metrics ['episode_len', 'return', 'reward', 'success_at_end', 'success_once']" in out.stdout
    assert [p.stat().st_size > 0 for p in videos.glob("*.mp4")] == [True, True]  # env 0's two episodes


def test_maniskill_baselines_fail_without_the_launcher(tmp_path, converted_sample):
    """Each of the launcher's two fixes is needed: without it the plain ids a user passes
    (`--env-id FetchBench-v0`) are unknown; with the plugin imported but gymnasium 1.x's vector
    env as it is, their evaluate() finds no final_info."""
    script = tmp_path / "evaluate_like_maniskill.py"
    script.write_text(MANISKILL_EVAL_CONTRACT)
    args = [str(script), str(converted_sample), "1", "0", "", "FetchBench-v0"]
    plain = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=600, env=ENV,
                           cwd=tmp_path)
    assert plain.returncode != 0, plain.stdout[-2000:]
    assert "NameNotFound: Environment `FetchBench` doesn't exist" in plain.stderr.strip().splitlines()[-1]
    imported = subprocess.run([sys.executable, "-c", "import runpy, sys; import fetchbench_ms; sys.argv = sys.argv[1:]; "
                               "runpy.run_path(sys.argv[0], run_name='__main__')", *args],
                              capture_output=True, text=True, timeout=600, env=ENV, cwd=tmp_path)
    assert imported.returncode != 0 and "KeyError: 'final_info'" in imported.stderr, imported.stderr[-2000:]


def test_maniskill_baselines_launcher_names_what_to_install(tmp_path, monkeypatch):
    """A script that imports what the [baselines] extra or torchvision of torch's build gives
    ends in one line with the pip command, not a traceback; a bad path likewise."""
    from fetchbench_ms import maniskill_baselines as launcher

    versions = {"torch": "2.13.0+cpu", "torchvision": "0.28.0"}
    monkeypatch.setattr(launcher.importlib.metadata, "version", lambda name: versions[name])
    missing = launcher.missing_dependency_message(ModuleNotFoundError("no", name="diffusers"), "diffusion_policy/train.py")
    assert missing.startswith("diffusion_policy/train.py imports diffusers") and '".[baselines]"' in missing
    assert launcher.missing_dependency_message(ModuleNotFoundError("no", name="torch.utils.tensorboard._x"), "b") is None
    tv = launcher.missing_dependency_message(ModuleNotFoundError("no", name="torchvision"), "act/train.py")
    assert tv.endswith('pip install "torchvision==0.28.0+cpu" --index-url https://download.pytorch.org/whl/cpu')
    other_build = launcher.missing_dependency_message(RuntimeError("operator torchvision::nms does not exist"), "x")
    assert other_build.startswith("torchvision 0.28.0 is not built for the installed torch 2.13.0+cpu")
    assert 'pip install --force-reinstall --no-deps "torchvision==0.28.0+cpu"' in other_build
    versions["torch"] = "2.14.1"
    assert launcher.torchvision_install_command() == 'pip install "torchvision==0.29.1"'
    versions["torch"] = "2.9.1+cu130"
    assert launcher.torchvision_install_command().endswith('"torchvision==0.24.1+cu130" --index-url '
                                                          'https://download.pytorch.org/whl/cu130')
    assert launcher.missing_dependency_message(RuntimeError("CUDA out of memory"), "x") is None
    assert launcher.missing_dependency_message(ModuleNotFoundError("no", name="numpyy"), "x") is None

    script = tmp_path / "train.py"
    script.write_text("import fetchbench_missing_dependency_probe\n")
    out = subprocess.run([sys.executable, "-c", "import sys; from fetchbench_ms import maniskill_baselines as m; "
                          "m.EXTRA_MODULES = ('fetchbench_missing_dependency_probe',); sys.exit(m.main(sys.argv[1:]))",
                          str(script)], capture_output=True, text=True, timeout=300, env=ENV)
    assert out.returncode == 2, out.stderr[-2000:]
    assert "fetchbench_missing_dependency_probe, which is not installed" in _one_error_line(
        out.stderr, "maniskill_baselines: error: ")
    bad = subprocess.run([sys.executable, "-m", "fetchbench_ms.maniskill_baselines", str(tmp_path / "none.py")],
                         capture_output=True, text=True, timeout=120, env=ENV)
    assert bad.returncode == 2 and "is not a Python file" in bad.stderr


def test_eval_where_every_task_ended_in_an_error_exits_non_zero(tmp_path, monkeypatch, capsys):
    from fetchbench_ms.evaluation.runner import open_suite, suite_items

    suite, _, _ = open_suite("smoke")
    seeds = [item.seed for item in suite_items(suite, range(2))]
    monkeypatch.setenv("FETCHBENCH_TEST_FAULTS", json.dumps({str(s): "raise" for s in seeds}))
    assert main(["eval", "--method", "evaluation_faults:faulty", "--suite", "smoke", "--tasks", "0:2",
                 "--out", str(tmp_path / "eval")]) == 1
    assert "every one of the 2 tasks ended in an error: nothing was evaluated" in capsys.readouterr().err


# ----------------------------------------------------------------------------- imitation conversion: other files
def _demo_pair(folder: Path, env_info: dict, episodes: list, steps: int = 4) -> Path:
    """A demo file of ``episodes`` (zero actions of ``steps`` steps each) and its JSON."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "demos.h5"
    with h5py.File(path, "w") as f:
        for e in episodes:
            f.create_dataset(f"traj_{e['episode_id']}/actions", data=np.zeros((steps, 8), np.float32))
    path.with_suffix(".json").write_text(json.dumps({"env_info": env_info, "episodes": episodes}))
    return path


def _conversion_refused(source: Path, out: Path) -> str:
    """The converter's one line for ``source``; nothing written."""
    from script_modules import import_script

    convert = import_script(REPO / "scripts/imitation/convert_demos_for_imitation.py")
    with pytest.raises(SystemExit) as excinfo:
        convert.main(["--traj-path", str(source), "--out", str(out)])
    message = excinfo.value.code
    assert isinstance(message, str) and "\n" not in message and "Traceback" not in message, message
    assert not out.exists()
    return message


def test_imitation_conversion_refuses_another_envs_demos(tmp_path):
    episode = {"episode_id": 0, "episode_seed": 0, "control_mode": "pd_joint_pos", "elapsed_steps": 4,
               "reset_kwargs": {"seed": 0}, "success": True}
    source = _demo_pair(tmp_path / "pickcube", {"env_id": "PickCube-v1", "env_kwargs": {
        "obs_mode": "none", "control_mode": "pd_joint_pos"}, "max_episode_steps": 50}, [episode])
    line = _conversion_refused(source, tmp_path / "out")
    assert "'PickCube-v1', not of a FetchBench env" in line and "valid: the demos `fetchbench demos run`" in line


def test_imitation_conversion_refuses_a_converted_file(tmp_path):
    """The replay tool's output (pd_joint_delta_pos, compact clouds) is not a source: it would
    convert to 0 frames, on which the trainers fail."""
    meta = json.loads(SAMPLE.with_suffix(".json").read_text())
    kwargs = {**meta["env_info"]["env_kwargs"], "control_mode": "pd_joint_delta_pos", "obs_mode": "compact_pointcloud"}
    episodes = [{**e, "control_mode": "pd_joint_delta_pos"} for e in meta["episodes"][:2]]
    source = _demo_pair(tmp_path / "converted", {**meta["env_info"], "env_kwargs": kwargs}, episodes)
    line = _conversion_refused(source, tmp_path / "out")
    assert "is a converted file (control mode pd_joint_delta_pos, obs mode compact_pointcloud)" in line
    assert "valid: the demos `fetchbench demos run` records" in line


def test_imitation_conversion_refuses_demos_without_stage_labels(tmp_path):
    source = _copy_sample(tmp_path / "unlabelled")
    first = json.loads(source.with_suffix(".json").read_text())["episodes"][0]["episode_id"]
    with h5py.File(source, "r+") as f:
        del f[f"traj_{first}/stage"]
    line = _conversion_refused(source, tmp_path / "out")
    assert f"traj_{first} carries no stage labels" in line


# ----------------------------------------------------------------------------- demos stats: other files
def test_demos_stats_refuses_another_envs_file(tmp_path, capsys):
    episode = {"episode_id": 0, "episode_seed": 0, "control_mode": "pd_joint_pos", "elapsed_steps": 4,
               "reset_kwargs": {"seed": 0}, "success": True}
    source = _demo_pair(tmp_path / "pickcube", {"env_id": "PickCube-v1", "env_kwargs": {}}, [episode])
    assert main(["demos", "stats", str(source)]) == 2
    assert "'PickCube-v1', not of a FetchBench env; valid:" in _one_error_line(capsys.readouterr().err)


def test_demos_stats_reads_a_converted_file(tmp_path, capsys):
    """The replay tool's conversion keeps each trajectory's task in its reset options only:
    its tasks, scene types and categories are those of its source; its C-space length is
    not recorded (no 'None rad')."""
    from fetchbench_ms.demos.stats import PAIR_ATTR, demo_stats

    source = demo_stats(SAMPLE)
    path = _copy_sample(tmp_path / "converted")
    meta = json.loads(path.with_suffix(".json").read_text())
    for e in meta["episodes"]:
        for key in ("task_id", "grasp_id", "scene_type", "category", "target_object", "cspace_length"):
            e.pop(key, None)
        e["control_mode"] = "pd_joint_delta_pos"
    path.with_suffix(".json").write_text(json.dumps(meta))
    with h5py.File(path, "r+") as f:  # the pair mark of a merged file names the old .json
        f.attrs.pop(PAIR_ATTR, None)
    stats = demo_stats(path)
    assert stats["tasks"] == source["tasks"] == 12
    assert stats["by_scene_type"] == source["by_scene_type"] and stats["by_category"] == source["by_category"]
    assert main(["demos", "stats", str(path)]) == 0
    out = capsys.readouterr().out
    assert "C-space length not recorded" in out and "None" not in out
