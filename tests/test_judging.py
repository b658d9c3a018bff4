"""The success judge and the one judgement of an episode's end (``envs/judging.py``) that every
runner calls."""
import ast
from pathlib import Path

import torch

from fetchbench_ms.envs import judging

PACKAGE = Path(__file__).resolve().parents[1] / "fetchbench_ms"


def test_success_flags_follow_the_criteria_strict_and_inclusive():
    com = torch.tensor([[0.0, 0.0, 0.30], [-0.01, 0.0, 0.31], [0.15, 0.0, 0.28]])
    moved = torch.tensor([0.0, 0.0999, 0.0])
    paper = judging.success_flags("paper", com, moved)
    assert paper["success"].tolist() == [False, True, False]
    assert paper["is_above_height"].tolist() == [False, True, False]
    release = judging.success_flags("release", com, moved)
    assert release["success"].tolist() == [True, True, True]
    assert not judging.success_flags("paper", com[1:2], torch.tensor([0.10]))["others_undisturbed"][0]


class _Agent:
    def __init__(self, held):
        self.held = held

    def is_grasping(self, target):
        return torch.tensor([self.held])


class _Env:
    def __init__(self, held):
        self.agent, self.target = _Agent(held), object()

    @property
    def unwrapped(self):
        return self


def _judge(monkeypatch, failure, success, held, undisturbed=True):
    info = {"success": torch.tensor([success]), "others_undisturbed": torch.tensor([undisturbed]),
            "target_moved": torch.tensor([0.123456]), "max_others_moved": torch.tensor([0.0123456])}
    monkeypatch.setattr(judging, "settle_and_hold", lambda env, seconds: info)
    return judging.judge(_Env(held), failure)


def test_judge_gives_the_failure_class_and_the_record_fields(monkeypatch):
    verdict = _judge(monkeypatch, None, success=True, held=True)
    assert verdict.record_fields() == {"success": True, "failure": None, "target_moved": 0.1235,
                                       "max_others_moved": 0.0123}
    assert _judge(monkeypatch, "motion_planning_failure", success=True, held=False).failure is None
    assert _judge(monkeypatch, None, success=False, held=True).failure == "retrieval_failure"
    assert _judge(monkeypatch, "grasp_failure", success=False, held=False).failure == "grasp_failure"
    assert _judge(monkeypatch, None, success=False, held=True, undisturbed=False).failure == "collision"
    assert _judge(monkeypatch, "not_attempted", success=False, held=False).failure == "not_attempted"
    assert _judge(monkeypatch, "timeout", success=False, held=True).held_at_end


def test_every_runner_judges_through_the_one_judge():
    """The sense-plan-act pipelines, the policies and ``idle`` end their episodes with
    ``judging.judge``; none calls ``settle_and_hold`` itself."""
    for path in ("solutions/sense_plan_act.py", "policies/deploy.py", "evaluation/methods.py"):
        calls = {node.func.id for node in ast.walk(ast.parse((PACKAGE / path).read_text()))
                 if isinstance(node, ast.Call) and isinstance(node.func, ast.Name)}
        assert "judge" in calls and "settle_and_hold" not in calls, path
