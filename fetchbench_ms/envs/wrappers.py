"""Observation wrappers for learners (``baselines/ppo``): importable by vector-env worker
processes, which rebuild their wrappers by name."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch


def _flatten_state(obs: dict) -> torch.Tensor:
    """[B, D] of every tensor under ``agent`` and ``extra`` (sorted keys)."""
    parts = []
    for group in ("agent", "extra"):
        for key in sorted(obs[group]):
            value = obs[group][key]
            parts.append(value.reshape(value.shape[0], -1).float())
    return torch.cat(parts, dim=1)


class PointCloudStateObs(gym.ObservationWrapper):
    """A compact-point-cloud env's observation as one flat vector [B, D + 4 P]: the
    proprioception and ``extra`` (no object poses: those are state-mode only), then ``P``
    points (x, y, z in the base frame, segment label / 4): 3/4 of them from the scene block
    (furniture and other objects), 1/4 from the target block, evenly strided. One flat
    Box keeps the vector-env and buffer code the same for both observation kinds."""

    def __init__(self, env, points: int):
        super().__init__(env)
        from fetchbench_ms.envs.pointcloud import COMPACT_SIZES

        self.points = points
        n_scene, n_target = points - points // 4, points // 4
        scene_size, target_size = COMPACT_SIZES["scene"], COMPACT_SIZES["target"]
        self._index = torch.cat([torch.linspace(0, scene_size - 1, n_scene).long(),
                                 scene_size + torch.linspace(0, target_size - 1, n_target).long()])
        obs, _ = env.reset(seed=0)
        dim = self.observation(obs).shape[-1]
        base = env.unwrapped
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (base.num_envs, dim), np.float32)
        base.single_observation_space = gym.spaces.Box(-np.inf, np.inf, (dim,), np.float32)
        base.observation_space = self.observation_space
        self.state_dim = dim - 4 * points

    def observation(self, obs):
        state = _flatten_state(obs)
        cloud = obs["pointcloud"]
        index = self._index.to(cloud["xyz"].device)
        xyz = cloud["xyz"][:, index].float()
        seg = cloud["seg"][:, index].float()[..., None] / 4.0
        return torch.cat([state, torch.cat([xyz, seg], dim=-1).reshape(state.shape[0], -1)], dim=1)
