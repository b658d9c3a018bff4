"""ManiSkill's own replay tool, unchanged (``python -m mani_skill.trajectory.replay_trajectory``),
on the shipped demonstration sample: it makes the env from the file's ``env_info`` alone
(``fetchbench_ms:FetchBench-v0``: Gymnasium imports the plugin), converts observations and
controllers."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from fetchbench_ms.demos.env_info import replayable_env_info
from fetchbench_ms.envs import ENV_IDS, recorded_env_id

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
POINTCLOUD_STEPS = 3  # a camera replay renders two 320x240 views a step: a few steps suffice


def maniskill_replay(traj_path: Path, *args: str) -> str:
    """Runs ManiSkill's tool in a fresh interpreter (nothing imported the plugin); its stdout."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
                          str(traj_path), "--save-traj", *args], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def _copy_sample(folder: Path) -> Path:
    for suffix in (".h5", ".json"):
        shutil.copy(SAMPLE.with_suffix(suffix), folder / f"sample{suffix}")
    return folder / "sample.h5"


def _meta(path: Path) -> dict:
    return json.loads(path.with_suffix(".json").read_text())


def test_the_sample_names_its_env_so_gymnasium_imports_the_plugin():
    env_info = _meta(SAMPLE)["env_info"]
    assert env_info["env_id"] == "fetchbench_ms:FetchBench-v0"
    assert "render_backend" not in env_info["env_kwargs"]  # camera obs modes need a renderer
    code = ("import json, sys, gymnasium as gym; info = json.load(open(sys.argv[1]))['env_info']; "
            "env = gym.make(info['env_id'], **info['env_kwargs']); print(env.spec.id, type(env.unwrapped).__name__)")
    out = subprocess.run([sys.executable, "-c", code, str(SAMPLE.with_suffix(".json"))], capture_output=True,
                         text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, cwd="/")
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split()[-2:] == ["FetchBench-v0", "FetchBenchEnv"]


def test_env_info_is_written_replayable_and_old_ids_stay_valid():
    old = {"env_id": "FetchBench-Shelf-v0", "env_kwargs": {"obs_mode": "none", "render_backend": "none"},
           "max_episode_steps": 400}
    new = replayable_env_info(old)
    assert new == {"env_id": "fetchbench_ms:FetchBench-Shelf-v0", "env_kwargs": {"obs_mode": "none"},
                   "max_episode_steps": 400}
    assert replayable_env_info(new) == new  # idempotent
    other = {"env_id": "PickCube-v1", "env_kwargs": {"render_backend": "none"}}
    assert replayable_env_info(other) == other and replayable_env_info(None) is None
    assert [recorded_env_id(i) for i in ENV_IDS] == [f"fetchbench_ms:{i}" for i in ENV_IDS]
    assert recorded_env_id("fetchbench_ms:FetchBench-v0") == "fetchbench_ms:FetchBench-v0"


def test_state_obs_and_joint_delta_controller_replay_the_first_demo_to_success(tmp_path):
    """``-o state -c pd_joint_delta_pos`` (one run: each start of the tool costs seconds)."""
    traj = _copy_sample(tmp_path)
    assert "1/1" in maniskill_replay(traj, "-o", "state", "-c", "pd_joint_delta_pos", "--count", "1")
    out = tmp_path / "sample.state.pd_joint_delta_pos.physx_cpu.h5"
    episode = _meta(SAMPLE)["episodes"][0]
    with h5py.File(out) as f, h5py.File(SAMPLE) as src:
        obs, actions, success = f["traj_0/obs"][()], f["traj_0/actions"][()], f["traj_0/success"][()]
        actors = {k: v[-1, :3] for k, v in f["traj_0/env_states/actors"].items()}
        actors_src = {k: v[-1, :3] for k, v in src[f"traj_{episode['episode_id']}/env_states/actors"].items()}
    assert obs.ndim == 2 and obs.shape[0] == actions.shape[0] + 1 and np.isfinite(obs).all()
    assert actions.shape[1] == 8 and np.abs(actions[:, :7]).max() <= 1.0 + 1e-6  # normalised joint deltas
    assert success[-1]
    assert set(actors) == set(actors_src)
    for name in actors:  # every object (the target in the gripper too) ends where the demo left it
        np.testing.assert_allclose(actors[name], actors_src[name], atol=0.01, err_msg=name)
    assert _meta(out)["env_info"]["env_kwargs"]["control_mode"] == "pd_joint_delta_pos"


