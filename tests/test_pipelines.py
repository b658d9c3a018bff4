"""Valid numbers: the paper's pipeline beside ours, count budgets (the same outcome on a busy
or an idle machine), the failure taxonomy and the funnel of methods without plan stages."""
import json
import multiprocessing as mp
import os
import re

import pytest

TIMING_FIELDS = {"computation_time", "wall_time"}


def _burn(stop):
    """A busy core (the artificial load)."""
    x = 0
    while not stop.is_set():
        for _ in range(100_000):
            x += 1


def test_pipelines_and_improvements_are_named_and_checked():
    from fetchbench_ms.method_spec import IMPROVEMENTS, pipeline_improvements
    from fetchbench_ms.solutions.sense_plan_act import (SolveConfig,
                                                        pipeline_label)

    assert pipeline_improvements("paper") == ()
    assert pipeline_improvements("ours") == IMPROVEMENTS
    assert pipeline_improvements("ours", ["retreat"]) == ("extra_lifts", "start_escape", "cgn_filter")
    assert pipeline_label(()) == "paper" and pipeline_label(IMPROVEMENTS) == "ours"
    assert pipeline_label(("extra_lifts", "cgn_filter")) == "ours-minus-retreat+start_escape"
    with pytest.raises(ValueError, match="valid: paper, ours"):
        pipeline_improvements("mine")
    with pytest.raises(ValueError, match="valid: retreat, extra_lifts, start_escape, cgn_filter"):
        pipeline_improvements("ours", ["retreats"])
    with pytest.raises(ValueError, match="'paper' has none"):
        pipeline_improvements("paper", ["retreat"])
    # The paper's pipeline plans from an invalid start as it is (no escape); ours escapes.
    assert SolveConfig().start_escape_depth == 0.0
    assert SolveConfig(improvements=("start_escape",)).start_escape_depth == 0.05
    with pytest.raises(ValueError, match="unknown improvement"):
        SolveConfig(improvements=("lift",))


