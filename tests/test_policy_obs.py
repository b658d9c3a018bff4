"""``obs_mode="policy_pointcloud"`` and ``"composed_pointcloud"``: the imitation policies' points
made by the env itself, the same at conversion (made from recorded env states) and at deployment
(the env stepped)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from fetchbench_ms.envs.pointcloud import (LABEL_FURNITURE, LABEL_NONE, LABEL_OBJECT, LABEL_ROBOT, LABEL_TARGET,
                                           POINTS_OBS_MODES, POLICY_CLOUD_SIZES, POLICY_OBS_MODE, hash32, pixel_keys,
                                           policy_cloud)

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
FIRST_STEPS = 9
N = sum(POLICY_CLOUD_SIZES.values())


_import = import_script


def test_hash_is_the_reference_lowbias32():
    """The int64 arithmetic (no overflow) gives lowbias32's 32-bit values."""
    def reference(x: int) -> int:
        x ^= x >> 16
        x = (x * 0x7FEB352D) & 0xFFFFFFFF
        x ^= x >> 15
        x = (x * 0x846CA68B) & 0xFFFFFFFF
        return x ^ (x >> 16)

    values = [0, 1, 2, 12345, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 0xDEADBEEF]
    assert hash32(torch.tensor(values)).tolist() == [reference(v) for v in values]
    keys = pixel_keys(torch.tensor([7, 8]), 1000)
    assert all(len(set(row.tolist())) == 1000 for row in keys)  # distinct within a row
    assert not torch.equal(keys[0], keys[1])
    assert torch.equal(keys, pixel_keys(torch.tensor([7, 8]), 1000))


def _cloud(rng, counts: dict) -> tuple[torch.Tensor, torch.Tensor]:
    labels = np.concatenate([np.full(n, label, np.uint8) for label, n in counts.items()])
    rng.shuffle(labels)
    points = rng.uniform(-0.15, 0.95, size=(len(labels), 3))  # inside the workspace box.astype(np.float32)
    return torch.from_numpy(points)[None], torch.from_numpy(labels)[None]


def test_policy_cloud_draws_each_segment_from_its_own_points():
    rng = np.random.default_rng(0)
    points, labels = _cloud(rng, {LABEL_NONE: 3000, LABEL_FURNITURE: 5000, LABEL_OBJECT: 800, LABEL_TARGET: 300,
                                  LABEL_ROBOT: 2000})
    out, out_label = policy_cloud(points, labels, torch.tensor([11]))
    assert out.shape == (1, N, 3) and out.dtype == torch.float16 and out_label.dtype == torch.uint8
    scene, target, robot = np.split(out_label[0].numpy(), [1024, 1536])
    assert set(scene) <= {LABEL_FURNITURE, LABEL_OBJECT} and set(target) == {LABEL_TARGET}
    assert set(robot) == {LABEL_ROBOT}
    # Every point is one of its segment's camera points.
    source = {tuple(p) for p in points[0].half().tolist()}
    assert all(tuple(p) in source for p in out[0].tolist())
    # The target has 300 points for 512 places: all of them, some twice, nothing else.
    picked = {tuple(p) for p in out[0, 1024:1536].tolist()}
    assert len(picked) == 300
    # The same seed: the same bytes; another seed: another draw.
    again = policy_cloud(points, labels, torch.tensor([11]))
    assert torch.equal(again[0], out) and torch.equal(again[1], out_label)
    assert not torch.equal(policy_cloud(points, labels, torch.tensor([12]))[0], out)


def test_policy_cloud_fills_an_unseen_segment_and_crops_to_the_workspace():
    rng = np.random.default_rng(1)
    points, labels = _cloud(rng, {LABEL_FURNITURE: 4000, LABEL_ROBOT: 1000})
    points[0, :10] = torch.tensor([5.0, 0.0, 0.5])  # outside the workspace box
    labels[0, :10] = LABEL_TARGET  # the only target points
    out, out_label = policy_cloud(points, labels, torch.tensor([3]))
    assert (out_label[0, 1024:1536] == LABEL_NONE).all() and (out[0, 1024:1536] == 0).all()
    assert (out_label[0, :1024] == LABEL_FURNITURE).all()


