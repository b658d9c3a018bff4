"""The per-task mesh-world cache of the expert (``planning.world_models.MESH_WORLD_CACHE``): the
same worlds, and so the same demos, as building every world from scratch."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]


def _tensors(world) -> dict:
    out = {}
    for group, sets in world.groups.items():
        for i, s in enumerate(sets):
            for name, value in vars(s).items():
                if isinstance(value, torch.Tensor):
                    out[(group, i, type(s).__name__, name)] = value
    return out


def _same(a, b) -> bool:
    ta, tb = _tensors(a), _tensors(b)
    return ta.keys() == tb.keys() and all(torch.equal(ta[k], tb[k]) for k in ta)


def _first_train_task(monkeypatch):
    """train/0000, its base and objects' poses (base frame), and a fresh process cache."""
    from fetchbench_ms.planning import world_models as worlds
    from fetchbench_ms.tasks.suite import load_suite

    suite = load_suite("train")
    task = suite.get(suite.ids()[0])
    T_base_world = np.linalg.inv(task.T_world_base())
    cache = worlds.MeshWorldCache()
    monkeypatch.setattr(worlds, "MESH_WORLD_CACHE", cache)
    return task, T_base_world, [T_base_world @ o.transform() for o in task.objects], cache


def test_cached_worlds_are_the_rebuilt_ones(monkeypatch):
    from fetchbench_ms.planning.world import pose_matrix
    from fetchbench_ms.planning import world_models as worlds
    from fetchbench_ms.tasks.suite import load_suite

    task, T_base_world, T_objects, cache = _first_train_task(monkeypatch)
    other = load_suite("train").get(load_suite("train").ids()[1])
    monkeypatch.setenv("FETCHBENCH_MESH_WORLD_CACHE", "0")
    rebuilt = worlds.task_mesh_world(task, T_base_world, T_objects)
    monkeypatch.setenv("FETCHBENCH_MESH_WORLD_CACHE", "1")
    first = worlds.task_mesh_world(task, T_base_world, T_objects)
    again = worlds.task_mesh_world(task, T_base_world, T_objects)
    assert _same(rebuilt, first) and _same(rebuilt, again)
    assert (cache.misses, cache.hits) == (1, 1)
    assert again.groups["scene"][0] is first.groups["scene"][0]  # reused, not rebuilt
    # An object that moved is built at its new pose; the others are reused.
    moved = list(T_objects)
    moved[task.target_index] = moved[task.target_index] @ pose_matrix([0.0, 0.0, 0.05])
    shifted = worlds.task_mesh_world(task, T_base_world, moved)
    monkeypatch.setenv("FETCHBENCH_MESH_WORLD_CACHE", "0")
    assert _same(shifted, worlds.task_mesh_world(task, T_base_world, moved))
    assert not _same(shifted, rebuilt)
    # Another task empties the cache.
    monkeypatch.setenv("FETCHBENCH_MESH_WORLD_CACHE", "1")
    T_other = np.linalg.inv(other.T_world_base())
    worlds.task_mesh_world(other, T_other, [T_other @ o.transform() for o in other.objects])
    assert cache.misses == 2 and all(key[0] in {o.object_id for o in other.objects} for key in cache.objects)


def test_the_generator_makes_the_same_demos_with_the_cache():
    """One train task through the generator's worker with every world rebuilt and with the
    cache: the same trajectories, dataset for dataset (scripts/bench/bench_expert_world.py)."""
    bench = import_script(ROOT / "scripts/bench/bench_expert_world.py")
    # train/0001 gives a trajectory at its first try (train/0000 none: nothing to compare)
    bench.main(["--start", "1", "--tasks", "1", "--per-task", "1"])  # exits non-zero when they differ


def test_pose_tolerance_reuses_sets_of_objects_that_barely_moved(monkeypatch):
    """After a grasp PhysX reports the fixed base and the untouched objects with float noise:
    within the tolerance their sets are reused; the moved target is built anew. Without a
    tolerance (the evaluation's worlds) the noise rebuilds, as before."""
    from fetchbench_ms.planning.world import pose_matrix
    from fetchbench_ms.planning import world_models as worlds

    task, T_base_world, T_objects, cache = _first_train_task(monkeypatch)
    monkeypatch.setenv("FETCHBENCH_MESH_WORLD_CACHE", "1")
    start = worlds.task_mesh_world(task, T_base_world, T_objects)
    noisy_base = T_base_world + 3e-8
    noisy = [T + 1e-6 for T in T_objects]
    noisy[task.target_index] = T_objects[task.target_index] @ pose_matrix([0.0, 0.0, 0.05])
    after = worlds.task_mesh_world(task, noisy_base, noisy, pose_tolerance=5e-4)
    assert cache.misses == 1  # the furniture's sets kept
    others = [k for k in range(len(task.objects)) if k != task.target_index]
    name = lambda k: "target" if k == task.target_index else f"object:{k}"  # noqa: E731
    assert all(after.groups[name(k)][0] is start.groups[name(k)][0] for k in others)
    assert after.groups["target"][0] is not start.groups["target"][0]
    exact = worlds.task_mesh_world(task, noisy_base, noisy)  # no tolerance: everything at its new pose
    assert cache.misses == 2 and all(exact.groups[name(k)][0] is not start.groups[name(k)][0] for k in others)


def test_object_sets_that_skip_the_convexity_test_at_each_pose_are_the_tested_ones():
    """``convex_set_from_parts`` asks each part (object frame) whether it is convex, once a
    process, instead of testing the moved copy at every pose: over the objects of a few train
    tasks placed at random poses, the verdicts and the sets' planes and balls are the same."""
    from fetchbench_ms.objects.loading import load_object
    from fetchbench_ms.planning.world import ConvexSet, convex_set_from_parts, pose_matrix
    from fetchbench_ms.tasks.suite import load_suite
    from scipy.spatial.transform import Rotation

    suite = load_suite("train")
    ids = sorted({o.object_id for task_id in suite.ids()[1500:1504] for o in suite.get(task_id).objects})
    rng = np.random.default_rng(0)
    parts_seen = 0
    for object_id in ids:
        parts = load_object(object_id).convex_parts
        quat = Rotation.random(random_state=int(rng.integers(2**31))).as_quat()[[3, 0, 1, 2]]
        T = pose_matrix(rng.uniform(-1, 1, 3), quat)
        moved = [p.copy().apply_transform(T) for p in parts]
        assert [bool(m.is_convex) for m in moved] == [bool(p.is_convex) for p in parts], object_id
        fast, tested = convex_set_from_parts(parts, T), ConvexSet(moved)
        for name in ("planes", "bound_center", "bound_radius"):
            assert torch.equal(getattr(fast, name), getattr(tested, name)), (object_id, name)
        parts_seen += len(parts)
    assert len(ids) >= 20 and parts_seen >= 100
