"""The Fetch dataset's generator: ManiSkill trajectories that ManiSkill's replay tool converts
and replays to success, resumable, the same bytes for the same tasks."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest

import fetchbench_ms  # noqa: F401
from fetchbench_ms.cli import main
from fetchbench_ms.demos.generate import DemoJob, done_parts, merge, parts_dir, suite_task_ids
from fetchbench_ms.solutions.expert import EXPERTS, solve, stage_end_flags
from fetchbench_ms.solutions.sense_plan_act import FAILURE_REASONS, STAGES

SUITE = "train"  # the demonstrations' suite (train-split tasks)
ENV_ID = "FetchBench-v0"


def _run(record_dir, n, name="trajectory", extra=()):
    args = ["demos", "run", "-e", ENV_ID, "--task-suite", SUITE, "-n", str(n), "--only-count-success",
            "--record-dir", str(record_dir), "--traj-name", name, "--per-task", "2", "--no-progress", *extra]
    assert main(args) == 0
    return Path(record_dir) / ENV_ID / "motionplanning" / f"{name}.h5"


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("demos"), 3)


def _replay(path, *args):
    """ManiSkill's replay tool (through the plugin's entry point); returns the output file."""
    out = subprocess.run([sys.executable, "-m", "fetchbench_ms.replay_trajectory", "--traj-path", str(path),
                          "--save-traj", *args], capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    line = [ln for ln in out.stdout.replace("\r", "\n").splitlines() if ln.startswith("Replayed")]
    return line[-1] if line else out.stdout[-2000:]


def test_files_are_maniskill_trajectories_with_stage_labels(demos):
    data = json.loads(demos.with_suffix(".json").read_text())
    env_info = data["env_info"]
    # ManiSkill's replay tool makes the env from these alone (gym.make imports the plugin)
    assert env_info["env_id"] == f"fetchbench_ms:{ENV_ID}" and env_info["max_episode_steps"] == 400
    assert "render_backend" not in env_info["env_kwargs"]
    assert env_info["env_kwargs"]["control_mode"] == "pd_joint_pos"
    assert env_info["env_kwargs"]["task_suite"] == SUITE
    assert "reward_mode" not in env_info["env_kwargs"]  # the generator's own env computes none; conversions get the default
    assert data["fetchbench"]["expert"] == EXPERTS["fast"].to_json()  # the expert configuration that made them
    part = next(parts_dir(demos.parents[2], ENV_ID, "trajectory").glob("task_*.json"))
    assert json.loads(part.read_text())["fetchbench"]["expert"]["name"] == "fast"
    for summary in done_parts(parts_dir(demos.parents[2], ENV_ID, "trajectory")).values():
        # every failed try has a class and a finer reason (solutions.sense_plan_act.FAILURE_REASONS)
        assert sum(summary["reasons"].values()) == sum(summary["failures"].values()) == \
            summary["tries"] - summary["successes"]
        assert all(r.split(":")[0] in FAILURE_REASONS + ("not_retrieved",) for r in summary["reasons"])
    eps = data["episodes"]
    assert len(eps) == 3 and all(e["success"] for e in eps)
    ids = suite_task_ids(ENV_ID, SUITE)
    with h5py.File(demos, "r") as f:
        for e in eps:
            assert e["reset_kwargs"]["options"]["task_id"] == ids[e["episode_seed"]] == e["task_id"]
            assert len(e["reset_kwargs"]["options"]["task_hash"]) == 16
            traj = f[f"traj_{e['episode_id']}"]
            n = e["elapsed_steps"]
            assert traj["actions"].shape == (n, 8) and traj["success"][-1] and not traj["truncated"][()].any()
            stage = traj["stage"][()]
            # approach, then close, then retrieve: one block each, in that order
            assert len(stage) == n and list(dict.fromkeys(stage.tolist())) == [0, 1, 2]
            assert (np.diff(stage) >= 0).all()
            assert traj["stage_end"][()].sum() == len(STAGES) and traj["stage_end"][-1]
    # two trajectories of one task use distinct grasps
    by_task = {}
    for e in eps:
        by_task.setdefault(e["task_id"], []).append(e["grasp_id"])
    assert all(len(set(g)) == len(g) for g in by_task.values()) and max(map(len, by_task.values())) == 2


def test_stage_end_flags():
    assert stage_end_flags(np.array([0, 0, 1, 2, 2])).tolist() == [False, True, True, False, True]


def test_replay_tool_converts_and_replays_to_success(demos):
    assert "3/3" in _replay(demos, "--use-env-states", "-o", "state")
    assert "3/3" in _replay(demos, "-c", "pd_joint_delta_pos", "-o", "state")
    converted = demos.with_name(f"{demos.stem}.state.pd_joint_delta_pos.physx_cpu.h5")
    data = json.loads(converted.with_suffix(".json").read_text())
    # what ManiSkill's own imitation baselines read from the json
    assert data["env_info"]["env_id"] == f"fetchbench_ms:{ENV_ID}" and data["env_info"]["max_episode_steps"] == 400
    assert data["env_info"]["env_kwargs"]["control_mode"] == "pd_joint_delta_pos"
    with h5py.File(converted, "r") as f:
        actions = f["traj_0"]["actions"][()]
    assert np.abs(actions[:, :7]).max() <= 1.0  # normalised deltas, none clipped past the limit


def test_resume_keeps_finished_parts_and_same_bytes(demos, tmp_path):
    """A second directory built in two steps (2, then 3) equals the one built at once."""
    path = _run(tmp_path, 2)
    parts = parts_dir(tmp_path, ENV_ID, "trajectory")
    first = {p.name: p.stat().st_mtime_ns for p in parts.glob("task_*")}
    # a killed worker's leftovers: a temp folder and an h5 without its json (not finished)
    (parts / ".tmp-999").mkdir()
    stray = parts / "task_000099.h5"
    stray.write_bytes(b"half")
    assert 99 not in done_parts(parts)
    path = _run(tmp_path, 3)
    assert {p.name: p.stat().st_mtime_ns for p in parts.glob("task_*") if p.name in first} == first
    assert not (parts / ".tmp-999").exists()
    with h5py.File(path, "r") as a, h5py.File(demos, "r") as b:
        assert list(a) == list(b)
        for k in a:
            assert np.array_equal(a[k]["actions"][()], b[k]["actions"][()])
            assert np.array_equal(a[k]["stage"][()], b[k]["stage"][()])
    strip = lambda d: {k: v for k, v in d.items() if k != "commit_info"}  # noqa: E731
    assert strip(json.loads(path.with_suffix(".json").read_text())) == strip(
        json.loads(demos.with_suffix(".json").read_text()))


def test_another_job_in_the_same_parts_is_refused(demos):
    record_dir = demos.parents[2]
    with pytest.raises(ValueError, match="another job"):
        from fetchbench_ms.demos.generate import generate

        generate(DemoJob(env_id=ENV_ID, task_suite=SUITE, per_task=1), record_dir, "trajectory", 1, progress=False)
    with pytest.raises(ValueError, match="another job"):  # the same job by another expert configuration
        generate(DemoJob(env_id=ENV_ID, task_suite=SUITE, per_task=2, expert="reference"), record_dir, "trajectory", 1,
                 progress=False)


def test_merge_cuts_at_n(demos):
    record_dir = demos.parents[2]
    out = merge(record_dir, ENV_ID, "trajectory", 1)
    assert len(json.loads(out.with_suffix(".json").read_text())["episodes"]) == 1
    merge(record_dir, ENV_ID, "trajectory", 3)  # leave the fixture as it was


def test_start_seed_runs_task_k_under_seed_k(demos, tmp_path, capsys):
    """``--start-seed K`` continues a run from 0: episode seed K is task K of the suite, with
    the same bytes as the run from 0 made for it (a dataset made in pieces on several
    machines must be what one run would have made)."""
    done0 = done_parts(parts_dir(demos.parents[2], ENV_ID, "trajectory"))
    k = max(done0)  # the fixture's last task, k >= 1
    assert k >= 1
    args = ["demos", "run", "-e", ENV_ID, "--task-suite", SUITE, "-n", "1", "--start-seed", str(k),
            "--record-dir", str(tmp_path), "--traj-name", "trajectory", "--per-task", "2", "--no-progress"]
    assert main(args) == 0
    done = done_parts(parts_dir(tmp_path, ENV_ID, "trajectory"))
    assert set(done) == {k}
    assert done[k]["task_id"] == done0[k]["task_id"] == suite_task_ids(ENV_ID, SUITE)[k]
    name = f"task_{k:06d}.h5"
    with h5py.File(parts_dir(tmp_path, ENV_ID, "trajectory") / name) as a, \
            h5py.File(parts_dir(demos.parents[2], ENV_ID, "trajectory") / name) as b:
        assert list(a) == list(b)
        for traj in a:
            np.testing.assert_array_equal(a[traj]["actions"][()], b[traj]["actions"][()])
    n_tasks = len(suite_task_ids(ENV_ID, SUITE))
    bad = [*args[:8], "--start-seed", str(n_tasks), *args[10:]]  # one past the last task
    assert main(bad) == 2
    assert f"valid: 0 .. {n_tasks - 1}" in capsys.readouterr().err


def test_runs_of_consecutive_task_ranges_merge_into_one_dataset(demos, tmp_path, capsys):
    """``fetchbench demos merge``: runs over tasks 0..k-1 and k.. (two holds) make the file one
    run over all of them makes; a gap or an overlap of tasks is refused."""
    import shutil

    parts = parts_dir(demos.parents[2], ENV_ID, "trajectory")
    k = max(done_parts(parts))
    for name in ("first", "second", "whole"):
        shutil.copytree(parts, parts_dir(tmp_path, ENV_ID, name))
    first = merge(tmp_path, ENV_ID, "first", k, only_count_success=False)  # tasks 0 .. k-1
    second = merge(tmp_path, ENV_ID, "second", 10**9, only_count_success=False, start_seed=k)
    whole = merge(tmp_path, ENV_ID, "whole", 10**9, only_count_success=False)
    out = tmp_path / "dataset" / "train.h5"
    assert main(["demos", "merge", str(second), str(first), "-o", str(out)]) == 0
    meta, meta_whole = (json.loads(p.with_suffix(".json").read_text()) for p in (out, whole))
    assert meta["fetchbench"]["tasks"] == meta_whole["fetchbench"]["tasks"] == k + 1
    assert [e["task_id"] for e in meta["episodes"]] == [e["task_id"] for e in meta_whole["episodes"]]
    with h5py.File(out) as a, h5py.File(whole) as b:
        assert list(a) == list(b)
        for traj in a:
            np.testing.assert_array_equal(a[traj]["actions"][()], b[traj]["actions"][()])
    assert main(["demos", "merge", str(first), str(first), "-o", str(tmp_path / "x.h5")]) == 2
    assert "back to back" in capsys.readouterr().err
    gap = json.loads(second.with_suffix(".json").read_text())
    gap["fetchbench"]["first_seed"] = k + 1
    second.with_suffix(".json").write_text(json.dumps(gap))
    assert main(["demos", "merge", str(first), str(second), "-o", str(tmp_path / "x.h5")]) == 2
    assert "back to back" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()


def test_bad_input_names_valid_choices(tmp_path, capsys):
    assert main(["demos", "run", "-e", "FetchBench-Nope-v0", "--record-dir", str(tmp_path), "--no-progress"]) == 2
    assert "valid: FetchBench-v0" in capsys.readouterr().err
    assert main(["demos", "run", "--task-suite", "nope", "--record-dir", str(tmp_path), "--no-progress"]) == 2
    assert "nope" in capsys.readouterr().err


def test_stats_and_show(demos, tmp_path, capsys):
    assert main(["demos", "stats", str(demos), "--png", str(tmp_path / "h.png")]) == 0
    out = capsys.readouterr().out
    assert "3 trajectories (3 successful)" in out and (tmp_path / "h.png").stat().st_size > 1000
    assert main(["demos", "show", str(demos), "--traj", "0", "--out", str(tmp_path / "t.gif")]) == 0
    assert (tmp_path / "t.gif").stat().st_size > 1000
    assert main(["demos", "show", str(demos), "--traj", "9", "--out", str(tmp_path / "x.gif")]) == 2


def test_maniskill_style_solve_returns_the_last_step_or_minus_one():
    env = gym.make(ENV_ID, obs_mode="none", control_mode="pd_joint_pos", task_suite=SUITE, render_backend="none")
    try:
        res = solve(env, seed=0)
        assert res == -1 or (len(res) == 5 and bool(res[-1]["success"]))
        with pytest.raises(ValueError, match="pd_joint_pos"):
            solve(gym.make(ENV_ID, obs_mode="none", task_suite=SUITE, render_backend="none"), seed=0)
    finally:
        env.close()


def test_demo_suites_hold_train_objects_only():
    from fetchbench_ms.objects.loading import object_ids
    from fetchbench_ms.tasks.suite import load_suite, shipped_suites

    test_objects = set(object_ids("test"))
    for name in ("train", "val"):
        assert name in shipped_suites()
        suite = load_suite(name)
        used = {o.object_id for t in suite.tasks.values() for o in t.objects}
        assert used and not used & test_objects, name


def test_converts_to_delta_pos_with_compact_point_clouds(demos):
    """What imitation trains on: pd_joint_delta_pos actions with compact point clouds,
    rendered by the replay tool from the recorded env states' episode (one trajectory:
    rendering two cameras a step on a CPU takes a while)."""
    assert "1/1" in _replay(demos, "-c", "pd_joint_delta_pos", "-o", "compact_pointcloud", "--count", "1")
    converted = demos.with_name(f"{demos.stem}.compact_pointcloud.pd_joint_delta_pos.physx_cpu.h5")
    with h5py.File(converted, "r") as f:
        traj = f["traj_0"]
        xyz = traj["obs"]["pointcloud"]["xyz"]
        assert xyz.dtype == np.float16 and xyz.shape[0] == traj["actions"].shape[0] + 1
        assert traj["success"][-1]


def test_a_changed_suite_task_is_refused_at_reset():
    env = gym.make(ENV_ID, obs_mode="none", task_suite=SUITE, render_backend="none")
    try:
        task_id = suite_task_ids(ENV_ID, SUITE)[0]
        good = env.unwrapped.task_suite.get(task_id).content_hash()[:16]
        env.reset(seed=0, options={"task_id": task_id, "task_hash": good})
        with pytest.raises(ValueError, match="suite changed"):
            env.reset(seed=0, options={"task_id": task_id, "task_hash": "0" * 16})
    finally:
        env.close()


SAMPLE = Path(__file__).resolve().parent.parent / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"


def test_shipped_sample_replays(tmp_path):
    """The shipped sample (20 trajectories of train tasks) is current: its tasks are the
    suite's (hash-checked at reset) and its first trajectories replay to success."""
    import shutil

    from fetchbench_ms.demos.stats import demo_stats

    stats = demo_stats(SAMPLE)
    assert stats["trajectories"] >= 20 and SAMPLE.stat().st_size <= 5 * 2**20
    for suffix in (".h5", ".json"):
        shutil.copy(SAMPLE.with_suffix(suffix), tmp_path / f"sample{suffix}")
    assert "3/3" in _replay(tmp_path / "sample.h5", "--use-env-states", "-o", "state", "--count", "3")


