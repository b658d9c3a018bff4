"""Every obs mode x every Panda control mode, gymnasium's env checker, bad kwargs.

A combination either works (reset and one step give observations inside the observation
space) or is refused at ``gym.make`` with a ValueError naming the valid choices."""
from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms.envs import control_modes
from fetchbench_ms.envs.fetchbench import MANISKILL_OBS_MODES, NO_RENDER_OBS_MODES
from mani_skill.utils import common

#: Other camera textures and state + camera mixes ManiSkill's parser accepts.
EXTRA_OBS_MODES = ("position", "normal", "albedo", "rgb+normal", "state+rgb", "state_dict+depth")
OBS_MODES = MANISKILL_OBS_MODES + EXTRA_OBS_MODES
#: The grid: ManiSkill's documented obs modes x every Panda control mode (143 cells), and the
#: extra modes with one control mode (obs and control are built independently; the full
#: 19 x 11 grid takes ~110 s on 2 shared cores, this one ~75 s: ~0.5 s a cell, most of
#: it ManiSkill's gc.collect() on reconfigure and close).
GRID = [(o, c) for o in MANISKILL_OBS_MODES for c in control_modes()] + [(o, "pd_joint_delta_pos") for o in EXTRA_OBS_MODES]
#: A quick, fixed task for the grid: a Desk with 2 objects. ``gym.make`` loads the task of
#: ManiSkill's start seed 2022; resetting to the same seed restarts it without a rebuild.
GRID_ENV, GRID_SEED = "FetchBench-Desk-v0", 2022
#: Small cameras (ManiSkill's sensor override): rendering is most of a camera cell's time.
GRID_KWARGS = dict(task_source="sampled", num_objects=2, sensor_configs=dict(width=80, height=60))


def _in_space(space, obs) -> bool:
    return space.contains(common.to_numpy(obs))


@pytest.mark.parametrize("obs_mode, control_mode", GRID)
def test_every_obs_mode_with_every_control_mode(obs_mode, control_mode):
    env = gym.make(GRID_ENV, obs_mode=obs_mode, control_mode=control_mode, **GRID_KWARGS)
    try:
        obs, info = env.reset(seed=GRID_SEED)
        assert not info["reconfigure"]  # the task gym.make loaded: no rebuild per cell
        assert env.unwrapped.control_mode == control_mode
        assert _in_space(env.observation_space, obs), f"reset obs of {obs_mode} outside the observation space"
        env.action_space.seed(0)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        assert _in_space(env.observation_space, obs), f"step obs of {obs_mode} outside the observation space"
        assert torch.isfinite(reward).all()
        if obs_mode.startswith("state+"):  # ManiSkill flattens agent and extra into one vector
            assert obs["state"].ndim == 2 and "extra" not in obs
        elif obs_mode not in ("state", "none"):
            assert obs["extra"]["tcp_pose"].shape == (1, 7)
        if obs_mode not in NO_RENDER_OBS_MODES:  # camera modes carry the cameras' data
            cameras = obs["pointcloud"] if obs_mode == "pointcloud" else obs["sensor_data"]
            assert ("xyz_base" in cameras) if obs_mode == "pointcloud" else set(cameras) == {"left_camera", "right_camera"}
    finally:
        env.close()


