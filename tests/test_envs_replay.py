"""Record a scripted FetchBench episode and convert it with the replay tool."""
from __future__ import annotations

import contextlib
import json
import shutil

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms import replay_trajectory
from fetchbench_ms.envs.fetchbench import MANISKILL_OBS_MODES, NO_RENDER_OBS_MODES
from mani_skill.utils.wrappers import RecordEpisode

STEPS = 12


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """A scripted pd_joint_pos episode: swing the arm, then close the gripper."""
    out = tmp_path_factory.mktemp("demo")
    env = gym.make("FetchBench-v0", task_source="sampled", obs_mode="state", control_mode="pd_joint_pos", num_objects=6)
    env = RecordEpisode(env, output_dir=str(out), trajectory_name="demo", save_video=False,
                        source_type="scripted", source_desc="test swing")
    env.reset(seed=3)
    q0 = env.unwrapped.agent.robot.get_qpos()[0, :7].clone()
    dq = torch.tensor([0.4, 0.3, 0.0, 0.3, 0.0, -0.3, 0.2])
    for t in range(STEPS):
        gripper = 0.04 if t < STEPS - 4 else -0.01
        action = torch.cat([q0 + dq * min(1.0, (t + 1) / (STEPS - 4)), torch.tensor([gripper])])
        env.step(action[None])
    env.close()
    return out / "demo.h5"


def _states(path):
    with h5py.File(path, "r") as f:
        traj = f["traj_0"]
        actors = {k: traj["env_states/actors"][k][:] for k in traj["env_states/actors"]}
        robot = traj["env_states/articulations/panda"][:]
        return actors, robot, traj["success"][:]


@pytest.mark.slow  # ~50 s: renders and stores 2 x 76,800 points per step
def test_replay_to_pointcloud_obs_matches_states(demo):
    replay_trajectory.main(["--traj-path", str(demo), "-o", "pointcloud", "--save-traj", "--allow-failure"])
    out = demo.parent / "demo.pointcloud.pd_joint_pos.physx_cpu.h5"
    actors, robot, success = _states(demo)
    r_actors, r_robot, r_success = _states(out)
    assert set(actors) == set(r_actors) and any(k.startswith("object_") for k in actors)
    for name in actors:
        np.testing.assert_allclose(r_actors[name], actors[name], atol=1e-5, err_msg=name)
    np.testing.assert_allclose(r_robot, robot, atol=1e-5)
    assert np.array_equal(success, r_success)
    with h5py.File(out, "r") as f:
        pcd = f["traj_0/obs/pointcloud"]
        assert pcd["xyz_base"].shape[1:] == (2 * 320 * 240, 3)
        assert pcd["fetch_label"].shape[0] == STEPS + 1
    meta = json.loads((demo.parent / "demo.pointcloud.pd_joint_pos.physx_cpu.json").read_text())
    assert meta["env_info"]["env_id"] == "fetchbench_ms:FetchBench-v0"


def test_replay_to_joint_delta_control_matches_objects_and_success(demo):
    replay_trajectory.main(["--traj-path", str(demo), "-c", "pd_joint_delta_pos", "--save-traj", "--allow-failure"])
    out = demo.parent / "demo.state.pd_joint_delta_pos.physx_cpu.h5"
    actors, robot, success = _states(demo)
    r_actors, r_robot, r_success = _states(out)
    for name in actors:
        if name.startswith("object_"):
            # Object poses at the end (positions) agree to a millimetre.
            np.testing.assert_allclose(r_actors[name][-1, :3], actors[name][-1, :3], atol=1e-3, err_msg=name)
    # The converted arm ends where the original did (joint positions, 9 after the 13 root values).
    np.testing.assert_allclose(r_robot[-1, 13:20], robot[-1, 13:20], atol=0.02)
    assert bool(r_success[-1]) == bool(success[-1])
    with h5py.File(out, "r") as f:
        actions = f["traj_0/actions"][:]
    assert actions.shape[1] == 8 and np.abs(actions).max() <= 1.0 + 1e-6  # normalised delta actions
    # the demo names the plain id; the converted file the one ManiSkill's own tool can make
    meta = json.loads(out.with_suffix(".json").read_text())
    assert json.loads(demo.with_suffix(".json").read_text())["env_info"]["env_id"] == "FetchBench-v0"
    assert meta["env_info"]["env_id"] == "fetchbench_ms:FetchBench-v0"