def test_eval_cli_refuses_bad_pipeline_options(capsys, tmp_path):
    from fetchbench_ms.cli import main

    assert main(["eval", "--method", "ga-mesh-rrt", "--suite", "smoke", "--tasks", "0:1", "--pipeline", "ours",
                 "--without", "lifts", "--out", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "unknown improvement 'lifts'" in err and len(err.strip().splitlines()) == 1
    assert main(["eval", "--method", "idle", "--suite", "smoke", "--tasks", "0:1", "--pipeline", "ours",
                 "--out", str(tmp_path / "b")]) == 2
    assert "runs no sense-plan-act pipeline" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_planner_options_reach_the_mppi_config(monkeypatch):
    """``--planner-option`` values become SolveConfig fields, and those the MppiConfig that
    MPPI plans with (unset: MppiConfig's defaults and the method's own cost)."""
    from types import SimpleNamespace

    import numpy as np

    from fetchbench_ms.planning import mppi
    from fetchbench_ms.solutions.planner_options import parse_planner_options
    from fetchbench_ms.method_spec import method_spec
    from fetchbench_ms.solutions.planner_options import check_planner_options
    from fetchbench_ms.solutions.sense_plan_act import EpisodeState, SolveConfig, _plan_and_move

    configs = []

    def plan_mppi(checker, q_start, q_goals, execute, config):
        configs.append(config)
        return SimpleNamespace(planning_time=0.0)

    monkeypatch.setattr(mppi, "plan_mppi", plan_mppi)
    for options in ([], ["mppi_goal_region=0", "mppi_cost=distance"], ["mppi_goal_region=0.25"]):
        spec = method_spec("cgn-ptd-mppi")
        config = SolveConfig(**check_planner_options(spec, parse_planner_options(options)))
        _plan_and_move(EpisodeState(config), None, np.random.default_rng(0), None, None, None, spec)
    assert [(c.goal_region, c.cost) for c in configs] == [(mppi.MppiConfig.goal_region, "network"),
                                                          (0, "distance"), (0.25, "network")]


def test_failure_taxonomy_tells_a_held_target_from_a_dropped_one():
    from fetchbench_ms.solutions.sense_plan_act import final_failure

    assert final_failure(None, held_at_end=True, others_undisturbed=True) == "retrieval_failure"
    assert final_failure(None, held_at_end=False, others_undisturbed=True) == "grasp_failure"
    assert final_failure("grasp_failure", held_at_end=True, others_undisturbed=True) == "retrieval_failure"
    assert final_failure(None, held_at_end=True, others_undisturbed=False) == "collision"
    assert final_failure("motion_planning_failure", held_at_end=True, others_undisturbed=False) == \
        "motion_planning_failure"
    assert final_failure("timeout", held_at_end=False, others_undisturbed=True) == "timeout"


def test_funnel_has_no_plan_stage_for_a_method_that_plans_nothing():
    from fetchbench_ms.evaluation.metrics import summarize

    policy = [{"success": s, "failure": None if s else "timeout", "phases": {"approach_reached": True,
               "grasped": s, "retrieved": s, "held_at_end": s}} for s in (True, False)]
    stats = summarize(policy)["all"]
    assert stats["funnel"]["pregrasp_plan"] is None and stats["funnel"]["retrieval_plan"] is None
    assert stats["funnel"]["retrieved"] == 0.5 and stats["funnel"]["success"] == 0.5
    assert stats["timeouts"] == 1
    planner = [{"success": False, "failure": "motion_planning_failure", "phases": {"pregrasp_plan": False}}]
    assert summarize(planner)["all"]["funnel"]["pregrasp_plan"] == 0.0


def _records(out) -> dict:
    records = {}
    for line in (out / "results.jsonl").read_text().splitlines():
        r = json.loads(line)
        notes = [re.sub(r" \d+\.\d+s\b", "", n) for n in r.pop("notes", [])]  # a plan's seconds
        records[r["task_id"]] = {**{k: v for k, v in r.items() if k not in TIMING_FIELDS}, "notes": notes}
    return records


def test_outcome_is_the_same_under_artificial_load(tmp_path):
    """The same smoke task (a searched retrieval plan with a start escape) idle and with three
    busy processes beside it: every field but the times is identical, plan by plan."""
    from fetchbench_ms.evaluation import evaluate

    common = dict(suite="smoke", tasks="2:3", workers=1, progress=False,
                  improvements=("retreat", "extra_lifts", "start_escape", "cgn_filter"))
    evaluate("ga-mesh-rrt", tmp_path / "idle", **common)
    stop = mp.Event()
    burners = [mp.Process(target=_burn, args=(stop,), daemon=True) for _ in range(max(3, os.cpu_count() or 1))]
    for p in burners:
        p.start()
    try:
        evaluate("ga-mesh-rrt", tmp_path / "loaded", **common)
    finally:
        stop.set()
        for p in burners:
            p.join(10)
    idle, loaded = _records(tmp_path / "idle"), _records(tmp_path / "loaded")
    for task_id in idle:
        differ = {k: (idle[task_id][k], loaded[task_id].get(k)) for k in idle[task_id]
                  if idle[task_id][k] != loaded[task_id].get(k)}
        assert not differ, (differ, idle[task_id]['notes'], loaded[task_id]['notes'])
    (record,) = idle.values()
    assert record["pipeline"] == "ours" and record["planning_checks"] > 1000, record["notes"]


def test_a_plan_stopped_by_the_safety_net_is_a_timeout():
    from fetchbench_ms.envs import make
    from fetchbench_ms.evaluation.runner import open_suite
    from fetchbench_ms.solutions.sense_plan_act import SolveConfig, solve

    suite, _, _ = open_suite("smoke")
    task_id = list(suite.tasks)[0]  # its pre-grasp plan needs a search (not the straight segment)
    env = make("FetchBench-v0", obs_mode="none", control_mode="pd_joint_pos")
    env.reset(seed=0, options={"task": suite.tasks[task_id].to_dict()})
    record = solve(env, seed=0, method="ga-mesh-rrt", reset=False, config=SolveConfig(plan_safety_seconds=0.0))
    env.close()
    assert record["failure"] == "timeout" and not record["success"], record["notes"]
    assert record["pipeline"] == "paper" and record["improvements"] == []


def test_cgn_with_an_unseen_target_has_no_grasp_candidate():
    """Cameras that miss the target (e.g. the original's placement) leave CGN nothing to
    predict on: a failed fetch of class no_grasp_candidate, not an error."""
    import numpy as np

    from fetchbench_ms.envs.pointcloud import FetchClouds
    from fetchbench_ms.method_spec import method_spec
    from fetchbench_ms.solutions.sense_plan_act import EpisodeState, SolveConfig, _grasp_candidates

    state = EpisodeState(SolveConfig())
    clouds = FetchClouds(scene=np.zeros((10, 3)), target=np.zeros((0, 3)), robot=np.zeros((0, 3)),
                         scene_labels=np.zeros(10, int), target_segmentation_id=0)
    assert _grasp_candidates(None, method_spec("cgn-ptd-rrt"), state, np.random.default_rng(0), set(), np.eye(4), clouds) is None
    assert state.notes == ["target not seen by the cameras"]
