"""Every obs mode x every Panda control mode, gymnasium's env checker, bad kwargs.

A combination either works (reset and one step give observations inside the observation
space) or is refused at ``gym.make`` with a ValueError naming the valid choices."""
from __future__ import annotations

import gc
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms.envs import control_modes
from fetchbench_ms.envs.fetchbench import MANISKILL_OBS_MODES, NO_RENDER_OBS_MODES
from mani_skill.utils import common

#: ManiSkill's documented modes plus the other camera textures and state + camera mixes
#: its parser accepts.
OBS_MODES = MANISKILL_OBS_MODES + ("position", "normal", "albedo", "rgb+normal", "state+rgb", "state_dict+depth")
#: A quick, fixed task for the grid: a Desk with 2 objects. ``gym.make`` loads the task of
#: ManiSkill's start seed 2022; resetting to the same seed restarts it without a rebuild.
GRID_ENV, GRID_SEED = "FetchBench-Desk-v0", 2022
#: Small cameras (ManiSkill's sensor override): rendering is most of a camera cell's time.
GRID_KWARGS = dict(num_objects=2, sensor_configs=dict(width=80, height=60))


@pytest.fixture(scope="module", autouse=True)
def _frozen_heap():
    """ManiSkill runs ``gc.collect()`` twice per env (on reconfigure and on close); with
    torch, trimesh and the catalog loaded that walks ~1M objects, ~0.2 s each time, most of
    this file's time. Freezing what is alive now leaves only the envs' own objects to walk."""
    gc.collect()
    gc.freeze()
    yield
    gc.unfreeze()


def _in_space(space, obs) -> bool:
    return space.contains(common.to_numpy(obs))


@pytest.mark.parametrize("control_mode", control_modes())
@pytest.mark.parametrize("obs_mode", OBS_MODES)
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