def test_joint_delta_conversion_without_stepping_the_source_env_writes_the_same_file(demo, tmp_path, monkeypatch):
    """The converter leaves ManiSkill's source env unstepped (it reads only its controller):
    the converted trajectory is ManiSkill's own conversion's, every array to the bit."""
    outputs, skipped = {}, []
    for name in ("stock", "unstepped"):
        folder = tmp_path / name
        folder.mkdir()
        for suffix in (".h5", ".json"):
            shutil.copy(demo.with_suffix(suffix), folder / f"demo{suffix}")
        with monkeypatch.context() as m, contextlib.ExitStack() as stack:
            if name == "stock":  # ManiSkill's conversion module, which steps the source env
                stack.enter_context(replay_trajectory.stock_action_conversion())
            else:  # count the source steps the stand-in skipped
                m.setattr(replay_trajectory._SourceControllerOnly, "step", lambda self, action: skipped.append(action))
            replay_trajectory.main(["--traj-path", str(folder / "demo.h5"), "-c", "pd_joint_delta_pos", "--save-traj",
                                    "--allow-failure"])
        outputs[name] = folder / "demo.state.pd_joint_delta_pos.physx_cpu.h5"
    arrays = {}
    for name, path in outputs.items():
        with h5py.File(path, "r") as f:
            arrays[name] = {}
            f.visititems(lambda key, obj, out=arrays[name]: out.__setitem__(key, obj[()])
                         if isinstance(obj, h5py.Dataset) else None)
    assert set(arrays["stock"]) == set(arrays["unstepped"]) and "traj_0/actions" in arrays["stock"]
    for key, value in arrays["stock"].items():
        assert np.array_equal(value, arrays["unstepped"][key]), key
    assert len(skipped) == STEPS  # every source step of the demo went to the stand-in, not to PhysX


@pytest.fixture(scope="module")
def demo_without_renderer(tmp_path_factory):
    """A short demo recorded as state-only data collection does it: render_backend="none"."""
    out = tmp_path_factory.mktemp("demo_norender")
    env = gym.make("FetchBench-Desk-v0", task_source="sampled", obs_mode="state", control_mode="pd_joint_pos", num_objects=2,
                   render_backend="none")
    env = RecordEpisode(env, output_dir=str(out), trajectory_name="demo", save_video=False, source_type="scripted")
    env.reset(seed=3)
    q = env.unwrapped.agent.robot.get_qpos()[0, :8].clone()
    for t in range(3):
        q[0] += 0.05
        env.step(q[None])
    env.close()
    assert json.loads((out / "demo.json").read_text())["env_info"]["env_kwargs"]["render_backend"] == "none"
    return out / "demo.h5"


@pytest.mark.parametrize("obs_mode", MANISKILL_OBS_MODES)
def test_replay_of_a_demo_without_renderer_works_in_every_obs_mode(demo_without_renderer, obs_mode, capsys):
    """Camera obs modes switch the replay to ManiSkill's default renderer (with a note);
    the others replay as recorded."""
    demo = demo_without_renderer
    replay_trajectory.main(["--traj-path", str(demo), "-o", obs_mode, "--save-traj", "--allow-failure"])
    noted = "replaying with ManiSkill's default renderer" in capsys.readouterr().out
    assert noted == (obs_mode not in NO_RENDER_OBS_MODES)
    out = demo.parent / f"demo.{obs_mode}.pd_joint_pos.physx_cpu.h5"
    actors, robot, _ = _states(demo)
    r_actors, r_robot, _ = _states(out)
    np.testing.assert_allclose(r_robot, robot, atol=1e-5)  # the same episode
    with h5py.File(out, "r") as f:
        obs = f["traj_0/obs"]
        if obs_mode == "pointcloud":
            assert obs["pointcloud/xyz_base"].shape[0] == 4
        elif obs_mode not in NO_RENDER_OBS_MODES:
            assert set(obs["sensor_data"]) == {"left_camera", "right_camera"}
    meta = json.loads((demo.parent / f"demo.{obs_mode}.pd_joint_pos.physx_cpu.json").read_text())
    assert meta["env_info"]["env_kwargs"].get("render_backend", "gpu") != "none" or obs_mode in NO_RENDER_OBS_MODES


def test_replay_names_valid_obs_modes_for_a_typo(demo_without_renderer, capsys):
    assert replay_trajectory.main(["--traj-path", str(demo_without_renderer), "-o", "pointclod"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown obs_mode 'pointclod'; valid: state, state_dict, none" in err[0]
