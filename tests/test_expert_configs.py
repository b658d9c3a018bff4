"""The expert's named configurations (``solutions.expert.EXPERTS``): what each changes, that the
baselines' defaults are untouched, and that the demo files record which one made them."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from fetchbench_ms.demos.generate import DemoJob
from fetchbench_ms.solutions.expert import EXPERTS, expert_spec
from fetchbench_ms.solutions.sense_plan_act import SolveConfig


def test_fast_and_reference_experts():
    assert expert_spec("reference").config() == EXPERTS["reference"].config()
    reference, fast = EXPERTS["reference"].config(), EXPERTS["fast"].config()
    # the reference expert is the evaluation pipeline's defaults for everything the fast one sets
    baseline = SolveConfig()
    for name in dict(EXPERTS["fast"].solve):
        assert getattr(reference, name) == getattr(baseline, name)
    assert (fast.pregrasp_goal_sets, fast.attachment_per_object, fast.plan_checks_per_try) == (3, True, 15000)
    assert json.loads(json.dumps(EXPERTS["fast"].to_json()))["solve"]["world_pose_tolerance"] == 5e-4
    with pytest.raises(ValueError, match="unknown expert 'quick'; valid: reference, fast"):
        expert_spec("quick")


def test_a_job_recorded_before_experts_had_names_is_the_reference_one():
    old = {k: v for k, v in DemoJob().__dict__.items() if k != "expert"}
    assert DemoJob.from_json(old) == {**old, "expert": "reference"}
    assert DemoJob.from_json({**old, "expert": "fast"})["expert"] == "fast"


def _tensors(world) -> list:
    return [(g, i, k, v) for g, sets in world.groups.items() for i, s in enumerate(sets)
            for k, v in vars(s).items() if isinstance(v, torch.Tensor)]


def test_pose_tolerance_reuses_sets_of_objects_that_barely_moved(monkeypatch):
    """After a grasp PhysX reports the fixed base and the untouched objects with float noise:
    within the tolerance their sets are reused; the moved target is built anew. Without a
    tolerance (the evaluation's worlds) the noise rebuilds, as before."""
    from fetchbench_ms.planning.world import pose_matrix
    from fetchbench_ms.solutions import worlds
    from fetchbench_ms.tasks.suite import load_suite

    suite = load_suite("train")
    task = suite.get(suite.ids()[0])
    T_base_world = np.linalg.inv(task.T_world_base())
    T_objects = [T_base_world @ o.transform() for o in task.objects]
    cache = worlds.MeshWorldCache()
    monkeypatch.setattr(worlds, "MESH_WORLD_CACHE", cache)
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


def test_balls_fitted_in_the_object_frame_cover_the_object_in_the_hand():
    from fetchbench_ms.planning.world import pose_matrix
    from fetchbench_ms.solutions.sense_plan_act import _object_attachment
    from fetchbench_ms.tasks.objects import load_object
    from fetchbench_ms.tasks.suite import load_suite

    object_id = load_suite("train").get(load_suite("train").ids()[1]).target.object_id
    T_hand_object = pose_matrix([0.01, -0.02, 0.1], [0.5, 0.5, -0.5, 0.5])
    balls = _object_attachment(object_id).moved(T_hand_object)
    assert _object_attachment(object_id) is _object_attachment(object_id)  # fitted once a process
    for part in load_object(object_id).convex_parts:
        vertices = part.vertices @ T_hand_object[:3, :3].T + T_hand_object[:3, 3]
        d = np.linalg.norm(vertices[:, None] - balls.centers_hand[None], axis=2) - balls.radii[None]
        assert (d.min(axis=1) <= 1e-9).all()  # every vertex inside a ball
