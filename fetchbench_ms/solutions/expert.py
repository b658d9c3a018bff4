"""The Fetch dataset's expert, in the style of ManiSkill's motion-planning solutions.

``solve(env, seed=None, debug=False, vis=False)`` resets the env, fetches the target with
the oracle sense-plan-act pipeline (annotated grasps, the exact mesh world, the project's
best planner) and returns what ManiSkill's solutions return: the last ``env.step`` result
``(obs, reward, terminated, truncated, info)``, or ``-1`` when it found no way. Every
control step goes through ``env.step`` with a ``pd_joint_pos`` action, so ManiSkill's
``RecordEpisode`` wrapper records the whole trajectory (env states and actions).

``solve_demo`` is the same with what the demonstration generator needs besides: which
annotated grasp was executed (so the next trajectory of the task takes another one), each
step's stage (``STAGES``: approach, close, retrieve) and why it failed.

What differs from the evaluation baselines (``sense_plan_act.solve``):
- grasps are tried best first: the open hand's clearance at pre-grasp and grasp, largest
  first (``SolveConfig.grasp_order="clearance"``), skipping grasps given in ``tried``;
- the trajectory ends once the target is out and the env's success has held for
  ``confirm_steps`` control steps (ManiSkill's demos end at success), not after FetchBench's
  10 s settle-and-hold: those idle frames teach a policy nothing;
- every improvement of our pipeline (``sense_plan_act.IMPROVEMENTS``: retreat, extra
  lifts, start escape): the expert is ours, not a row of the paper;
- one try: a failed try has moved the scene, and a demonstration with a failed grasp in it
  is not what imitation should copy. The generator resets and tries the next grasp.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from ..method_spec import MethodSpec, method_spec, registry
from .sense_plan_act import IMPROVEMENTS, STAGES, EpisodeState, SolveConfig, _attempt

#: The expert's planner set-up: the oracle mesh world and the best planner the project has
#: (RRTConnect with path shortcutting); any sense-plan-act method with the mesh world and the
#: annotated grasps drops in (``ga-mesh-trajopt``: the trajectory optimiser).
EXPERT_METHOD = "ga-mesh-rrt"
CONFIRM_STEPS = 5  # control steps (0.25 s at 20 Hz) the env's success must hold at the end
MAX_CONFIRM_STEPS = 40  # steps to wait for success after the retrieval path (the object swings)


#: The expert moves faster than the evaluation baselines (0.4 / 0.1 of the velocity limits,
#: 1.5 s to close): its trajectories are what a policy imitates step by step, and long idle
#: stretches teach nothing (about 200 control steps a trajectory instead of 300; the paper's
#: average is 131). 0.7 keeps every joint's step under 0.1 rad at 20 Hz, the clip of
#: ManiSkill's pd_joint_delta_pos controller, so conversion to it loses nothing.
EXPERT_SPEEDS = dict(speed_scale=0.7, approach_speed_scale=0.2, close_seconds=1.0)


def expert_config(**overrides) -> SolveConfig:
    return dataclasses.replace(SolveConfig(grasp_order="clearance", improvements=IMPROVEMENTS, **EXPERT_SPEEDS),
                               **overrides)


@dataclass(frozen=True)
class ExpertSpec:
    """A named configuration of the expert: what its trajectories depend on besides the task,
    the seed and the method. The demo generator records it in every file's JSON
    (``fetchbench.expert``), and a parts folder made with another is refused."""

    name: str
    confirm_steps: int = CONFIRM_STEPS
    solve: tuple = ()  # (SolveConfig field, value) pairs on top of expert_config()'s
    # The generator gives up a task after this many failed tries in a row (0: only the
    # generator's --max-tries): a task whose grasps keep failing to plan their retrieval
    # rarely yields later, and each such try costs a whole planning budget.
    max_failures_in_a_row: int = 0

    def config(self) -> SolveConfig:
        return expert_config(**dict(self.solve))

    def to_json(self) -> dict:
        return {"name": self.name, "confirm_steps": self.confirm_steps, "solve": dict(self.solve),
                "max_failures_in_a_row": self.max_failures_in_a_row}


#: The expert's configurations (``fetchbench demos run --expert NAME``):
#: - ``reference``: every world and every carried object's balls built anew at each try, one
#:   goal set for the pre-grasp plan (the configuration the published dataset was made with);
#: - ``fast`` (the default): reuses what a task's tries share and changes little between them
#:   (an untouched object's convex set while it moved < 0.5 mm; the target's balls fitted once
#:   in its own frame), and when no pre-grasp plan reaches the best 8 candidates, plans to the
#:   next 8 (up to 24) within the episode's collision-check budget; 3 settle steps after a
#:   motion instead of 6; a task is given up after 3 failed tries in a row;
#: - ``fast2``: ``fast``, and the straight approach (the target left out) and the open hand at
#:   the grasp may overlap the world by 2 mm (``SolveConfig.approach_tolerance``: the finger
#:   spheres' own margin), so a grasp whose fingers clear the support by a hair is tried;
#: - ``fast3``: ``fast2``, and the planners check a straight segment's first 16 configurations
#:   before the rest (``SolveConfig.motion_check_first``): a rejected segment mostly collides
#:   within a few steps of its start, and the rest is then not computed. The answers and the
#:   counted checks are the same, so are the plans and trajectories (train/1500-1579: the same
#:   178 as ``fast2``'s, byte for byte; a clearance computed in another batch size may differ in
#:   its last bit, so this is not promised everywhere); 15 % less CPU there (docs/demos.md).
_FAST = (("pregrasp_goal_sets", 3), ("world_pose_tolerance", 5e-4), ("attachment_per_object", True),
         ("settle_steps", 3), ("reuse_candidates", True))
EXPERTS = {
    "reference": ExpertSpec("reference"),
    "fast": ExpertSpec("fast", solve=_FAST, max_failures_in_a_row=3),
    "fast2": ExpertSpec("fast2", solve=_FAST + (("approach_tolerance", 0.002),), max_failures_in_a_row=3),
    "fast3": ExpertSpec("fast3", solve=_FAST + (("approach_tolerance", 0.002), ("motion_check_first", 16)),
                        max_failures_in_a_row=3),
}
DEFAULT_EXPERT = "fast"


def expert_spec(name: str) -> ExpertSpec:
    if name not in EXPERTS:
        raise ValueError(f"unknown expert {name!r}; valid: {', '.join(EXPERTS)}")
    return EXPERTS[name]


@dataclass
class Demo:
    """One expert try on a task (what the demonstration generator keeps or drops)."""

    success: bool
    failure: str | None  # sense_plan_act.FAILURE_CLASSES, or "not_retrieved" (success never held)
    reason: str | None  # finer: sense_plan_act.FAILURE_REASONS (a planner's ":status" added), or "not_retrieved"
    last_step: tuple | None  # the last env.step result
    grasp_id: int | None  # the executed grasp's index in the object's annotated-grasp list
    stages: np.ndarray  # (steps,) int8 index into STAGES, one per env.step
    cspace_length: float  # rad, all 9 joints
    computation_time: float  # s of planning, IK and world building
    notes: list = dataclasses.field(default_factory=list)  # what the try did (sense_plan_act's notes)
    checks: int = 0  # collision checks its plans spent

    @property
    def steps(self) -> int:
        return len(self.stages)


def stage_end_flags(stages: np.ndarray) -> np.ndarray:
    """The original's end-of-stage flag: True at the last step of each stage."""
    stages = np.asarray(stages)
    end = np.zeros(len(stages), dtype=bool)
    if len(stages):
        end[:-1] = stages[1:] != stages[:-1]
        end[-1] = True
    return end


