"""The caches an evaluation worker keeps from task to task, and what bounds them.

A worker runs hundreds of tasks in one process (``evaluation.local``, ``evaluation.ray_backend``),
so anything it remembers per object, scene or task must have a bound, or its memory grows
with the run. ``bounded_caches`` names the in-memory caches that a task fills with entries
of its own (its objects, its furniture, its sampled task), each with its bound; the test
``tests/test_cache_bounds.py`` runs many tasks' worth of them and checks each stays within
it. Caches keyed by something a run does not change (the robot model, the network weights,
the suite file, the grasp store) hold a handful of entries and are left out.

``release_between_tasks`` hands the torch CUDA allocator's unused blocks back after a task.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable


@dataclass(frozen=True)
class CacheSize:
    name: str  # module.attribute
    size: int  # entries now
    bound: int | None  # entries at most (None: unbounded, a defect for these caches)


def _lru(name: str, fn) -> Callable[[], CacheSize]:
    return lambda: CacheSize(name, fn.cache_info().currsize, fn.cache_info().maxsize)


def bounded_caches() -> list[Callable[[], CacheSize]]:
    """Per cache filled per task: a function giving its ``CacheSize`` now."""
    from ..envs import curriculum, task_source
    from ..grasp_labels import candidates
    from ..objects import catalog, loading
    from ..planning import world_models
    from ..scenes import sapien_build
    from ..sim import bodies
    from ..solutions import sense_plan_act

    mesh_worlds = world_models.MESH_WORLD_CACHE
    return [
        _lru("objects.loading.load_object", loading.load_object),
        _lru("objects.catalog.get_object", catalog.get_object),
        _lru("sim.bodies.object_files", bodies.object_files),
        _lru("sim.bodies._render_material", bodies._render_material),
        _lru("scenes.sapien_build._render_material", sapien_build._render_material),
        _lru("grasp_labels.candidates.object_grasps", candidates.object_grasps),
        _lru("solutions.sense_plan_act._object_attachment", sense_plan_act._object_attachment),
        _lru("envs.task_source.sample_task_cached", task_source.sample_task_cached),
        _lru("envs.curriculum._apply_cached", curriculum._apply_cached),
        lambda: CacheSize("envs.task_source._SCENES", len(task_source._SCENES), task_source._SCENES_KEPT),
        # One task's obstacle sets at a time (a new task empties it), at most max_objects of them.
        lambda: CacheSize("planning.world_models.MESH_WORLD_CACHE.objects", len(mesh_worlds.objects),
                          mesh_worlds.max_objects),
    ]


def cache_sizes() -> list[CacheSize]:
    return [size() for size in bounded_caches()]


def release_between_tasks() -> None:
    """Return the torch CUDA allocator's cached, unused blocks to the device.

    The torch planners (trajopt, MPPI) allocate tensors whose sizes follow the task: the
    obstacle and sphere-pair tensors grow with its world. The caching allocator keeps every
    freed block for reuse, so blocks cut to earlier tasks' sizes pile up in its pool; over a
    long run the pool, not the live tensors, is what grows. Emptying it between tasks bounds
    a worker's reserved memory by one task's peak, for a few ms a task (tasks take seconds).
    A process that never used CUDA is not touched (no context is created here)."""
    import torch

    if torch.cuda.is_initialized():
        torch.cuda.empty_cache()
