"""FetchBench environments, registered with gymnasium on import (with ManiSkill at the first
``gym.make``, which loads the simulator).

- ``FetchBench-v0``: any scene type, any target;
- ``FetchBench-{Table,Shelf,Drawer,Basket}-v0``: the target rests on that kind of support;
- ``FetchBench-{SceneType}-v0``: scenes of one of the 13 types (e.g. ``FetchBench-LargeShelf-v0``);
  the scene type "Drawer" is ``FetchBench-DrawerScene-v0``, because ``FetchBench-Drawer-v0``
  is the in-drawer category.

Env options toward the original FetchBench, for ablations (``fetchbench_ms.envs.options``):
``sim_freq`` (120 default, or 60 Hz) and ``camera_placement`` (``"task"`` default, or
``"paper"``); ``parse_env_options(["sim_freq=60", ...])`` turns ``NAME=VALUE`` strings into
those kwargs.
"""
import functools
import importlib

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

from .env_ids import (  # noqa: F401  (the ids and their tables: public here)
    ENV_IDS, ENV_KWARGS, MAX_EPISODE_STEPS, PLUGIN_MODULE, recorded_env_id, scene_type_env_id)


def _default_kwargs(env_id: str) -> dict:
    # id_fixes: what the id fixes, so a contradicting kwarg (FetchBench-Shelf-v0 with
    # category="Table") is refused rather than silently overriding the id.
    return {"id_fixes": dict(ENV_KWARGS[env_id]), **ENV_KWARGS[env_id]}


def register_with_maniskill() -> None:
    """Registers every id in ManiSkill's registry (it imports the simulator): done by the first
    ``gym.make`` of a FetchBench id, or by hand for a tool that reads that registry."""
    from mani_skill.utils.registration import REGISTERED_ENVS, register

    from ..utils.quiet import quiet_maniskill
    from .fetchbench import FetchBenchEnv

    quiet_maniskill()  # ManiSkill's warnings that are expected on a CPU machine

    for env_id in ENV_IDS:
        if env_id not in REGISTERED_ENVS:
            register(env_id, FetchBenchEnv, max_episode_steps=MAX_EPISODE_STEPS, default_kwargs=_default_kwargs(env_id))


def _make_env(env_id: str, **kwargs):
    """gymnasium's entry point of every FetchBench id: ManiSkill's own (``register_env``)
    once the ids are in ManiSkill's registry."""
    from mani_skill.utils.registration import make

    register_with_maniskill()
    return make(env_id, **kwargs)


def _make_vec_env(env_id: str, **kwargs):
    from mani_skill.utils.registration import make_vec

    register_with_maniskill()
    return make_vec(env_id, **kwargs)


# Registered with gymnasium as ManiSkill's ``register_env`` does (its time-limit wrapper,
# no env checker), with entry points that load the simulator only when an env is made:
# importing the package (a CLI answering a bad flag, a worker reading a file) stays light.
for _env_id in ENV_IDS:
    if _env_id not in gym.registry:
        gym.register(
            _env_id,
            entry_point=functools.partial(_make_env, env_id=_env_id),
            vector_entry_point=functools.partial(_make_vec_env, env_id=_env_id),
            max_episode_steps=MAX_EPISODE_STEPS,
            disable_env_checker=True,
            kwargs=_default_kwargs(_env_id),
            additional_wrappers=[WrapperSpec("MSTimeLimit", entry_point="mani_skill.utils.registration:TimeLimitWrapper",
                                             kwargs=dict(max_episode_steps=MAX_EPISODE_STEPS))],
        )


def make(env_id: str, **kwargs):
    """``gymnasium.make`` for FetchBench ids, with an error naming the valid ids."""
    if env_id not in ENV_IDS:
        raise ValueError(f"unknown FetchBench env id {env_id!r}; valid: {', '.join(ENV_IDS)}")
    return gym.make(env_id, **kwargs)


#: Names loaded on first use (they import torch and the simulator).
_LAZY = {
    "FetchBenchEnv": "fetchbench", "control_modes": "fetchbench",
    "settle_and_hold": "judging", "judge": "judging", "Judgement": "judging",
    "CAMERA_PLACEMENTS": "options", "ENV_OPTIONS": "options", "SIM_FREQS": "options", "parse_env_options": "options",
    "FetchClouds": "pointcloud", "fetch_clouds": "pointcloud", "make_vec_env": "vector",
}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["CAMERA_PLACEMENTS", "ENV_IDS", "ENV_OPTIONS", "FetchBenchEnv", "FetchClouds", "Judgement", "SIM_FREQS", "control_modes",
           "fetch_clouds", "judge", "make", "make_vec_env", "parse_env_options", "register_with_maniskill",
           "settle_and_hold"]
