"""The ``env_info`` that FetchBench trajectory files carry, written so that tools knowing
nothing of the plugin replay them: ManiSkill's own
``python -m mani_skill.trajectory.replay_trajectory`` makes the env with
``gym.make(env_info["env_id"], **env_info["env_kwargs"])``."""
from __future__ import annotations

from ..envs import PLUGIN_MODULE, recorded_env_id


def replayable_env_info(env_info: dict | None) -> dict | None:
    """``env_info`` with the env id Gymnasium resolves by importing the plugin
    (``fetchbench_ms:FetchBench-v0``, ``envs.recorded_env_id``) and without
    ``render_backend="none"`` among the env kwargs: recording without a renderer is a setting
    of data collection, not part of the task, and a replay into a camera obs mode
    (``-o pointcloud``) needs one. Other ids and kwargs are left as they are; ``None`` (an
    empty file) stays ``None``. Files with a plain id (``FetchBench-v0``) stay readable: every
    reader makes the env with ``gym.make``, which takes both forms."""
    if not env_info or not isinstance(env_info.get("env_id"), str):
        return env_info
    env_id = recorded_env_id(env_info["env_id"])
    if not env_id.startswith(f"{PLUGIN_MODULE}:"):
        return env_info  # not a FetchBench env
    kwargs = {k: v for k, v in (env_info.get("env_kwargs") or {}).items()
              if not (k == "render_backend" and v in (None, "none"))}
    return {**env_info, "env_id": env_id, "env_kwargs": kwargs}
