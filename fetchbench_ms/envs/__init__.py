"""FetchBench environments, registered with ManiSkill and gymnasium on import.

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
from mani_skill.utils.registration import register_env

from ..robots import agents as _robot_agents  # noqa: F401  (registers the other robots' agents)
from ..scenes import SCENE_TYPES
from ..tasks.spec import CATEGORY_LABELS
from .fetchbench import FetchBenchEnv, control_modes, settle_and_hold
from .options import CAMERA_PLACEMENTS, ENV_OPTIONS, SIM_FREQS, parse_env_options
from .pointcloud import FetchClouds, fetch_clouds
from .vector import make_vec_env

MAX_EPISODE_STEPS = 400  # 20 s at 20 Hz



def scene_type_env_id(scene_type: str) -> str:
    name = f"{scene_type}Scene" if scene_type in CATEGORY_LABELS else scene_type
    return f"FetchBench-{name}-v0"


#: env id -> the keyword arguments it fixes.
ENV_KWARGS = {"FetchBench-v0": {}}
ENV_KWARGS.update({f"FetchBench-{c}-v0": {"category": c} for c in CATEGORY_LABELS})
ENV_KWARGS.update({scene_type_env_id(t): {"scene_type": t} for t in SCENE_TYPES})
ENV_IDS = tuple(ENV_KWARGS)

for _env_id, _kwargs in ENV_KWARGS.items():
    # id_fixes: what the id fixes, so a contradicting kwarg (FetchBench-Shelf-v0 with
    # category="Table") is refused rather than silently overriding the id.
    register_env(_env_id, max_episode_steps=MAX_EPISODE_STEPS, id_fixes=dict(_kwargs), **_kwargs)(FetchBenchEnv)


def make(env_id: str, **kwargs):
    """``gymnasium.make`` for FetchBench ids, with an error naming the valid ids."""
    import gymnasium as gym

    if env_id not in ENV_IDS:
        raise ValueError(f"unknown FetchBench env id {env_id!r}; valid: {', '.join(ENV_IDS)}")
    return gym.make(env_id, **kwargs)


__all__ = ["CAMERA_PLACEMENTS", "ENV_IDS", "ENV_OPTIONS", "FetchBenchEnv", "FetchClouds", "SIM_FREQS", "control_modes",
           "fetch_clouds", "make", "make_vec_env", "parse_env_options", "settle_and_hold"]
