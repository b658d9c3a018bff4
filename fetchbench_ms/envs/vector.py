"""Many FetchBench environments on the CPU: a gymnasium vector env of single-scene envs.

ManiSkill batches sub-scenes only in GPU simulation (``num_envs > 1`` needs
``sim_backend="physx_cuda"``); on the CPU each env simulates one scene, so parallel envs
are processes::

    envs = fetchbench_ms.envs.make_vec_env("FetchBench-v0", 4, obs_mode="state",
                                           control_mode="pd_joint_delta_pos")
    obs, info = envs.reset(seed=0)      # env i gets seed 0 + i (gymnasium's rule)
    obs, reward, terminated, truncated, info = envs.step(envs.action_space.sample())

Each worker holds ``CPUGymWrapper(gym.make(env_id, **kwargs))``: numpy observations
without the batch dimension, as gymnasium's vector API expects, and gymnasium's
auto-reset after an episode ends.
"""
from __future__ import annotations

import functools


def _make_cpu_env(env_id: str, kwargs: dict, wrappers: tuple = (), wrapper_kwargs: dict | None = None):
    import gymnasium as gym
    import torch
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    import fetchbench_ms  # noqa: F401  (registers FetchBench-*-v0 in a spawned worker)

    # One scene per process: torch's own thread pool would only fight the other workers
    # for the cores (a machine of N cores runs N workers).
    torch.set_num_threads(1)
    env = gym.make(env_id, **kwargs)
    for wrapper in wrappers:
        env = wrapper(env)
    return CPUGymWrapper(env, **(wrapper_kwargs or {}))


def make_vec_env(env_id: str, num_envs: int, context: str = "spawn", wrappers: tuple = (),
                 record_metrics: bool = False, ignore_terminations: bool = False, autoreset_mode=None, **kwargs):
    """A ``gymnasium.vector.AsyncVectorEnv`` of ``num_envs`` CPU envs ``env_id`` made with
    ``kwargs`` (every env kwarg, e.g. ``obs_mode``, ``control_mode``, ``task_source``).

    Workers are separate processes started with ``context`` (``"spawn"`` by default:
    a fork of a process that has rendered can break SAPIEN's renderer); each imports
    the package, so the first reset takes a few seconds. ``num_envs`` and ``sim_backend``
    are not env kwargs here: every worker simulates one scene on the CPU.

    ``wrappers``: callables (picklable: classes or module-level functions) applied in
    order to each worker's batched ManiSkill env before ``CPUGymWrapper``;
    ``record_metrics`` / ``ignore_terminations``: ``CPUGymWrapper``'s (episode return,
    length, success_once in ``info["episode"]``); ``autoreset_mode``: gymnasium's
    (``gymnasium.vector.AutoresetMode.SAME_STEP`` resets a finished env in the same step
    and hands over ``final_obs`` / ``final_info``, as ManiSkill's GPU vector env does)."""
    import gymnasium as gym

    from .env_ids import ENV_IDS

    if env_id not in ENV_IDS:
        raise ValueError(f"unknown FetchBench env id {env_id!r}; valid: {', '.join(ENV_IDS)}")
    if int(num_envs) < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    for key in ("num_envs", "sim_backend"):
        if key in kwargs:
            raise ValueError(f"make_vec_env runs one CPU env per worker process: leave {key!r} out of the env kwargs")
    factory = functools.partial(_make_cpu_env, env_id, {**kwargs, "sim_backend": "physx_cpu"}, tuple(wrappers),
                                dict(record_metrics=record_metrics, ignore_terminations=ignore_terminations))
    extra = {} if autoreset_mode is None else {"autoreset_mode": autoreset_mode}
    from ..utils.quiet import announce_render_device

    announce_render_device()  # once here, not once a worker
    return gym.vector.AsyncVectorEnv([factory] * int(num_envs), context=context, **extra)
