"""The checks of the FetchBench env's keyword arguments, made before anything is built: a
bad value gets a ``ValueError`` naming the valid choices where ManiSkill would raise a bare
``TypeError``, ``KeyError``, ``NotImplementedError`` or an assertion from deep inside."""
from __future__ import annotations

import difflib
import inspect
from typing import Optional

import torch
from mani_skill.agents.robots.panda.panda import Panda
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.envs.utils.system.backend import sim_backend_name_mapping
from mani_skill.utils.structs.types import SimConfig

from .obs_modes import check_obs_mode


def control_modes() -> tuple[str, ...]:
    """The Panda's control modes (its controller configs are class-level, no robot needed);
    every robot of ``fetchbench_ms.robots`` has the same ones."""
    return tuple(Panda._controller_configs.fget(Panda))


def check_num_envs(num_envs: int, sim_backend: str = "auto") -> None:
    """ValueError for GPU simulation asked for without a CUDA device, and for several
    sub-scenes where GPU simulation is impossible (ManiSkill raises a bare RuntimeError
    about a missing "cuda" device or a CPU backend), naming the ways that work."""
    backend = str(sim_backend).split(":")[0]
    if sim_backend_name_mapping.get(backend) == "physx_cuda" and not torch.cuda.is_available():
        raise ValueError(f"sim_backend={sim_backend!r} simulates on a CUDA GPU, and no CUDA device is available "
                         "here; valid here: sim_backend='auto' or 'physx_cpu' (one sub-scene an env; for many, "
                         "fetchbench_ms.envs.make_vec_env)")
    if num_envs <= 1:
        return
    cpu = backend in ("cpu", "physx_cpu")
    if cpu or not torch.cuda.is_available():
        why = (f"sim_backend={sim_backend!r} simulates one sub-scene" if cpu
               else "no CUDA device is available here")
        raise ValueError(
            f"num_envs={num_envs} needs GPU simulation, but {why}. Either run sim_backend='physx_cuda' on a "
            "machine with a CUDA GPU (and SAPIEN's PhysX GPU runtime), or on the CPU use "
            f"fetchbench_ms.envs.make_vec_env(env_id, {num_envs}, **kwargs): a gymnasium AsyncVectorEnv of "
            "single-scene CPU envs")


def check_kwarg_names(cls, kwargs: dict) -> None:
    """ValueError for a keyword argument neither the env nor ManiSkill's ``BaseEnv`` takes
    (``camera_widht``), with the closest valid name; Python would raise a bare TypeError
    from deep inside ManiSkill."""
    taken = {fn: [name for name, p in inspect.signature(fn).parameters.items()
                  if name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
             for fn in (cls.__init__, BaseEnv.__init__)}
    unknown = [name for name in kwargs if name not in taken[BaseEnv.__init__]]
    if unknown:
        valid = sorted({name for names in taken.values() for name in names})
        close = difflib.get_close_matches(unknown[0], valid, n=1)
        hint = f"did you mean {close[0]!r}? " if close else ""
        raise ValueError(f"unknown env kwarg {unknown[0]!r}; {hint}valid: {', '.join(valid)}")


def check_maniskill_kwargs(cls, kwargs: dict) -> None:
    """ValueErrors naming the valid choices for ManiSkill's own kwargs, raised before any
    scene is built (ManiSkill raises NotImplementedError, KeyError or an assertion)."""
    control_mode = kwargs.get("control_mode")
    if control_mode is not None and control_mode not in control_modes():
        raise ValueError(f"unknown control mode {control_mode!r}; valid: {', '.join(control_modes())}")
    reward_mode = kwargs.get("reward_mode")
    if reward_mode is not None and reward_mode not in cls.SUPPORTED_REWARD_MODES:
        raise ValueError(f"unknown reward_mode {reward_mode!r}; valid: {', '.join(cls.SUPPORTED_REWARD_MODES)}")
    render_mode = kwargs.get("render_mode")
    if render_mode is not None and render_mode not in cls.SUPPORTED_RENDER_MODES:
        raise ValueError(f"unknown render_mode {render_mode!r}; valid: None, {', '.join(cls.SUPPORTED_RENDER_MODES)}")
    sim_backend = kwargs.get("sim_backend", "auto")
    if sim_backend != "auto" and str(sim_backend).split(":")[0] not in sim_backend_name_mapping:
        valid = ", ".join(["auto", *sim_backend_name_mapping])
        raise ValueError(f"unknown sim_backend {sim_backend!r}; valid: {valid} (a GPU may be named, e.g. cuda:1)")
    check_obs_mode(kwargs.get("obs_mode"), kwargs.get("render_backend", "gpu"))


def check_sim_config(sim_freq: Optional[int], sim_config) -> None:
    """ValueError when ManiSkill's ``sim_config`` sets another physics rate than the
    ``sim_freq`` kwarg (it would silently win over the kwarg)."""
    if sim_freq is None or sim_config is None:
        return
    given = sim_config.sim_freq if isinstance(sim_config, SimConfig) else dict(sim_config).get("sim_freq")
    if given is not None and given != sim_freq:
        raise ValueError(f"sim_config sets sim_freq={given!r} but the sim_freq kwarg is {sim_freq!r}; valid: give "
                         "the physics rate once, as sim_freq=60 or 120 (or only in sim_config)")


def check_id_fixes(id_fixes: Optional[dict], **given) -> None:
    """ValueError when a kwarg contradicts what the env id fixes (e.g.
    ``gym.make("FetchBench-Shelf-v0", category="Table")``). ``id_fixes``: the kwargs the id
    was registered with (``fetchbench_ms.envs.ENV_KWARGS``)."""
    for key, fixed in (id_fixes or {}).items():
        if given.get(key) != fixed:
            from .env_ids import ENV_KWARGS

            env_id = next(i for i, kw in ENV_KWARGS.items() if kw == id_fixes)
            wanted = [i for i, kw in ENV_KWARGS.items() if kw == {key: given.get(key)}]
            raise ValueError(
                f"{env_id} is the env for {key}={fixed!r}, but {key}={given.get(key)!r} was given; valid: leave "
                f"{key} out (or give {key}={fixed!r}), or make " + (f"{wanted[0]} or " if wanted else "")
                + f"FetchBench-v0 with {key}={given.get(key)!r}")