def test_transport_copy_keeps_what_conversion_needs(tmp_path):
    """scripts/maint/demos_transport.py (moving demos between machines, docs/demos.md):
    pack -> unpack keeps every array but the env states' middle rows, and the unpacked file
    converts to pd_joint_delta_pos and replays to success with ManiSkill's replay tool."""
    script = Path(__file__).resolve().parents[1] / "scripts" / "maint" / "demos_transport.py"

    def transport(*args):
        out = subprocess.run([sys.executable, str(script), *map(str, args)], capture_output=True, text=True)
        assert out.returncode == 0, out.stderr[-2000:]
        return json.loads(out.stdout.strip().splitlines()[-1])

    packed = transport("pack", SAMPLE, tmp_path / "sample.npz")
    assert packed["bytes"] < packed["source_bytes"] / 5
    unpacked_path = tmp_path / "unpacked" / "sample.h5"
    transport("unpack", tmp_path / "sample.npz", unpacked_path)
    meta = json.loads(unpacked_path.with_suffix(".json").read_text())
    assert meta["fetchbench_transport"]["source"] == SAMPLE.name
    assert meta["episodes"] == json.loads(SAMPLE.with_suffix(".json").read_text())["episodes"]
    with h5py.File(SAMPLE) as a, h5py.File(unpacked_path) as b:
        assert set(a) == set(b)
        for name in a:
            for key in ("actions", "stage", "stage_end", "success", "terminated", "truncated"):
                np.testing.assert_array_equal(a[name][key][()], b[name][key][()])
                assert a[name][key].dtype == b[name][key].dtype
            panda_a, panda_b = a[name]["env_states/articulations/panda"], b[name]["env_states/articulations/panda"]
            np.testing.assert_array_equal(panda_b[()], panda_a[()][[0, -1]])
    # a transport copy is refused as a source of another one
    bad = subprocess.run([sys.executable, str(script), "pack", unpacked_path, tmp_path / "again.npz"],
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "already a transport copy" in bad.stderr
    assert "2/2" in _replay(unpacked_path, "-c", "pd_joint_delta_pos", "-o", "state", "--count", "2")


def test_transport_copy_with_full_states_replays_from_env_states(tmp_path):
    """``pack --full-states N``: the first N trajectories keep every env-state row, so the
    replay tool's --use-env-states works on them (the dataset's conversion figures are
    measured on a second machine from such a copy); the others keep the first and last."""
    script = Path(__file__).resolve().parents[1] / "scripts" / "maint" / "demos_transport.py"
    for args in (("pack", SAMPLE, tmp_path / "full.npz", "--full-states", "1"),
                 ("unpack", tmp_path / "full.npz", tmp_path / "u" / "full.h5")):
        out = subprocess.run([sys.executable, str(script), *map(str, args)], capture_output=True, text=True)
        assert out.returncode == 0, out.stderr[-2000:]
    unpacked = tmp_path / "u" / "full.h5"
    assert json.loads(unpacked.with_suffix(".json").read_text())["fetchbench_transport"]["full_env_states"] == 1
    with h5py.File(SAMPLE) as a, h5py.File(unpacked) as b:
        for k, name in enumerate(a):
            panda_a, panda_b = a[name]["env_states/articulations/panda"][()], b[name]["env_states/articulations/panda"][()]
            np.testing.assert_array_equal(panda_b, panda_a if k == 0 else panda_a[[0, -1]])
    assert "1/1" in _replay(unpacked, "--use-env-states", "-o", "state", "--count", "1")
