"""A toy planner and a toy policy kind, for the tests that register them (test_method_spec.py).

``plan`` is a planner as ``method_spec.PlannerSpec.entry`` names one: ``plan(PlanRequest) ->
PlanResult``; it takes the straight joint-space segment to the first goal it finds free.
``ToyPolicy`` is a network as ``method_spec.PolicyKind.network`` names one: it holds the arm
still and asks to end every stage at once. The worker processes import this module (the
method's spec names it), as they import ``evaluation_faults``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn as nn

from fetchbench_ms.planning.rrt import PlanRequest, PlanResult
from fetchbench_ms.policies.networks import EncoderConfig

#: What the toy planner calls its plans (``PlanResult.planner``; their status: ``line`` when
#: found, ``line-blocked`` when every segment collides).
LINE = "line"


def plan(request: PlanRequest) -> PlanResult:
    t, checked = time.perf_counter(), request.checker.n_checked
    q_start = np.asarray(request.q_start, float).reshape(7)
    goals = np.asarray(request.q_goals, float).reshape(-1, 7)
    for i, goal in enumerate(goals):
        if request.checker.motion_valid(q_start, goal):
            return PlanResult(LINE, np.stack([q_start, goal]), time.perf_counter() - t,
                              request.checker.n_checked - checked, goal_index=i, planner=LINE)
    return PlanResult(f"{LINE}-blocked", None, time.perf_counter() - t, request.checker.n_checked - checked,
                      planner=LINE)


@dataclass
class ToyConfig:
    encoder: EncoderConfig = field(default_factory=EncoderConfig)


class ToyPolicy(nn.Module):
    kind = "toy"
    history = 1

    def __init__(self, cfg: ToyConfig):
        super().__init__()
        self.cfg = cfg
        self.arm = nn.Parameter(torch.zeros(7))

    @torch.no_grad()
    def act(self, obs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(actions [B, 1, 7]: hold, termination probability [B]: 1)."""
        batch = obs["qpos"].shape[0]
        return torch.tanh(self.arm).expand(batch, 1, 7), torch.ones(batch)
