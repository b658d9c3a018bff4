"""The caches an evaluation worker keeps across tasks stay bounded over many tasks
(``evaluation.worker_caches``), and what they evict comes back the same.

Runs the per-task code that fills them (a worker's path minus the simulator: the oracle mesh
world of each task through the process's ``MESH_WORLD_CACHE``, the objects' files, the
target's annotated grasps, and the trajectory optimiser's device-side world and robot) for
enough distinct val tasks that the per-object caches reach their bounds, then checks every
cache is within its bound, that the memory the process holds (traced) grows by less than a
margin from the end of a warm-up to the end (an unbounded object cache holds ~0.1 MB per object, about a dozen
new objects a task), and that no tensors are left behind by the per-task torch worlds.
"""
from __future__ import annotations

import gc
import tracemalloc

import numpy as np
import torch

WARM_UP_TASKS = 22  # by then ``load_object`` holds its 256 objects (~12 new ones a task)
MEASURED_TASKS = 20  # ~240 objects more: held, were the object cache unbounded (+15 MB here)
# Bytes the held memory may grow by over the measured tasks. Bounded it grows ~5 MB here: a
# new target's grasps each task, and the objects held at the end weighing more or less than
# those held after the warm-up.
HELD_GROWTH_MARGIN = 9e6


def _world_tensors(world) -> dict:
    return {(group, i, name): value for group, sets in world.groups.items() for i, s in enumerate(sets)
            for name, value in vars(s).items() if isinstance(value, torch.Tensor)}


def _live_tensor_bytes() -> int:
    gc.collect()
    return sum(o.untyped_storage().nbytes() for o in gc.get_objects() if type(o) is torch.Tensor)


def test_worker_caches_stay_bounded_and_evictions_rebuild_the_same(monkeypatch):
    from fetchbench_ms.evaluation.worker_caches import cache_sizes
    from fetchbench_ms.grasp_labels.candidates import object_grasps
    from fetchbench_ms.grasp_labels.store import _default_store
    from fetchbench_ms.objects.loading import LOADED_OBJECTS_KEPT, load_object
    from fetchbench_ms.planning import world_models as worlds
    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.distance import PairCache, TorchRobot, TorchWorld
    from fetchbench_ms.planning.robot import panda
    from fetchbench_ms.sim.bodies import object_files
    from fetchbench_ms.tasks.suite import load_suite

    suite = load_suite("val")
    tasks = [suite.get(task_id) for task_id in suite.ids()[: WARM_UP_TASKS + MEASURED_TASKS]]
    robot = panda()
    monkeypatch.setattr(worlds, "MESH_WORLD_CACHE", worlds.MeshWorldCache())
    store = _default_store()
    for shard in map(int, store.manifest["shards"]):  # the grasp store's fixed 64 shards, loaded up front
        store._shard(shard)

    def mesh_world(task):
        T_base_world = np.linalg.inv(task.T_world_base())
        return worlds.task_mesh_world(task, T_base_world, [T_base_world @ o.transform() for o in task.objects])

    def run_task(task, k: int) -> None:
        world = mesh_world(task)
        for placement in task.objects:
            object_files(placement.object_id)
        object_grasps(task.target.object_id)
        # What trajopt builds on its device for one plan: the world and robot tensors, a
        # batch of configurations' collision cost through the pair cache.
        checker = CollisionChecker(robot, world)
        torch_world = TorchWorld([world], [()], "cpu", max_planes=24)
        torch_robot = TorchRobot(robot, [checker], "cpu")
        q = torch.as_tensor(np.random.default_rng(k).uniform(robot.q_min, robot.q_max, (1, 16, 7)),
                            dtype=torch.float32)
        centers, _ = torch_robot.spheres(q)
        radii = torch_robot.world_radii[:, None].expand(1, 16, centers.shape[2]).reshape(1, -1)
        torch_world.penalty(centers.reshape(1, -1, 3), radii, 0.03, torch_robot.groups, PairCache(0.03))

    def held_bytes() -> int:
        """Traced memory held now, less the last task's obstacle sets (one task's: the cache
        empties at the next task) and anything only a reference cycle keeps."""
        monkeypatch.setattr(worlds, "MESH_WORLD_CACHE", worlds.MeshWorldCache())
        gc.collect()
        return tracemalloc.get_traced_memory()[0]

    first_task = tasks[0]
    first_world = _world_tensors(mesh_world(first_task))
    first_object = load_object(first_task.target.object_id)
    tracemalloc.start()
    try:
        for k, task in enumerate(tasks[:WARM_UP_TASKS]):
            run_task(task, k)
        held_after_warm_up, tensors_after_warm_up = held_bytes(), _live_tensor_bytes()
        for k, task in enumerate(tasks[WARM_UP_TASKS:], start=WARM_UP_TASKS):
            run_task(task, k)
        held_growth = held_bytes() - held_after_warm_up
    finally:
        tracemalloc.stop()

    sizes = cache_sizes()
    unbounded = [s.name for s in sizes if s.bound is None]
    assert not unbounded, f"caches filled per task without a bound: {unbounded}"
    over = [s for s in sizes if s.size > s.bound]
    assert not over, f"caches over their bound: {over}"
    loaded = next(s for s in sizes if s.name == "objects.loading.load_object")
    assert loaded.size == loaded.bound == LOADED_OBJECTS_KEPT  # the run reached the bound it checks
    assert held_growth < HELD_GROWTH_MARGIN, (
        f"{held_growth / 1e6:.1f} MB more held after {MEASURED_TASKS} tasks than after a warm-up of "
        f"{WARM_UP_TASKS} (margin {HELD_GROWTH_MARGIN / 1e6:.0f} MB): a cache grows per task")
    assert _live_tensor_bytes() <= tensors_after_warm_up + 1e6  # no per-task torch world left alive

    # The first task's objects were evicted since; rebuilt, they give the same world, bit for bit.
    assert load_object(first_task.target.object_id) is not first_object
    rebuilt = _world_tensors(mesh_world(first_task))
    assert rebuilt.keys() == first_world.keys()
    assert all(torch.equal(rebuilt[k], first_world[k]) for k in first_world)
