"""FetchBench's success judge: the success region, the 10 s settle-and-hold, and the one
judgement of an episode's end that every runner (the sense-plan-act pipelines, the policies,
``idle``) calls.

- ``success_flags``: the success conditions on the target's centre of mass in the robot-base
  frame and the other objects' largest displacement (``SUCCESS_CRITERIA``); the env's
  ``evaluate()`` reads them at every step.
- ``settle_and_hold``: the gripper squeezing and the arm held for 10 s of simulated time,
  then ``evaluate()``.
- ``judge``: ``settle_and_hold``, then the episode's verdict (``Judgement``): success, whether
  the target is still held, the failure class (``final_failure``) and the displacements a
  record reports.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch

#: Success thresholds on the target's centre of mass in the robot-base frame, and on the
#: largest displacement of any other object. "paper": strict inequalities as in the paper;
#: "release": the original code release's (inclusive) values.
SUCCESS_CRITERIA = {
    "paper": dict(min_height=0.30, max_x=0.0, max_others_moved=0.10, inclusive=False),
    "release": dict(min_height=0.28, max_x=0.15, max_others_moved=0.10, inclusive=True),
}
HOLD_SECONDS = 10.0  # FetchBench's settle-and-hold before judging


def success_flags(criteria: str, target_com_base: torch.Tensor, max_others_moved: torch.Tensor) -> dict:
    """The success conditions of ``SUCCESS_CRITERIA[criteria]``, each [B] bool:
    ``is_above_height`` (the target's centre of mass above the success height),
    ``is_retrieved`` (out in front of the robot), ``others_undisturbed`` and ``success``
    (all three)."""
    c = SUCCESS_CRITERIA[criteria]
    if c["inclusive"]:
        lifted, retrieved = target_com_base[:, 2] >= c["min_height"], target_com_base[:, 0] <= c["max_x"]
    else:
        lifted, retrieved = target_com_base[:, 2] > c["min_height"], target_com_base[:, 0] < c["max_x"]
    undisturbed = max_others_moved < c["max_others_moved"]
    return dict(success=lifted & retrieved & undisturbed, is_above_height=lifted, is_retrieved=retrieved,
                others_undisturbed=undisturbed)


def settle_and_hold(env, seconds: float = HOLD_SECONDS) -> dict:
    """FetchBench's judging step: keep the gripper closed (squeezing) and the arm at its
    current joint positions for ``seconds`` of simulated time, then evaluate.

    Works for every control mode: it drives the joints directly (not through the
    controller) and steps the physics, so it does not count as env steps. Returns the
    ``evaluate()`` dict after the hold.
    """
    base = env.unwrapped
    robot = base.agent.robot
    joints = robot.active_joints
    targets = robot.get_qpos().clone()
    squeeze = getattr(base.agent, "squeeze_targets", None)
    if squeeze is None:  # the Franka hand
        is_finger = torch.tensor(["finger" in j.name for j in joints], device=base.device)
        targets[:, is_finger] = -0.01  # below fully closed (0): the fingers keep squeezing
    else:
        for k, joint in enumerate(joints):
            if joint.name in squeeze:
                targets[:, k] = squeeze[joint.name]
    robot.set_joint_drive_targets(targets, joints=joints, joint_indices=torch.arange(len(joints), device=base.device))
    # ManiSkill's GPU scene keeps its state in buffers: pushed before the raw physics steps
    # (the env's own steps go through ``_step_action``, which would count as env steps) and
    # fetched after them.
    if base.gpu_sim_enabled:
        base.scene._gpu_apply_all()
    for _ in range(int(round(seconds * base.sim_freq))):
        base.scene.step()
    if base.gpu_sim_enabled:
        base.scene.px.gpu_update_articulation_kinematics()
        base.scene._gpu_fetch_all()
    return base.evaluate()


def final_failure(failure: Optional[str], held_at_end: bool, others_undisturbed: bool) -> str:
    """The failure class of a failed episode, from the run's own verdict (None: every step
    went through) and the judge's: another object pushed away is a ``collision``; a target
    still held but not carried out a ``retrieval_failure``; one not held a ``grasp_failure``.
    Planning failures, timeouts and any other class keep their class."""
    if failure in (None, "grasp_failure"):
        if not others_undisturbed:
            return "collision"
        return "retrieval_failure" if held_at_end else "grasp_failure"
    return failure


@dataclass(frozen=True)
class Judgement:
    """The end of one episode (sub-scene 0), as FetchBench judges it."""

    success: bool
    failure: Optional[str]  # None on success; else ``final_failure``'s class
    held_at_end: bool  # the target between the fingers after the hold
    target_moved: float  # m, the target's centre of mass from its start (rounded to 0.1 mm)
    max_others_moved: float  # m, the other objects' largest displacement (rounded)
    info: dict  # ``evaluate()`` after the hold

    def record_fields(self) -> dict:
        """What every episode record says of the judgement."""
        return {"success": self.success, "failure": self.failure, "target_moved": self.target_moved,
                "max_others_moved": self.max_others_moved}


def judge(env, failure: Optional[str] = None, seconds: float = HOLD_SECONDS) -> Judgement:
    """FetchBench's judgement of the episode's end: ``settle_and_hold``, then success, whether
    the target is still held, and the failure class of a failed episode from the runner's own
    verdict ``failure`` (``final_failure``: None, every step went through; another class is
    kept)."""
    u = env.unwrapped
    info = settle_and_hold(env, seconds)
    success = bool(info["success"][0])
    held = bool(u.agent.is_grasping(u.target)[0])
    if not success:
        failure = final_failure(failure, held_at_end=held, others_undisturbed=bool(info["others_undisturbed"][0]))
    return Judgement(success, None if success else failure, held, round(float(info["target_moved"][0]), 4),
                     round(float(info["max_others_moved"][0]), 4), info)
