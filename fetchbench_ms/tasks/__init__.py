"""Fetching tasks: the plain ``TaskSpec`` and the sampler that draws one from a seed.

    from fetchbench_ms.tasks import sample_task
    task = sample_task(seed=3, category="Shelf")      # a TaskSpec
    same = TaskSpec.from_dict(task.to_dict())          # JSON round trip
"""
from .spec import CATEGORY_LABELS, DEFAULT_QPOS, CameraPose, ObjectPlacement, TaskSpec

_SAMPLER_NAMES = ("SamplerConfig", "categories", "sample_task", "scene_types_for")


def __getattr__(name: str):
    # The sampler (trimesh, scipy) loads on first use: reading a TaskSpec needs neither.
    if name in _SAMPLER_NAMES:
        from . import sampler

        return getattr(sampler, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "CATEGORY_LABELS", "DEFAULT_QPOS", "CameraPose", "ObjectPlacement", "SamplerConfig", "TaskSpec",
    "categories", "sample_task", "scene_types_for",
]
