"""Fetching tasks: the plain ``TaskSpec`` and the sampler that draws one from a seed.

    from fetchbench_ms.tasks import sample_task
    task = sample_task(seed=3, category="Shelf")      # a TaskSpec
    same = TaskSpec.from_dict(task.to_dict())          # JSON round trip
"""
from .sampler import SamplerConfig, categories, sample_task, scene_types_for
from .spec import CATEGORY_LABELS, DEFAULT_QPOS, CameraPose, ObjectPlacement, TaskSpec

__all__ = [
    "CATEGORY_LABELS", "DEFAULT_QPOS", "CameraPose", "ObjectPlacement", "SamplerConfig", "TaskSpec",
    "categories", "sample_task", "scene_types_for",
]