def test_policy_obs_mode_cameras_and_refusals():
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401

    with pytest.raises(ValueError, match="160x120"):
        gym.make("FetchBench-v0", obs_mode=POLICY_OBS_MODE, camera_width=320, camera_height=240)
    env = gym.make("FetchBench-v0", obs_mode=POLICY_OBS_MODE, task_suite="train")
    try:
        obs, _ = env.reset(seed=1)
        assert env.unwrapped.obs_mode == POLICY_OBS_MODE
        assert all((s.config.width, s.config.height) == (160, 120) for s in env.unwrapped._sensors.values())
        assert obs["pointcloud"]["points"].shape == (1, N, 3) and "sensor_data" not in obs
        # Its obs_mode is the policies' input as it is: the same bytes through observation_input.
        from fetchbench_ms.policies.data import observation_input

        step_input = observation_input(obs)
        assert np.array_equal(step_input.points, obs["pointcloud"]["points"].numpy())
    finally:
        env.close()


@pytest.fixture(scope="module")
def state_replay(tmp_path_factory) -> Path:
    """The sample's first demo's first steps through the state-only replay (pd_joint_delta_pos),
    as the converter runs it for --obs-mode policy_pointcloud."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    from fetchbench_ms import replay_trajectory

    work = tmp_path_factory.mktemp("state-replay")
    meta = json.loads(SAMPLE.with_suffix(".json").read_text())
    convert.write_chunk_source(SAMPLE, meta["episodes"][:1], meta["env_info"], work / "demos.h5", FIRST_STEPS)
    replay_trajectory.main(["--traj-path", str(work / "demos.h5"), "-c", "pd_joint_delta_pos", "-o", "state",
                            "--save-traj", "--allow-failure"])
    return work


@pytest.mark.parametrize("obs_mode", POINTS_OBS_MODES)
def test_conversion_is_the_obs_mode_on_the_recorded_states(state_replay, obs_mode):
    """The training frames of --obs-mode policy_pointcloud / composed_pointcloud are, to the bit,
    what a fresh env in that obs mode observes at each recorded env state after a reset to the
    demo's task (its step counter at the frame's step)."""
    import gymnasium as gym
    import h5py
    from mani_skill.trajectory.utils import index_dict

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.policies.data import convert_episodes

    converted = state_replay / "demos.state.pd_joint_delta_pos.physx_cpu.h5"
    data = convert_episodes(converted, state_replay / "demos.h5", POLICY_CLOUD_SIZES, log=lambda m: None,
                            render_obs_mode=obs_mode)
    assert data["obs_mode"] == obs_mode and data["points"].shape[1:] == (N, 3)
    meta = json.loads(converted.with_suffix(".json").read_text())
    episode = meta["episodes"][0]
    kwargs = {k: v for k, v in meta["env_info"]["env_kwargs"].items() if k not in ("obs_mode", "render_backend")}
    env = gym.make(meta["env_info"]["env_id"], **kwargs, obs_mode=obs_mode)
    try:
        env.reset(**episode["reset_kwargs"])
        with h5py.File(converted, "r") as f:
            states = index_dict(f[f"traj_{episode['episode_id']}"]["env_states"], slice(None))
        for t in range(data["episode_length"][0]):
            env.unwrapped.set_state_dict(index_dict(states, slice(t, t + 1)))
            env.unwrapped._elapsed_steps[:] = t
            obs = env.unwrapped.get_obs()
            assert np.array_equal(obs["pointcloud"]["points"][0].numpy(), data["points"][t]), t
            assert np.array_equal(obs["pointcloud"]["point_label"][0].numpy(), data["point_label"][t]), t
    finally:
        env.close()


@pytest.mark.parametrize("obs_mode", POINTS_OBS_MODES)
def test_deployment_steps_observe_what_the_conversion_renders(state_replay, obs_mode):
    """At deployment the env is stepped, not set: the obs mode's points at the replay's own steps
    against those made from the recorded states of the same steps. The camera pixels differ
    only where the Panda's simulated link poses differ from its kinematics' (~1e-8 m, an edge
    pixel); the per-pixel draw keeps such a pixel's change to its own candidacy. The composed
    points move with those poses (~1e-8 m: a float16 rounding at most)."""
    import gymnasium as gym
    import h5py

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.render_env_states import StateRenderer

    converted = state_replay / "demos.state.pd_joint_delta_pos.physx_cpu.h5"
    meta = json.loads(converted.with_suffix(".json").read_text())
    episode = meta["episodes"][0]
    kwargs = {k: v for k, v in meta["env_info"]["env_kwargs"].items() if k not in ("obs_mode", "render_backend")}
    with h5py.File(converted, "r") as f:
        actions = f[f"traj_{episode['episode_id']}"]["actions"][:]
    env = gym.make(meta["env_info"]["env_id"], **kwargs, obs_mode=obs_mode)
    renderer = StateRenderer(meta["env_info"]["env_id"], meta["env_info"]["env_kwargs"], obs_mode)
    try:
        obs, _ = env.reset(**episode["reset_kwargs"])
        renderer.env.reset(**episode["reset_kwargs"])
        same, first = [], None
        for t in range(len(actions) + 1):
            if t:
                obs, *_ = env.step(torch.as_tensor(actions[t - 1:t]))
            if t % 4:
                continue
            from_state = renderer.observation(env.unwrapped.get_state_dict(), t)["pointcloud"]
            stepped = obs["pointcloud"]
            points, points_s = stepped["points"][0].float().numpy(), from_state["points"][0].float().numpy()
            assert np.array_equal(stepped["point_label"][0].numpy(), from_state["point_label"][0].numpy()), t
            same.append(float((np.abs(points - points_s).max(axis=1) < 1e-6).mean()))
            first = points if first is None else first
        assert min(same) > 0.95, same
        assert (np.abs(points - first).max(axis=1) > 1e-3).sum() > 50  # the arm moved: not a stale render
    finally:
        env.close()
        renderer.close()


def test_render_workers_take_the_render_backends_in_turn(state_replay):
    """``--render-gpus N``: worker i renders on cuda:{i % N}. Here two CPU workers given the two
    spellings of the CPU renderer render what one process renders, job by job in order."""
    import h5py
    from mani_skill.trajectory.utils import index_dict

    from fetchbench_ms.render_env_states import RenderJob, render_backends, render_compact_clouds

    assert render_backends(1) is None and render_backends(3) == ["cuda:0", "cuda:1", "cuda:2"]
    with pytest.raises(ValueError, match=">= 1"):
        render_backends(0)
    converted = state_replay / "demos.state.pd_joint_delta_pos.physx_cpu.h5"
    meta = json.loads(converted.with_suffix(".json").read_text())
    episode = meta["episodes"][0]
    with h5py.File(converted, "r") as f:
        states = index_dict(f[f"traj_{episode['episode_id']}"]["env_states"], slice(None))
    jobs = [RenderJob(episode["reset_kwargs"], int(episode["episode_seed"]), np.array(steps),
                      index_dict(states, np.array(steps))) for steps in ([0, 3], [6])]
    env_id, env_kwargs = meta["env_info"]["env_id"], meta["env_info"]["env_kwargs"]
    one = list(render_compact_clouds(env_id, env_kwargs, jobs, 1, POLICY_OBS_MODE))
    two = list(render_compact_clouds(env_id, env_kwargs, jobs, 2, POLICY_OBS_MODE, ["cpu", "sapien_cpu"]))
    assert [len(xyz) for xyz, _ in two] == [2, 1]
    assert all(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) for a, b in zip(one, two))
