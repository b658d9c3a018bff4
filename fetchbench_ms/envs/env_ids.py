"""The FetchBench env ids and what each fixes (``ENV_KWARGS``), the episode length, and the
ids as trajectory files record them. Plain data below the env package's modules, which
read it from here; ``fetchbench_ms.envs`` hands these names on."""
from ..scenes import SCENE_TYPES
from ..tasks.spec import CATEGORY_LABELS

MAX_EPISODE_STEPS = 400  # 20 s at 20 Hz


def scene_type_env_id(scene_type: str) -> str:
    name = f"{scene_type}Scene" if scene_type in CATEGORY_LABELS else scene_type
    return f"FetchBench-{name}-v0"


#: env id -> the keyword arguments it fixes.
ENV_KWARGS = {"FetchBench-v0": {}}
ENV_KWARGS.update({f"FetchBench-{c}-v0": {"category": c} for c in CATEGORY_LABELS})
ENV_KWARGS.update({scene_type_env_id(t): {"scene_type": t} for t in SCENE_TYPES})
ENV_IDS = tuple(ENV_KWARGS)
#: The module that registers the ids: ``gym.make("fetchbench_ms:FetchBench-v0")`` imports it
#: first (Gymnasium's ``module:id`` form), so a program that never imported the plugin can
#: make the env.
PLUGIN_MODULE = "fetchbench_ms"


def recorded_env_id(env_id: str) -> str:
    """``env_id`` as trajectory files record it: ``fetchbench_ms:FetchBench-v0`` for a
    FetchBench id (plain or already qualified), any other id unchanged."""
    plain = env_id.split(":", 1)[1] if env_id.startswith(f"{PLUGIN_MODULE}:") else env_id
    return f"{PLUGIN_MODULE}:{plain}" if plain in ENV_KWARGS else env_id