def test_pointcloud_obs_of_the_first_steps(tmp_path):
    """The sample's first demo cut to its first steps (the file as the sample writes it, but
    shorter): ManiSkill's tool renders the cameras into FetchBench's segmented clouds."""
    meta = _meta(SAMPLE)
    episode = dict(meta["episodes"][0], elapsed_steps=POINTCLOUD_STEPS, success=False)
    traj = tmp_path / "first_steps.h5"
    with h5py.File(SAMPLE) as src, h5py.File(traj, "w") as dst:
        group = dst.create_group("traj_0")
        for key in ("actions", "terminated", "truncated", "success"):
            group.create_dataset(key, data=src[f"traj_{episode['episode_id']}/{key}"][:POINTCLOUD_STEPS])
    episode["episode_id"] = 0
    traj.with_suffix(".json").write_text(json.dumps({**meta, "episodes": [episode]}))
    assert "1/1" in maniskill_replay(traj, "-o", "pointcloud", "--allow-failure")
    with h5py.File(tmp_path / "first_steps.pointcloud.pd_joint_pos.physx_cpu.h5") as f:
        cloud = f["traj_0/obs/pointcloud"]
        xyz, labels = cloud["xyz_base"][()], cloud["fetch_label"][()]
    assert xyz.shape == (POINTCLOUD_STEPS + 1, 2 * 320 * 240, 3) and labels.shape[:2] == xyz.shape[:2]
    assert np.isfinite(xyz).all() and len(np.unique(labels)) > 1  # segmented: more than one label



def test_a_raw_point_cloud_conversion_says_its_size_and_is_refused_beyond_the_free_disk(tmp_path, capsys, monkeypatch):
    """`-o pointcloud --save-traj` writes ~5 MB a step: the size is printed before anything runs,
    and a conversion larger than the free disk is one line and exit 2 (nothing written)."""
    import shutil
    from collections import namedtuple

    from fetchbench_ms import replay_trajectory

    for suffix in (".h5", ".json"):
        shutil.copy(SAMPLE.with_suffix(suffix), tmp_path / f"demos{suffix}")
    traj = str(tmp_path / "demos.h5")
    meta = json.loads((tmp_path / "demos.json").read_text())
    steps, size = replay_trajectory.raw_pointcloud_bytes(meta, 1)
    assert steps == meta["episodes"][0]["elapsed_steps"] + 1 and 3e6 < size / steps < 7e6
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(replay_trajectory.shutil, "disk_usage", lambda path: usage(10**12, 10**12 - 10**8, 10**8))
    before = sorted(p.name for p in tmp_path.iterdir())
    assert replay_trajectory.main(["--traj-path", traj, "-o", "pointcloud", "--save-traj", "--count", "1"]) == 2
    captured = capsys.readouterr()
    assert "GB" in captured.out and "compact_pointcloud" in captured.out
    assert len(captured.err.strip().splitlines()) == 1 and "--allow-exceeding-disk" in captured.err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    # with the flag, or without saving, nothing is refused (checked without running the replay)
    args = replay_trajectory._maniskill_replay.parse_args(["--traj-path", traj, "-o", "pointcloud", "--save-traj"])
    assert replay_trajectory.check_raw_size(args, meta, allow=True) is None
    args = replay_trajectory._maniskill_replay.parse_args(["--traj-path", traj, "-o", "pointcloud"])
    assert replay_trajectory.check_raw_size(args, meta, allow=False) is None


def test_a_replay_that_renders_nothing_runs_without_a_renderer():
    """-o state (no video) replays with render_backend="none" (no renderer to start in each of a
    conversion's processes); a camera obs mode keeps the recorded backend, or gets the default."""
    from fetchbench_ms import replay_trajectory

    parse = replay_trajectory._maniskill_replay.parse_args
    state = parse(["--traj-path", str(SAMPLE), "-o", "state"])
    assert replay_trajectory._replay_env_kwargs(state, {"obs_mode": "state"})["render_backend"] == "none"
    assert replay_trajectory._replay_env_kwargs(state, {"render_backend": "none"}) is None
    camera = parse(["--traj-path", str(SAMPLE), "-o", "pointcloud"])
    assert replay_trajectory._replay_env_kwargs(camera, {"obs_mode": "state"}) is None
    assert "render_backend" not in replay_trajectory._replay_env_kwargs(camera, {"render_backend": "none"})
