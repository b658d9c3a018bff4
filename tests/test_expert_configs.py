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


def test_fast2_is_fast_with_the_approach_tolerance_and_records_it():
    fast, fast2 = EXPERTS["fast"], EXPERTS["fast2"]
    assert dict(fast2.solve) == {**dict(fast.solve), "approach_tolerance": 0.002}
    assert fast2.max_failures_in_a_row == fast.max_failures_in_a_row
    assert SolveConfig().approach_tolerance == 0.0 and fast.config().approach_tolerance == 0.0
    recorded = json.loads(json.dumps(fast2.to_json()))
    assert recorded["name"] == "fast2" and recorded["solve"]["approach_tolerance"] == 0.002
    assert "approach_tolerance" not in fast.to_json()["solve"]  # fast's recorded settings are unchanged


def _first_try(expert: str, seed: int):
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.demos.generate import suite_task_ids
    from fetchbench_ms.solutions.expert import solve_demo

    task_id = suite_task_ids("FetchBench-v0", "train")[seed]
    env = gym.make("FetchBench-v0", obs_mode="none", control_mode="pd_joint_pos", task_suite="train",
                   render_backend="none", reward_mode="none")
    try:
        return solve_demo(env, seed, reset_options={"task_id": task_id}, tried=set(),
                          config=expert_spec(expert).config())
    finally:
        env.close()


def test_a_finger_that_clears_the_board_by_a_hair_is_tried_by_fast2():
    """train/1509 (a drawer): fast finds no free straight approach (the spheres overlap the world
    by under 0.1 mm) and says why; fast2's 2 mm tolerance approaches, grasps and retrieves."""
    fast = _first_try("fast", 1509)
    assert (fast.success, fast.failure, fast.reason) == (False, "no_grasp_candidate", "no_approach")
    fast2 = _first_try("fast2", 1509)
    assert fast2.success and fast2.reason is None and fast2.steps > 0


def test_fast3_is_fast2_with_segment_checks_that_look_at_the_start_first():
    fast2, fast3 = EXPERTS["fast2"], EXPERTS["fast3"]
    assert dict(fast3.solve) == {**dict(fast2.solve), "motion_check_first": 16}
    assert fast3.max_failures_in_a_row == fast2.max_failures_in_a_row
    assert SolveConfig().motion_check_first == 0 and fast2.config().motion_check_first == 0
    assert json.loads(json.dumps(fast3.to_json()))["solve"]["motion_check_first"] == 16
    assert "motion_check_first" not in fast2.to_json()["solve"]


def test_every_expert_can_be_asked_for_by_name():
    """The command lines that make demonstrations offer every configuration in ``EXPERTS``."""
    import argparse
    import re
    from pathlib import Path

    from fetchbench_ms.demos.cli import add_run_arguments

    p = argparse.ArgumentParser()
    add_run_arguments(p)
    assert set(next(a for a in p._actions if a.dest == "expert").choices) == set(EXPERTS)
    root = Path(__file__).resolve().parents[1]
    for script in ("scripts/imitation/build_imitation_data.py", "scripts/imitation/imitation_round.py"):
        choices = re.search(r'"--expert", default="fast", choices=\(([^)]*)\)', (root / script).read_text()).group(1)
        assert set(re.findall(r'"(\w+)"', choices)) == set(EXPERTS), script


def test_fast3_makes_fast2s_trajectory(monkeypatch):
    """train/1513's first try plans its retrieval with RRTConnect (about 11,000 checks, most
    segments rejected): fast3 executes the same grasp along the same steps, with the same
    counted checks. (Each run gets a fresh world cache: a warm one may hand the second run the
    first run's sets of objects that barely moved.)"""
    from fetchbench_ms.planning import world_models
    from fetchbench_ms.solutions import sense_plan_act

    built = []
    make = sense_plan_act._checker
    monkeypatch.setattr(sense_plan_act, "_checker", lambda *a, **k: built.append(make(*a, **k)) or built[-1])
    demos = {}
    for name in ("fast2", "fast3"):
        monkeypatch.setattr(world_models, "MESH_WORLD_CACHE", world_models.MeshWorldCache())
        built.clear()
        demos[name] = _first_try(name, 1513)
        assert {c.motion_check_first for c in built} == {16 if name == "fast3" else 0}
    fast2, fast3 = demos["fast2"], demos["fast3"]
    assert fast2.success and any("plan solved" in note for note in fast2.notes)
    assert (fast3.success, fast3.grasp_id, fast3.checks, fast3.notes[-1].split("checks")[0]) == (
        fast2.success, fast2.grasp_id, fast2.checks, fast2.notes[-1].split("checks")[0])
    assert np.array_equal(fast3.stages, fast2.stages) and fast3.cspace_length == fast2.cspace_length


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


def test_tasks_without_a_trajectory_count_under_the_furthest_stage_they_failed_at():
    from pathlib import Path

    from script_modules import import_script

    bench = import_script(Path(__file__).resolve().parents[1] / "scripts/bench/bench_demos.py")
    summaries = [
        {"successes": 0, "reasons": {"no_approach": 1, "retrieval_plan:budget": 2}},
        {"successes": 0, "reasons": {"no_free_grasp": 1, "no_pregrasp_ik": 1}},
        {"successes": 0, "reasons": {"not_retrieved": 1, "retrieval_plan:budget": 1}},
        {"successes": 1, "reasons": {"no_approach": 1}},  # has a trajectory: not counted
        {"successes": 0, "reasons": {"no_pregrasp_ik": 1}},
    ]
    assert bench.tasks_without_demo_by_reason(summaries) == {
        "no_pregrasp_ik": 2, "not_retrieved": 1, "retrieval_plan:budget": 1}