@pytest.mark.parametrize("obs_mode", OBS_MODES)
def test_obs_modes_without_a_renderer_work_or_fail_at_make(obs_mode):
    """``render_backend="none"`` builds no cameras: camera modes are refused at gym.make
    (not with a KeyError on the first observation), the others work."""
    if obs_mode in NO_RENDER_OBS_MODES:
        env = gym.make(GRID_ENV, obs_mode=obs_mode, render_backend="none", **GRID_KWARGS)
        try:
            obs, _ = env.reset(seed=GRID_SEED)
            assert _in_space(env.observation_space, obs)
            obs, *_ = env.step(torch.zeros(env.action_space.shape))
            assert _in_space(env.observation_space, obs)
        finally:
            env.close()
    else:
        with pytest.raises(ValueError, match="without a renderer valid obs modes: state, state_dict, none"):
            gym.make(GRID_ENV, obs_mode=obs_mode, render_backend="none", **GRID_KWARGS)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(obs_mode="pointclouds"), "unknown obs_mode 'pointclouds'; valid: state, state_dict, none, sensor_data"),
        (dict(obs_mode="rgb+dpeth"), r"unknown obs_mode 'rgb\+dpeth'; valid: .*rgb, depth, segmentation"),
        (dict(obs_mode="state+state_dict"), "unknown obs_mode"),  # no camera texture: not a mode
        (dict(control_mode="pd_joint_delta_pose"), "unknown control mode 'pd_joint_delta_pose'; valid: pd_joint_delta_pos"),
        (dict(reward_mode="shaped"), "unknown reward_mode 'shaped'; valid: normalized_dense, dense, sparse, none"),
        (dict(render_mode="rgb"), "unknown render_mode 'rgb'; valid: None, human, rgb_array, sensors, all"),
        (dict(sim_backend="physx_gpu"), "unknown sim_backend 'physx_gpu'; valid: auto, cpu, cuda"),
        (dict(object_split="val"), "unknown object_split 'val'; valid: train, test"),
    ],
)
def test_bad_maniskill_kwargs_name_valid_choices(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make(GRID_ENV, **GRID_KWARGS, **kwargs)


#: Warnings of gymnasium's checker that say nothing wrong about the env: the wrapper is
#: the point of the check (ManiSkill's CPUGymWrapper), state vectors are unbounded, and
#: NumPy 2 deprecates an interface torch tensors still use.
EXPECTED_CHECKER_WARNINGS = ("is different from the unwrapped version", "observation space minimum value is -infinity",
                             "observation space maximum value is infinity", "__array_wrap__ must accept context")


def test_gymnasium_env_checker_passes_on_maniskills_cpu_gym_wrapper():
    """gymnasium's ``check_env`` on ``CPUGymWrapper(gym.make(ID, obs_mode="state"))``: spaces,
    reset seeding (``np_random`` seeded by the reset seed, same seed same observation, an
    unseeded reset after a seeded one repeats too), step determinism, no reused data.

    Its render and close parts are run below by hand instead, because check_env runs them
    on ``env.spec.make(...)``, and ManiSkill's TimeLimitWrapper and CPUGymWrapper do not
    record their constructor arguments, so gymnasium refuses to re-create the wrapped env
    from its spec (a ManiSkill limitation, whatever the env); and its "human" render mode
    opens a window, which a machine without a display cannot."""
    from gymnasium.utils.env_checker import check_env
    from gymnasium.utils.passive_env_checker import env_render_passive_checker
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    env = CPUGymWrapper(gym.make("FetchBench-v0", task_source="sampled", obs_mode="state", num_objects=4))
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env, skip_render_check=True, skip_close_check=True)
        unexpected = [str(w.message) for w in caught
                      if not any(ok in str(w.message) for ok in EXPECTED_CHECKER_WARNINGS)]
        assert not unexpected, unexpected  # e.g. "observations are not equal although similar"
        # Exactly the same observation from the same seed, also after another task was loaded.
        first, _ = env.reset(seed=5)
        env.reset(seed=6)
        again, _ = env.reset(seed=5)
        assert np.array_equal(first, again)
        assert env.unwrapped.np_random_seed == 5
    finally:
        env.close()

    for mode in ("rgb_array", "sensors", "all"):
        # The "human" viewer needs a display; the other render modes as check_env's render part checks them.
        assert mode in env.metadata["render_modes"] and env.metadata["render_fps"] == 20
        shown = CPUGymWrapper(gym.make("FetchBench-v0", task_source="sampled", obs_mode="state", num_objects=4, render_mode=mode))
        shown.reset(seed=5)
        frame = env_render_passive_checker(shown)
        assert isinstance(frame, np.ndarray) and frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
        assert frame.std() > 0  # a picture, not a blank
        shown.close()
        shown.close()  # closing twice is allowed (check_env's close check)