def solve_demo(env, seed: int | None = None, *, reset: bool = True, reset_options: dict | None = None,
               tried: set | None = None, method: MethodSpec | str = EXPERT_METHOD, config: SolveConfig | None = None,
               confirm_steps: int = CONFIRM_STEPS) -> Demo:
    """One expert try; ``tried`` (grasp ids) is updated with the grasp it executed."""
    spec = method if isinstance(method, MethodSpec) else method_spec(method)
    oracle = [m.name for m in registry().values()
              if m.family == "sense_plan_act" and m.world == "mesh" and m.grasps == "annotated"]
    if spec.name not in oracle:
        raise ValueError(f"the expert plans with the annotated grasps in the oracle mesh world; {spec.name!r} "
                         f"does not. Valid: {', '.join(oracle)}")
    torch.set_num_threads(1)
    if reset:
        env.reset(seed=seed, options=reset_options)
    config = config or expert_config()
    state = EpisodeState(config, checks_left=config.plan_checks_total, via_env_step=True)
    rng = np.random.default_rng(seed if seed is not None else 0)
    failure = _attempt(env, spec, state, rng, tried if tried is not None else set())
    if failure is None:
        failure = _confirm(env, state, confirm_steps)
        state.reason = failure
    return Demo(
        success=failure is None,
        failure=failure,
        reason=None if failure is None else (state.reason or failure),
        last_step=state.last_step,
        grasp_id=state.grasp_id,
        stages=np.array([STAGES.index(s) for s in state.stage_log], dtype=np.int8),
        cspace_length=state.cspace_length,
        computation_time=state.computation_time,
        notes=state.notes,
        checks=config.plan_checks_total - state.checks_left,
    )


def _confirm(env, state: EpisodeState, confirm_steps: int) -> str | None:
    """Hold the last configuration until the env's success has held ``confirm_steps`` steps."""
    from .sense_plan_act import GRIPPER_CLOSED, Executor

    ex = Executor(env, state)
    q_hold, streak = state.last_arm_target, 0
    for _ in range(MAX_CONFIRM_STEPS):
        if state.last_step is not None and bool(state.last_step[3]):  # truncated: out of steps
            return "not_retrieved"
        ex.step(q_hold, GRIPPER_CLOSED)
        streak = streak + 1 if bool(state.last_step[-1]["success"]) else 0
        if streak >= confirm_steps:
            return None
    return "not_retrieved"


def solve(env, seed: int | None = None, debug: bool = False, vis: bool = False):
    """ManiSkill's motion-planning signature: the last ``env.step`` result, or -1 on failure.
    (``debug`` and ``vis`` are accepted for compatibility; the planner has no viewer.)"""
    demo = solve_demo(env, seed)
    return demo.last_step if demo.success else -1
