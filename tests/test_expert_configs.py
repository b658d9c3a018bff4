"""The expert's named configurations (``solutions.expert.EXPERTS``): what each changes, that the
baselines' defaults are untouched, and that the demo files record which one made them."""
from __future__ import annotations

import json

import numpy as np
import pytest

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
    assert (fast.pregrasp_goal_sets, fast.attachment_per_object, fast.reuse_candidates) == (3, True, True)
    assert (EXPERTS["fast"].max_failures_in_a_row, EXPERTS["reference"].max_failures_in_a_row) == (3, 0)
    assert json.loads(json.dumps(EXPERTS["fast"].to_json()))["solve"]["world_pose_tolerance"] == 5e-4
    with pytest.raises(ValueError, match="unknown expert 'quick'; valid: reference, fast"):
        expert_spec("quick")


def test_a_job_recorded_before_experts_had_names_is_the_reference_one():
    old = {k: v for k, v in DemoJob().__dict__.items() if k != "expert"}
    assert DemoJob.from_json(old) == {**old, "expert": "reference"}
    assert DemoJob.from_json({**old, "expert": "fast"})["expert"] == "fast"


def test_balls_fitted_in_the_object_frame_cover_the_object_in_the_hand():
    from fetchbench_ms.planning.world import pose_matrix
    from fetchbench_ms.solutions.sense_plan_act import _object_attachment
    from fetchbench_ms.objects.loading import load_object
    from fetchbench_ms.tasks.suite import load_suite

    object_id = load_suite("train").get(load_suite("train").ids()[1]).target.object_id
    T_hand_object = pose_matrix([0.01, -0.02, 0.1], [0.5, 0.5, -0.5, 0.5])
    balls = _object_attachment(object_id).moved(T_hand_object)
    assert _object_attachment(object_id) is _object_attachment(object_id)  # fitted once a process
    for part in load_object(object_id).convex_parts:
        vertices = part.vertices @ T_hand_object[:3, :3].T + T_hand_object[:3, 3]
        d = np.linalg.norm(vertices[:, None] - balls.centers_hand[None], axis=2) - balls.radii[None]
        assert (d.min(axis=1) <= 1e-9).all()  # every vertex inside a ball
