"""What the dense reward says about recorded demonstrations and simple policies.

``demo_rollout`` replays a recorded trajectory's actions (optionally perturbed) through a
FetchBench env made with the recording's env kwargs and ``reward_mode="dense"``, and
returns the reward and its parts (``FetchBenchEnv.reward_terms``) at every step. After
the recorded actions run out, the last action is repeated (the arm holds the target
where the demo left it) up to ``horizon`` steps, so demos of different lengths and
policies that run the full horizon are compared over the same number of steps.
``policy_rollout`` does the same for a policy given as a function of the step.
``scripts/bench/bench_reward.py`` uses both (docs/rl.md).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import torch

from ..envs.fetchbench import REWARD_WEIGHTS

#: Reward parts recorded per step: the weighted stages, then the penalty terms.
TERM_NAMES = tuple(REWARD_WEIGHTS) + ("disturb", "contact")


@dataclass
class Rollout:
    """Per-step rewards of one episode (``steps`` of them) and how it ended."""

    rewards: np.ndarray  # [T] dense reward (0..6)
    terms: dict[str, np.ndarray] = field(default_factory=dict)  # name -> [T] in [0, 1]
    success: np.ndarray = None  # [T] bool: the env's success at each step
    recorded_steps: int = 0  # steps that came from the recording (the rest repeat its last action)

    @property
    def ret(self) -> float:
        return float(self.rewards.sum())

    @property
    def success_at_end(self) -> bool:
        return bool(self.success[-1])


def load_demos(h5_path: str | Path) -> tuple[dict, list[dict]]:
    """(env_info, episodes) of a ManiSkill trajectory file's JSON."""
    meta = json.loads(Path(h5_path).with_suffix(".json").read_text())
    return meta["env_info"], meta["episodes"]


def make_env(env_info: dict, **overrides):
    """The recording's env (its id and kwargs) with the dense reward and state obs."""
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401  (registers the ids)

    kwargs = {k: v for k, v in env_info["env_kwargs"].items() if k != "id_fixes"}
    kwargs.update(reward_mode="dense", obs_mode="state", render_backend="none")
    kwargs.update(overrides)
    return gym.make(env_info["env_id"], **kwargs)


def _step_record(env, action, rewards, terms, success) -> None:
    _, reward, _, _, info = env.step(action)
    rewards.append(float(reward))
    parts = env.unwrapped.reward_terms(info)
    for name in TERM_NAMES:
        terms[name].append(float(parts[name]))
    success.append(bool(info["success"]))


def demo_rollout(env, h5_path: str | Path, episode: dict, horizon: int, action_noise: float = 0.0,
                 rng: Optional[np.random.Generator] = None) -> Rollout:
    """Replay ``episode`` (an entry of the file's JSON) from its reset kwargs with its
    recorded actions (pd_joint_pos). ``action_noise`` > 0 perturbs the arm's joint targets
    by a per-episode offset N(0, noise) plus per-step N(0, noise / 2) (rad), drawn from
    ``rng``: a miss of a few centimetres at the hand, as a worse demonstrator would make."""
    import h5py

    if env.unwrapped.control_mode != episode["control_mode"]:
        raise ValueError(f"episode {episode['episode_id']} has {episode['control_mode']} actions but the env "
                         f"runs {env.unwrapped.control_mode}")
    with h5py.File(h5_path, "r") as f:
        actions = f[f"traj_{episode['episode_id']}/actions"][:].astype(np.float32)
    if action_noise > 0:
        offset = rng.normal(0.0, action_noise, size=(1, 7))
        actions = actions.copy()
        actions[:, :7] += (offset + rng.normal(0.0, action_noise / 2, size=(len(actions), 7))).astype(np.float32)
    reset_kwargs = episode["reset_kwargs"]
    env.reset(seed=reset_kwargs.get("seed"), options=reset_kwargs.get("options", {}))
    rewards, terms, success = [], {n: [] for n in TERM_NAMES}, []
    for t in range(max(horizon, len(actions))):
        action = actions[min(t, len(actions) - 1)]
        _step_record(env, torch.from_numpy(action)[None], rewards, terms, success)
    return Rollout(np.array(rewards), {k: np.array(v) for k, v in terms.items()}, np.array(success),
                   recorded_steps=len(actions))


def policy_rollout(env, reset_kwargs: dict, policy: Callable[[int], np.ndarray], horizon: int) -> Rollout:
    """``horizon`` steps of ``policy(step)`` (an action of the env's control mode) from
    the episode ``reset_kwargs`` give."""
    env.reset(seed=reset_kwargs.get("seed"), options=reset_kwargs.get("options", {}))
    rewards, terms, success = [], {n: [] for n in TERM_NAMES}, []
    for t in range(horizon):
        _step_record(env, torch.as_tensor(policy(t), dtype=torch.float32)[None], rewards, terms, success)
    return Rollout(np.array(rewards), {k: np.array(v) for k, v in terms.items()}, np.array(success))
