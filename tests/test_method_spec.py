"""Methods as data (``fetchbench_ms.method_spec``): the registry built from the planners' and
the policy kinds' tables, the run spec that ``run.json`` records, and a toy planner and a toy
policy kind (tests/toy_methods.py) registered here, run through ``fetchbench eval`` on a smoke
task in worker processes that receive the spec, and removed."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fetchbench_ms.method_spec import (PLANNERS, POLICY_KINDS, PlannerSpec, PolicyKind, RunSpec, method_spec,
                                       register_planner, register_policy_kind, registry, unregister_planner,
                                       unregister_policy_kind)

ROOT = Path(__file__).resolve().parents[1]
TOY_PLANNER = PlannerSpec("line", "toy_methods:plan", compositions=("ga-mesh", "ga-ptd"))
TOY_KIND = PolicyKind("toy", "toy_methods:ToyPolicy", "toy_methods:ToyConfig", "tests/toy_methods.py")


def test_the_registry_is_built_from_the_tables():
    methods = registry()
    assert len(methods) == sum(len(p.compositions) for p in PLANNERS.values()) + 3 * len(POLICY_KINDS) + 1
    spec = method_spec("cgn-ptd-mppi")
    assert (spec.family, spec.grasps, spec.world, spec.planner.name, spec.collision) == (
        "sense_plan_act", "cgn", "pointcloud", "mppi", "network")
    assert spec.robots == ("panda",) and spec.paper.name == "CGN-Cabinet" and spec.paper.success == 0.121
    assert spec.planner.options == ("mppi_goal_region", "mppi_cost") and not spec.planner.budgeted
    assert method_spec("ga-mesh-mppi").collision == "distance" and method_spec("ga-mesh-mppi").robots is None
    assert method_spec("ga-mesh-rrt").obs_mode == "none" and method_spec("cgn-mesh-rrt").obs_mode == "pointcloud"
    hybrid = method_spec("cgn-imit-act")
    assert (hybrid.family, hybrid.planner.name, hybrid.policy.name, hybrid.approach_method) == (
        "hybrid", "trajopt", "act", "cgn-ptd-trajopt")
    assert method_spec("e2e-mlp").regrasp and not method_spec("twostage-mlp").regrasp
    assert method_spec("e2e-mlp").obs_mode is None  # its checkpoint's
    assert method_spec("idle").family == "idle" and not method_spec("idle").has_pipeline
    with pytest.raises(ValueError, match="unknown method 'ga-mesh-rrtx'; valid: ga-mesh-rrt, "):
        method_spec("ga-mesh-rrtx")


def test_run_specs_record_the_shipped_runs_options():
    """A run spec made from a shipped run's options records them as ``run.json`` has them
    (what resuming compares): old records read, new ones are written the same way."""
    checked = 0
    for path in sorted((ROOT / "results" / "runs").glob("*/run.json")):
        manifest = json.loads(path.read_text())
        o = manifest["method_options"]
        if "pipeline" not in o:  # legacy runs: made before the pipeline was recorded
            continue
        run = RunSpec(method_spec(manifest["method"]), retries=o["retries"],
                      grasp_model=o.get("grasp_model", "pretrained"), policy_checkpoint=o.get("policy_checkpoint"),
                      policy_stride=o.get("policy_stride", 1), improvements=tuple(o.get("improvements", ())),
                      planner_options=tuple(sorted(o.get("planner_options", {}).items())),
                      env_options=tuple(sorted(o.get("env_options", {}).items())), robot=o.get("robot", "panda"))
        assert run.method_options() == o, path
        checked += 1
    assert checked > 50


@pytest.fixture
def toys():
    register_planner(TOY_PLANNER)
    register_policy_kind(TOY_KIND)
    try:
        yield
    finally:
        unregister_planner(TOY_PLANNER.name)
        unregister_policy_kind(TOY_KIND.name)
    with pytest.raises(ValueError, match="unknown method"):
        method_spec("ga-mesh-line")
    with pytest.raises(ValueError, match="unknown method"):
        method_spec("twostage-toy")


def test_toy_planner_and_policy_kind_run_through_fetchbench_eval(toys, tmp_path, capsys):
    """One table row each makes their methods; ``fetchbench eval`` resolves them once and its
    worker process (which never registered them) runs them from the spec it receives."""
    import torch

    from fetchbench_ms.cli import main
    from fetchbench_ms.evaluation import ResultsStore
    from fetchbench_ms.policies.agent import save_checkpoint
    from toy_methods import LINE, ToyConfig, ToyPolicy

    assert {"ga-mesh-line", "ga-ptd-line", "e2e-toy", "twostage-toy", "cgn-imit-toy"} <= set(registry())
    with pytest.raises(ValueError, match="a planner named 'line' is registered already"):
        register_planner(TOY_PLANNER)
    common = ["--suite", "smoke", "--tasks", "0:1"]

    out = tmp_path / "line"
    assert main(["eval", "--method", "ga-mesh-line", *common, "--out", str(out)]) == 0
    store = ResultsStore(out)
    assert store.manifest()["method_spec"] == {"family": "sense_plan_act", "grasps": "annotated", "world": "mesh",
                                               "planner": "line", "collision": "spheres", "retrieval": "planner"}
    [record] = store.records()
    assert record["method"] == "ga-mesh-line" and "error" not in record and record["pipeline"] == "paper"
    # the toy planner planned (its status in the notes): the worker had it from the spec
    assert any(f"pre-grasp plan {LINE}" in note for note in record["notes"]), record["notes"]

    checkpoint = tmp_path / "imit_toy.pt"
    torch.manual_seed(0)
    save_checkpoint(checkpoint, ToyPolicy(ToyConfig()), {})
    out = tmp_path / "toy"
    assert main(["eval", "--method", "twostage-toy", "--policy-checkpoint", str(checkpoint), *common,
                 "--out", str(out)]) == 0
    store = ResultsStore(out)
    assert store.manifest()["method_spec"] == {"family": "policy", "retrieval": "policy", "policy": "toy"}
    [record] = store.records()
    assert record["method"] == "twostage-toy" and "error" not in record, record.get("error")
    assert record["policy_obs_mode"] == "compact_pointcloud" and record["regrasps"] == 0
    assert [to for _, _, to in record["phase_log"]] == ["close", "retrieve", "done"]
    capsys.readouterr()
    # A missing checkpoint names the kind's trainer (its row), before any task runs.
    assert main(["eval", "--method", "e2e-toy", *common, "--out", str(tmp_path / "none")]) == 2
    assert "tests/toy_methods.py" in capsys.readouterr().err
