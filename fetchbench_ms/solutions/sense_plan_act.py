"""FetchBench's sense-plan-act baselines as a ManiSkill-style ``solve(env, seed)``.

Steps of one try (the original's, see docs): grasp candidates -> IK for the pre-grasp
(4 cm back along the approach) and the grasp -> RRTConnect to the pre-grasp (goal set
over the IK solutions, best candidates first) -> straight approach (4 cm x 1.05) ->
close the gripper -> lift 2 cm -> attach the object to the hand -> RRTConnect to the
free-space pose (-0.2, +-0.25, 0.66) in the base frame -> execute; the env's 10 s
settle-and-hold judges the episode.

Two pipelines (``SolveConfig.improvements``, ``fetchbench eval --pipeline paper|ours``): ``paper``
runs exactly the step list above, CGN's top 10 unfiltered; ``ours`` adds ``IMPROVEMENTS``
(``method_spec``)
(a straight retreat before the retrieval plan, extra lifts, escaping a start the spheres call
in collision, dropping colliding CGN candidates), each of which can be switched off alone
(``--without``). Every record names its variant (``pipeline``, ``improvements``).

Budgets are counts (``plan_checks_per_try``, ``plan_checks_total``: collision checks; trajopt's
iterations; MPPI's replans), every plan seeded from the episode's rng, so a task's outcome
does not depend on the machine's speed or load. Wall-clock limits are safety nets: a plan one
stops ends the episode as ``timeout``.

Variants (``method_spec.registry()``: one per grasp source, world model and planner, the
planners' table ``method_spec.PLANNERS``): ``ga-mesh-rrt`` plans in the oracle mesh world, ``ga-ptd-rrt``
in the segmented point clouds; both take the annotated grasps and, like the original
release, filter grasps by IK (collision-aware) in their own world. ``ga-mesh-trajopt`` and
``ga-ptd-trajopt`` plan the same motions with the batched torch trajectory optimiser
(``planning.trajopt``, the paper's cuRobo rows) instead of RRTConnect. ``cgn-ptd-rrt`` (the
paper's CGN-RRTConnect) and ``cgn-mesh-rrt`` (CGN-Mesh-RRTConnect) take the top
Contact-GraspNet predictions on the observed target instead (``SolveConfig.grasp_model``:
``pretrained`` or ``ours``, see ``fetchbench_ms.grasp_prediction``); ``cgn-ptd-trajopt`` (CGN-CuRobo)
and ``cgn-mesh-trajopt`` (CGN-Mesh-CuRobo) plan those with the trajectory optimiser. ``cgn-ptd-mppi`` (the paper's CGN-Cabinet),
``ga-ptd-mppi`` and ``ga-mesh-mppi`` move by receding-horizon MPPI (``planning.mppi``), which
executes while it plans; its collision cost is the learned scene-collision network on the
observed cloud (``planning.collision_net``), or for ``ga-mesh-mppi`` the meshes' distances.

Execution drives the env's ``pd_joint_pos`` controller open loop with the time-
parametrised plan. Rendering cameras at every control step would only slow an open-loop
executor down, so for evaluation steps go through ``BaseEnv._step_action`` (the simulation
part of ``env.step``); the observation is taken once per try, at its start. The
demonstration expert (``solutions.expert``) sets ``EpisodeState.via_env_step``: every step
then goes through ``env.step`` (wrappers such as ManiSkill's ``RecordEpisode`` see it) and
is labelled with its stage (``STAGES``).
"""
from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..envs.judging import final_failure, judge  # noqa: F401  (final_failure: public here too)
from ..method_spec import IMPROVEMENTS, MethodSpec, RunSpec, load, method_spec, pipeline_label
from ..planning.checker import Attachment, CollisionChecker
from ..planning.ik import solve_ik
from ..planning.robot import robot_for_env
from ..planning.rrt import PlanRequest
from ..planning.timing import time_parametrize
from ..grasp_prediction.candidates import predicted_grasps
from ..grasp_labels.candidates import choose_grasps, object_grasps, retreat, tcp_from_hand
from ..planning.world import pose_matrix
from ..planning.world_models import T_world_base, mesh_world, object_poses_base, pointcloud_world
from ..utils.io import sha256_bytes

#: Why a task failed. ``grasp_failure``: the gripper closed on nothing, or the target slipped out
#: before or while it was carried; ``retrieval_failure``: the target is held at the end but was
#: not carried out (the retrieval stopped short); ``timeout``: a wall-clock safety net stopped a
#: planner (the budgets are counts; a timeout is the machine's, reported, counted as a failure).
FAILURE_CLASSES = ("no_grasp_candidate", "motion_planning_failure", "grasp_failure", "retrieval_failure",
                   "collision", "timeout")
GRIPPER_OPEN, GRIPPER_CLOSED = 1.0, -1.0  # normalised pd_joint_pos gripper action (0.04 m / -0.01 m)
FREE_SPACE_POSITIONS = ((-0.2, 0.25, 0.66), (-0.2, -0.25, 0.66))
PHASES = ("ik_found", "pregrasp_plan", "approach_reached", "grasped", "retrieval_plan", "held_at_end")
#: Stages of a fetch, as the original's demonstrations label them: move to the pre-grasp and
#: approach, close the gripper, retrieve (lift, back out, carry to free space).
STAGES = ("approach", "close", "retrieve")
GRASP_ORDERS = ("random", "clearance")
#: Why a try failed, one step finer than its failure class (``EpisodeState.reason``):
#: ``no_untried_grasp`` every candidate was tried before; ``no_free_grasp`` the open hand
#: collides at every candidate's pre-grasp or grasp; ``no_pregrasp_ik`` no collision-free IK at
#: any free candidate's pre-grasp; ``no_approach`` no candidate with an IK has a free straight
#: approach; ``pregrasp_plan:STATUS`` / ``retrieval_plan:STATUS`` the planner failed
#: (``planning.rrt.STATUSES``); ``not_grasped`` the gripper closed on nothing (or the target
#: slipped on the lift); ``retrieval_no_ik`` no collision-free IK at the free-space pose with
#: the object; ``retrieval_no_budget`` the episode's collision checks were spent;
#: ``target_not_seen`` (point-cloud grasp sources) the cameras see no target.
#: In the pipeline's order (the expert adds ``not_retrieved`` after them).
FAILURE_REASONS = ("target_not_seen", "no_untried_grasp", "no_free_grasp", "no_pregrasp_ik", "no_approach",
                   "pregrasp_plan", "not_grasped", "retrieval_no_ik", "retrieval_no_budget", "retrieval_plan")


@dataclass
class SolveConfig:
    pregrasp_distance: float = 0.04  # m back along the approach axis
    approach_overshoot: float = 1.05  # the approach goes 4 cm x 1.05
    lift_height: float = 0.02  # m, straight up after closing
    # Which of IMPROVEMENTS are on (the parameters below apply only to those that are).
    improvements: tuple = ()
    # The annotated grasps' store (a directory; None: the shipped Franka-hand labels, which
    # other hands use as the paper did: same TCP pose, approach axis and width).
    grasp_labels: str | None = None
    retreat_distances: tuple = (0.10, 0.06, 0.03)  # "retreat"
    extra_lifts: tuple = (0.02, 0.04, 0.06)  # "extra_lifts"
    # "start_escape": at rest, or holding an object on its support, the conservative spheres
    # can overlap the furniture by a few cm while the simulated robot touches nothing.
    start_tolerance: float = 0.05  # m of sphere overlap
    close_seconds: float = 1.5
    max_grasps: int = 128  # candidates drawn (annotated grasps, or antipodal stand-ins)
    grasp_model: str = "pretrained"  # CGN methods: weight set (fetchbench_ms.grasp_prediction.GRASP_MODELS)
    cgn_grasps: int = 10  # CGN methods: the best predictions by score that go to IK (the original's top 10)
    ik_grasps: int = 24  # annotated grasps whose open hand is collision-free go to IK, at most
    ik_seeds: int = 12  # seeds per candidate (plus the current configuration)
    goal_set_size: int = 8  # IK solutions handed to the planner at once
    # Goal sets the pre-grasp plan may try, one after another: when no path to the first
    # goal_set_size candidates is found, the next ones (the expert; the baselines plan once).
    pregrasp_goal_sets: int = 1
    # The mesh world after a grasp reuses an object's convex set while its pose is within this of
    # the pose it was built at (planning.world_models.MeshWorldCache; 0: only the exact pose).
    world_pose_tolerance: float = 0.0
    # The carried object's balls: fitted once per object in its own frame and moved to the hand
    # (True, the expert), or fitted in the hand frame at every grasp (False: the baselines).
    attachment_per_object: bool = False
    # Pre-grasp IK solutions and approach paths kept from a task's earlier tries that started
    # from the same state (``CandidateMemo``; the expert, which resets before every try).
    reuse_candidates: bool = False
    # Planning budgets are counts of collision checks, so a plan is the same on a busy or an
    # idle machine, on any CPU (the original's 10 s a try and 30 s an episode at ~3,000 checks
    # a second). Each plan is seeded from the episode's rng (planning.rrt's ``seed``).
    plan_checks_per_try: int = 30000  # per planning call (RRTConnect's search, trajopt's RRT fallback)
    plan_checks_total: int = 90000  # all planning calls of one episode
    # Wall-clock safety net per planning call (s): a plan it stops is a ``timeout`` failure.
    plan_safety_seconds: float = 300.0
    speed_scale: float = 0.4  # fraction of the Panda's velocity limits when executing
    settle_steps: int = 6  # control steps holding a path's end before the next motion
    approach_speed_scale: float = 0.1  # the straight approach, the lift and the extra lifts
    margin: float = 0.0  # extra clearance on top of the spheres' own 4 mm
    # The planners' segment checks look at a segment's first this many configurations before
    # the rest (``CollisionChecker.motion_check_first``; the expert's ``fast3``): the same
    # answers and counted checks, less computation. 0: every segment as one batch.
    motion_check_first: int = 0
    # The straight approach from the pre-grasp to the grasp (the target left out), and the open
    # hand at the grasp in the candidates' filter, may overlap the world by this much (m): the
    # spheres' own margin (2 mm on the fingers, 3 on the hand, 4 elsewhere) makes a finger that
    # clears the board under the target by a hair count as a collision. 0: the spheres are the
    # robot (the baselines).
    approach_tolerance: float = 0.0
    retries: int = 1  # tries in all (FetchBench's "--retries 5" = 5)
    # "random": the seeded order of choose_grasps (the baselines: no verified grasp is better
    # than another); "clearance": the open hand's clearance at pre-grasp and grasp, largest
    # first (the expert's "best first": roomier grasps plan and execute more reliably).
    grasp_order: str = "random"
    retry_target_moved: float = 0.12  # a retry needs the target moved <= this
    retry_others_moved: float = 0.10  # and every other object moved < this
    # The hybrid methods (fetchbench_ms.policies.deploy): after the gripper closed, this
    # callable ``(env, state, executor) -> failure class or None`` retrieves instead of the
    # lift + planned retrieval. None: the planner retrieves.
    retrieval: object = None
    # MPPI methods: the scene-collision cost, "network" or "distance" (the ablation: the
    # world's distance fields); None: the method's own (``MethodSpec.collision``).
    mppi_cost: str | None = None
    # MPPI methods: the goal credit's region in rad (0: no credit); None: MppiConfig's default.
    mppi_goal_region: float | None = None
    # trajopt methods and the hybrids: the optimiser's counts, "SEEDSxITERSxSUBSTEPS"; None:
    # TrajoptConfig's.
    trajopt_counts: str | None = None
    # trajopt methods and the hybrids: the optimiser's Adam loop, "eager", "graph" or "grid"
    # (planning.trajopt.LOOPS); None: eager.
    trajopt_loop: str | None = None
    # trajopt methods and the hybrids: certified checks' floor in rad, or "off"; None:
    # TrajoptConfig's. (These five are what `fetchbench eval --planner-option` may set:
    # solutions.planner_options.)
    trajopt_certify: float | str | None = None

    def __post_init__(self):
        unknown = [i for i in self.improvements if i not in IMPROVEMENTS]
        if unknown:
            raise ValueError(f"unknown improvement {unknown[0]!r}; valid: {', '.join(IMPROVEMENTS)}")
        self.improvements = tuple(i for i in IMPROVEMENTS if i in self.improvements)

    @classmethod
    def for_run(cls, run: RunSpec, **fields) -> "SolveConfig":
        """The config of a resolved run: its pipeline's improvements, grasp labels, CGN weight
        set and planner options; ``fields``: any other of the config's."""
        return cls(improvements=run.improvements, grasp_labels=run.grasp_labels, grasp_model=run.grasp_model,
                   **dict(run.planner_options), **fields)

    @property
    def pipeline(self) -> str:
        return pipeline_label(self.improvements)

    def uses(self, improvement: str) -> bool:
        return improvement in self.improvements

    @property
    def start_escape_depth(self) -> float:
        """The planners' ``start_tolerance``: 0 (an invalid start fails) unless ``start_escape``."""
        return self.start_tolerance if self.uses("start_escape") else 0.0


@dataclass
class EpisodeState:
    config: SolveConfig
    computation_time: float = 0.0  # grasp inference + IK + world building + planning, s
    checks_left: int = 90000  # the episode's planning budget (collision checks) still unspent
    cspace_length: float = 0.0
    sim_steps: int = 0
    phases: dict = field(default_factory=lambda: {p: False for p in PHASES})
    grasp_source: str = ""
    notes: list = field(default_factory=list)  # what each try did, for diagnosis
    via_env_step: bool = False  # step through env.step (recordable) instead of _step_action
    stage: str = STAGES[0]  # the stage the next steps belong to
    stage_log: list = field(default_factory=list)  # the stage of every step taken
    last_step: tuple | None = None  # the last env.step result (via_env_step only)
    grasp_id: int | None = None  # the executed grasp's index in the object's grasp list
    last_arm_target: np.ndarray | None = None  # the last commanded arm joint targets
    reason: str | None = None  # why the try failed, finer than its class (FAILURE_REASONS)

    def timed(self, fn, *args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            self.computation_time += time.perf_counter() - t


class Executor:
    """Sends joint-position targets to the env, tracking C-space length (all 9 joints)."""

    def __init__(self, env, state: EpisodeState):
        self.env, self.u, self.state = env, env.unwrapped, state
        if self.u.agent.control_mode != "pd_joint_pos":
            raise ValueError(f"the sense-plan-act solver drives pd_joint_pos; the env uses "
                             f"{self.u.agent.control_mode!r} (make it with control_mode='pd_joint_pos')")
        self.dt = 1.0 / self.u.control_freq
        self.robot = robot_for_env(env)
        # GRIPPER_OPEN / GRIPPER_CLOSED are the Franka hand's normalised actions; a hand
        # whose action runs the other way (the Robotiq: +1 closes) flips them.
        self.gripper_sign = float(getattr(self.u.agent, "gripper_action_sign", 1.0))
        self.gripper = GRIPPER_OPEN
        self.last_qpos = self.qpos_full()

    def qpos_full(self) -> np.ndarray:
        return self.u.agent.robot.get_qpos()[0].cpu().numpy().astype(float)

    @property
    def q(self) -> np.ndarray:
        return self.qpos_full()[:7]

    def finger_opening(self) -> float:
        """Per-finger opening (m) now (the gripper's driving joint is right after the arm's)."""
        return self.robot.finger_from_gripper_q(self.qpos_full()[7:8])

    def step(self, q_arm: np.ndarray, gripper: float | None = None) -> None:
        if gripper is not None:
            self.gripper = gripper
        action = np.concatenate([q_arm, [self.gripper_sign * self.gripper]]).astype(np.float32)
        self.state.last_arm_target = np.asarray(q_arm, float)
        if self.state.via_env_step:
            self.state.last_step = self.env.step(action)
        else:
            self.u._step_action(action)
            self.u._elapsed_steps += 1
        self.state.stage_log.append(self.state.stage)
        qpos = self.qpos_full()
        self.state.cspace_length += float(np.abs(qpos - self.last_qpos).sum())
        self.last_qpos = qpos
        self.state.sim_steps += 1

    def follow(self, path: np.ndarray, speed_scale: float, settle_steps: int | None = None) -> None:
        robot = self.robot
        settle_steps = self.state.config.settle_steps if settle_steps is None else settle_steps
        for q in time_parametrize(path, self.dt, robot.velocity_limits, robot.acceleration_limits, speed_scale):
            self.step(q)
        for _ in range(settle_steps):
            self.step(path[-1])

    def hold(self, gripper: float, seconds: float) -> None:
        q = self.last_qpos[:7] if gripper == GRIPPER_OPEN else self.q
        for _ in range(int(round(seconds / self.dt))):
            self.step(q, gripper)


def _checker(cfg: SolveConfig, robot, world, **kwargs) -> CollisionChecker:
    """A collision checker with the config's margin and segment-check order."""
    checker = CollisionChecker(robot, world, margin=cfg.margin, **kwargs)
    checker.motion_check_first = cfg.motion_check_first
    return checker


def _hand_poses_base(T_base_object: np.ndarray, T_object_hand: np.ndarray) -> np.ndarray:
    return T_base_object[None] @ T_object_hand


def _cartesian_waypoints(T_from: np.ndarray, T_to: np.ndarray, n: int) -> list[np.ndarray]:
    out = []
    for s in np.linspace(0, 1, n + 1)[1:]:
        T = T_from.copy()
        T[:3, 3] = T_from[:3, 3] + s * (T_to[:3, 3] - T_from[:3, 3])
        out.append(T)
    return out


def _follow_cartesian(robot, q_start: np.ndarray, targets: list[np.ndarray], checker) -> np.ndarray | None:
    """Joint waypoints tracking Cartesian TCP targets from ``q_start`` (each IK seeded by the
    previous solution, one seed: the motion stays on the same IK branch); None if one fails."""
    path = [q_start]
    for T in targets:
        result = solve_ik(robot, T, checker=checker, q_seed=path[-1], n_seeds=1)
        if not result.found or np.abs(result.q[0] - path[-1]).max() > 0.5:
            return None
        path.append(result.q[0])
    return np.stack(path)


def _retrieval_goals(robot, checker, q_now: np.ndarray, rng) -> np.ndarray:
    """IK solutions for the free-space pose: hand down or sideways, the nearer side first."""
    T_tcp_now = robot.link_poses(q_now[None])[robot.tcp_link][0].numpy()
    positions = sorted(FREE_SPACE_POSITIONS, key=lambda p: abs(p[1] - T_tcp_now[1, 3]))
    targets = []
    for position in positions:
        side = np.sign(position[1])
        for approach in ((0, 0, -1), (0, side, 0), (-1, 0, 0)):
            for roll in (0.0, np.pi / 2, np.pi, -np.pi / 2):
                z = np.asarray(approach, float)
                helper = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 0, 1.0])
                y = np.cross(z, helper)
                y /= np.linalg.norm(y)
                c, s = np.cos(roll), np.sin(roll)
                y = c * y + s * np.cross(z, y)
                T = np.eye(4)
                T[:3, :3] = np.column_stack([np.cross(y, z), y, z])
                T[:3, 3] = position
                targets.append(T)
    result = solve_ik(robot, np.stack(targets), checker=checker, q_seed=q_now, n_seeds=4, rng=rng)
    if not result.found:
        return result.q
    # One (the nearest) solution per target pose, targets in the order above.
    best = result.best_per_target()
    return np.stack([best[i] for i in sorted(best)])


def _moved(env) -> tuple[float, float]:
    """(target displacement, largest other displacement) of centres of mass, m."""
    info = env.unwrapped.evaluate()
    return float(info["target_moved"][0]), float(info["max_others_moved"][0])


def _observe(env):
    from ..envs import fetch_clouds

    return fetch_clouds(env.unwrapped.get_obs(unflattened=True))  # one render per try


def _world_model(env, spec: MethodSpec, state: EpisodeState):
    if spec.world == "mesh":
        return state.timed(mesh_world, env), None
    clouds = _observe(env)
    robot = robot_for_env(env)
    qpos = env.unwrapped.agent.robot.get_qpos()[0].cpu().numpy().astype(float)
    q_full = np.concatenate([qpos[:7], [robot.finger_from_gripper_q(qpos[7:8])]])  # arm + finger opening
    return state.timed(pointcloud_world, clouds, q_full, robot=robot), clouds


def _grasp_candidates(env, spec: MethodSpec, state: EpisodeState, rng, tried: set, T_base_object, clouds):
    """The annotated grasps (a seeded random order), or the CGN predictions (best first); None
    when CGN has no target points to predict on."""
    cfg = state.config
    if spec.grasps == "annotated":
        return state.timed(choose_grasps, object_grasps(env.unwrapped.tasks[0].target.object_id, cfg.grasp_labels), rng,
                           cfg.max_grasps)
    clouds = clouds if clouds is not None else _observe(env)
    if len(clouds.target) == 0:
        # The cameras do not see the target: Contact-GraspNet has nothing to predict on.
        state.notes.append("target not seen by the cameras")
        state.reason = "target_not_seen"
        return None
    # Fresh ids for this try's predictions: never among the grasps tried before.
    return state.timed(predicted_grasps, clouds, T_base_object, cfg.grasp_model, cfg.max_grasps, rng,
                       first_index=max(tried, default=-1) + 1)


@dataclass
class Sensed:
    """What a try starts from: the world model, the observed clouds (None: the mesh world),
    the target's pose in the base frame and its catalog asset."""

    world: object
    clouds: object
    T_base_object: np.ndarray
    asset: object


@dataclass
class Grasps:
    """The grasp candidates still in play: their ids in the object's grasp list (a grasp tried
    in an earlier try is not tried again), TCP poses at the grasp and at the pre-grasp (N, 4, 4)."""

    ids: list
    T_grasp_tcp: np.ndarray
    T_pre_tcp: np.ndarray

    def take(self, rows) -> "Grasps":
        return Grasps([self.ids[i] for i in rows], self.T_grasp_tcp[rows], self.T_pre_tcp[rows])


def _attempt(env, spec: MethodSpec, state: EpisodeState, rng, tried: set) -> str | None:
    """One try; returns the failure class, or None when the target was carried out. Its stages:
    sense, grasp candidates (untried, then the open hand free), plan to a pre-grasp, approach
    and close; then the method's retrieval policy, or lift, attach the object, clear the support,
    retreat and plan the retrieval."""
    cfg, robot = state.config, robot_for_env(env)
    ex = Executor(env, state)
    sensed = _sense(env, spec, state)
    grasps = _untried_grasps(env, spec, state, rng, tried, sensed)
    if grasps is None:
        state.reason = state.reason or "no_untried_grasp"
        return "no_grasp_candidate"
    open_checker = _checker(cfg, robot, sensed.world, exclude=())
    near_target = _checker(cfg, robot, sensed.world, exclude=("target",))
    approach_checker = (near_target if not cfg.approach_tolerance else
                        _checker(dataclasses.replace(cfg, margin=cfg.margin - cfg.approach_tolerance), robot,
                                 sensed.world, exclude=("target",)))
    grasps = _free_grasps(spec, state, grasps, open_checker, near_target)
    if not grasps.ids:
        state.reason = "no_free_grasp"
        return "no_grasp_candidate"
    failure, chosen, approach_path = _plan_pregrasp(env, spec, state, ex, rng, grasps, open_checker, approach_checker)
    if failure is not None:
        return failure
    state.phases["pregrasp_plan"] = True
    tried.add(grasps.ids[chosen])
    state.grasp_id = grasps.ids[chosen]
    tcp_error = _approach_and_close(env, state, ex, approach_path, grasps.T_pre_tcp[chosen])
    if cfg.retrieval is not None:
        return cfg.retrieval(env, state, ex)
    if not _lift(env, state, ex, robot, tcp_error):
        state.reason = "not_grasped"
        return "grasp_failure"
    carry, world, finger = _carry_checker(env, state, ex, rng, robot, sensed, grasps.T_grasp_tcp[chosen])
    _clear_support(state, ex, robot, world, finger, carry)
    _retreat(state, ex, robot, carry)
    return _plan_retrieval(spec, state, ex, rng, robot, carry)


def _sense(env, spec: MethodSpec, state: EpisodeState) -> Sensed:
    """The try's world model (and clouds), the target's pose and its asset."""
    from ..objects.loading import load_object

    task = env.unwrapped.tasks[0]
    world, clouds = _world_model(env, spec, state)
    return Sensed(world, clouds, object_poses_base(env)[task.target_index], load_object(task.target.object_id))


def _untried_grasps(env, spec: MethodSpec, state: EpisodeState, rng, tried: set, sensed: Sensed) -> Grasps | None:
    """The method's grasp candidates not tried before, as TCP poses at the grasp and the
    pre-grasp; None when there are none."""
    grasps = _grasp_candidates(env, spec, state, rng, tried, sensed.T_base_object, sensed.clouds)
    if grasps is None:
        return None
    state.grasp_source = grasps.source
    T_grasp_tcp = tcp_from_hand(_hand_poses_base(sensed.T_base_object, grasps.T_object_hand))  # (N, 4, 4)
    untried = np.array([int(i) not in tried for i in grasps.index], dtype=bool)
    keep = [int(i) for i in grasps.index[untried]]
    if not keep:
        return None
    T_grasp_tcp = T_grasp_tcp[untried]
    return Grasps(keep, T_grasp_tcp, retreat(T_grasp_tcp, state.config.pregrasp_distance))


def _free_grasps(spec: MethodSpec, state: EpisodeState, grasps: Grasps, open_checker, near_target) -> Grasps:
    """The candidates that go to IK, in order. Cheap filter before IK: the open hand alone must
    be free at the pre-grasp (target included) and at the grasp (target left out: the fingers
    close on it). Annotated grasps: the open hand must be free (what collision-aware IK over
    every grasp finds, as the original's IK filter does, at a fraction of its cost). CGN
    predictions: the original's top 10 by score as they are; ``cgn_filter`` drops the colliding
    ones first."""
    cfg = state.config
    to_hand = np.linalg.inv(tcp_from_hand(np.eye(4)))
    # At the grasp the hand is where the straight approach ends: it gets the approach's tolerance.
    clearance = state.timed(lambda: np.minimum(open_checker.hand_clearance(grasps.T_pre_tcp @ to_hand),
                                               near_target.hand_clearance(grasps.T_grasp_tcp @ to_hand)
                                               + cfg.approach_tolerance))
    annotated = spec.grasps == "annotated"
    free = clearance > cfg.margin
    order = np.flatnonzero(free) if (annotated or cfg.uses("cgn_filter")) else np.arange(len(clearance))
    if cfg.grasp_order == "clearance":
        order = order[np.argsort(-clearance[order], kind="stable")]
    return grasps.take(order[: cfg.ik_grasps if annotated else cfg.cgn_grasps])


def _pregrasp_configurations(env, state: EpisodeState, rng, grasps: Grasps, open_checker, q_now, memo) -> dict:
    """Pre-grasp IK solutions by candidate row (the best per candidate that has one); with a
    ``CandidateMemo``, only the candidates it has not met are solved for."""
    cfg, robot = state.config, robot_for_env(env)
    if memo is None:
        pre = state.timed(solve_ik, robot, grasps.T_pre_tcp, checker=open_checker, q_seed=q_now, n_seeds=cfg.ik_seeds,
                          rng=rng)
        return pre.best_per_target()
    new = [j for j, grasp_id in enumerate(grasps.ids) if grasp_id not in memo.q_pre]
    if new:
        pre = state.timed(solve_ik, robot, grasps.T_pre_tcp[new], checker=open_checker, q_seed=q_now,
                          n_seeds=cfg.ik_seeds, rng=rng).best_per_target()
        memo.q_pre.update({grasps.ids[j]: pre.get(k) for k, j in enumerate(new)})
    return {j: memo.q_pre[g] for j, g in enumerate(grasps.ids) if memo.q_pre[g] is not None}


def _plan_pregrasp(env, spec: MethodSpec, state: EpisodeState, ex: "Executor", rng, grasps: Grasps, open_checker,
                   approach_checker) -> tuple[str | None, int | None, np.ndarray | None]:
    """IK for the pre-grasps, then the planner to a goal set of them (each with its straight
    approach path, checked with ``approach_checker``); the robot moves to the pre-grasp. Returns (failure class or None, the
    chosen candidate's row, its approach path)."""
    cfg, robot = state.config, robot_for_env(env)
    q_now = ex.q
    memo = (_candidate_memo(env.unwrapped.tasks[0], q_now, object_poses_base(env), rng, cfg) if cfg.reuse_candidates
            else None)
    best_pre = _pregrasp_configurations(env, state, rng, grasps, open_checker, q_now, memo)
    # Approach: Cartesian line from each pre-grasp to 4 cm x 1.05 along the approach.
    pending = iter(best_pre.items())
    keep, T_pre_tcp = grasps.ids, grasps.T_pre_tcp

    def goal_sets():
        """Up to ``pregrasp_goal_sets`` sets of ``goal_set_size`` (candidate index, q_pre,
        approach path), each made when it is asked for: only a failed plan pays for the next."""
        for _ in range(cfg.pregrasp_goal_sets):
            goal_set = []
            for i, q_pre in pending:
                if memo is not None and keep[i] in memo.approach:
                    path = memo.approach[keep[i]]
                else:
                    T_end = retreat(T_pre_tcp[i], -cfg.pregrasp_distance * cfg.approach_overshoot)
                    path = state.timed(_follow_cartesian, robot, q_pre, _cartesian_waypoints(T_pre_tcp[i], T_end, 4),
                                       approach_checker)
                    if memo is not None:
                        memo.approach[keep[i]] = path
                if path is not None:
                    goal_set.append((i, q_pre, path))
                if len(goal_set) >= cfg.goal_set_size:
                    break
            if not goal_set:
                return
            yield goal_set

    plan = None
    for goal_set in goal_sets():
        state.phases["ik_found"] = True
        plan = _plan_and_move(state, ex, rng, open_checker, q_now, np.stack([c[1] for c in goal_set]), spec)
        state.notes.append(f"candidates {len(keep)} ik {len(goal_set)}; pre-grasp plan {plan.status} "
                           f"{plan.n_checked} checks {plan.planning_time:.2f}s"
                           + (" (start escaped)" if plan.start_escaped else ""))
        if plan.success or (state.checks_left <= 0 and spec.planner.budgeted):
            break
    if plan is None:
        state.reason = "no_approach" if best_pre else "no_pregrasp_ik"
        return "no_grasp_candidate", None, None
    if not plan.success:
        state.reason = f"pregrasp_plan:{plan.status}"
        return _plan_failure(plan), None, None
    chosen, _, approach_path = goal_set[plan.goal_index]
    return None, chosen, approach_path


def _approach_and_close(env, state: EpisodeState, ex: "Executor", approach_path: np.ndarray,
                        T_pre_tcp: np.ndarray) -> float:
    """The straight approach from the pre-grasp, then the gripper closes; returns how far (m)
    the TCP stopped from the approach's end."""
    cfg, u = state.config, env.unwrapped
    ex.follow(np.vstack([ex.q[None], approach_path[1:]]), cfg.approach_speed_scale)
    T_tcp_actual = u.agent.tcp.pose.raw_pose[0].cpu().numpy()
    T_base_tcp_actual = np.linalg.inv(T_world_base(env)) @ pose_matrix(T_tcp_actual[:3], T_tcp_actual[3:])
    T_end = retreat(T_pre_tcp, -cfg.pregrasp_distance * cfg.approach_overshoot)
    tcp_error = np.linalg.norm(T_base_tcp_actual[:3, 3] - T_end[:3, 3])
    state.phases["approach_reached"] = bool(tcp_error < 0.01)
    state.stage = "close"
    ex.hold(GRIPPER_CLOSED, cfg.close_seconds)
    state.stage = "retrieve"
    return tcp_error


def _lift(env, state: EpisodeState, ex: "Executor", robot, tcp_error: float) -> bool:
    """Lift straight up; whether the target is grasped then."""
    cfg, u = state.config, env.unwrapped
    T_lift = robot.link_poses(ex.q[None])[robot.tcp_link][0].numpy().copy()
    T_lift[2, 3] += cfg.lift_height  # the base is upright: base z is world z
    lift = state.timed(_follow_cartesian, robot, ex.q, [T_lift], None)
    if lift is not None:
        ex.follow(lift, cfg.approach_speed_scale)
    state.phases["grasped"] = bool(u.agent.is_grasping(u.target)[0])
    state.notes.append(f"finger gap after close {2 * ex.finger_opening():.4f} m, tcp error {tcp_error:.4f} m")
    return state.phases["grasped"]


def _carry_checker(env, state: EpisodeState, ex: "Executor", rng, robot, sensed: Sensed, T_grasp_tcp: np.ndarray):
    """The checker of the arm carrying the object: the object attached in the hand frame, its
    convex parts at the simulated pose (mesh world, built again: objects may have shifted while
    grasping), or its observed points carried along with the planned grasp (point clouds).
    Returns (checker, its world, the finger opening)."""
    cfg, task = state.config, env.unwrapped.tasks[0]
    T_base_hand = robot.link_poses(ex.q[None])[robot.hand_link][0].numpy()
    world = sensed.world
    if sensed.clouds is None:
        T_hand_object = np.linalg.inv(T_base_hand) @ object_poses_base(env)[task.target_index]
        seed = int(rng.integers(2**31))
        if cfg.attachment_per_object:
            attachment = _object_attachment(task.target.object_id).moved(T_hand_object)
        else:
            parts_hand = [p.copy().apply_transform(T_hand_object) for p in sensed.asset.convex_parts]
            attachment = Attachment.from_convex_parts(parts_hand, seed=seed)
        world = state.timed(mesh_world, env, cfg.world_pose_tolerance)
    else:
        target = sensed.clouds.target
        T_hand_grasp = T_grasp_tcp @ np.linalg.inv(tcp_from_hand(np.eye(4)))
        points_hand = (np.linalg.inv(T_hand_grasp) @ np.c_[target, np.ones(len(target))].T).T[:, :3]
        if len(points_hand) == 0:  # target not seen: a ball between the fingers
            points_hand = np.array([[0.0, 0.0, 0.1034]])
        attachment = Attachment.from_points(points_hand, seed=int(rng.integers(2**31)))
    finger = ex.finger_opening()
    # The fingers wrap the object: the attachment spheres stand for both there.
    carry = _checker(cfg, robot, world, finger=finger, exclude=("target",), attachment=attachment,
                     ignore_links=robot.finger_links)
    return carry, world, finger


def _clear_support(state: EpisodeState, ex: "Executor", robot, world, finger: float, carry) -> None:
    """``extra_lifts``: the carried object's balls still touch what it stood on (they bulge
    ~1 cm past its faces, or it slipped a little): lift further, checking the arm alone."""
    cfg = state.config
    if carry.valid(ex.q)[0]:
        return
    arm_only = _checker(cfg, robot, world, finger=finger, exclude=("target",), ignore_links=robot.finger_links)
    for extra in (cfg.extra_lifts if cfg.uses("extra_lifts") else ()):
        T_up = robot.link_poses(ex.q[None])[robot.tcp_link][0].numpy().copy()
        T_up[2, 3] += extra
        path = state.timed(_follow_cartesian, robot, ex.q, _cartesian_waypoints(
            robot.link_poses(ex.q[None])[robot.tcp_link][0].numpy(), T_up, 3), arm_only)
        if path is not None and carry.valid(path[-1])[0]:
            ex.follow(path, cfg.approach_speed_scale)
            state.notes.append(f"lifted {extra:.2f} m more")
            break


def _retreat(state: EpisodeState, ex: "Executor", robot, carry) -> None:
    """``retreat``: back out straight along the approach, the longest free distance first."""
    cfg = state.config
    T_tcp = robot.link_poses(ex.q[None])[robot.tcp_link][0].numpy()
    for distance in (cfg.retreat_distances if cfg.uses("retreat") else ()):
        path = state.timed(_follow_cartesian, robot, ex.q, _cartesian_waypoints(T_tcp, retreat(T_tcp, distance), 4),
                           carry)
        if path is not None and all(
                carry.motion_valid(a, b) for a, b in zip(path[:-1], path[1:])):
            ex.follow(path, cfg.approach_speed_scale * 2)
            state.notes.append(f"retreated {distance:.2f} m")
            break


def _plan_retrieval(spec: MethodSpec, state: EpisodeState, ex: "Executor", rng, robot, carry) -> str | None:
    """The planner to the free-space pose with the object; the failure class or None."""
    cfg = state.config
    goals = state.timed(_retrieval_goals, robot, carry, ex.q, rng)
    if len(goals) == 0 or (state.checks_left <= 0 and spec.planner.budgeted):
        state.notes.append("retrieval: no IK goal" if len(goals) == 0 else "retrieval: no planning budget left")
        state.reason = "retrieval_no_ik" if len(goals) == 0 else "retrieval_no_budget"
        return "motion_planning_failure"
    plan = _plan_and_move(state, ex, rng, carry, ex.q, goals[: cfg.goal_set_size], spec)
    state.notes.append(f"retrieval goals {len(goals)}; plan {plan.status} {plan.n_checked} checks "
                       f"{plan.planning_time:.2f}s" + (" (start escaped)" if plan.start_escaped else ""))
    if not plan.success:
        state.reason = f"retrieval_plan:{plan.status}"
        return _plan_failure(plan)
    state.phases["retrieval_plan"] = True
    return None


@dataclass
class CandidateMemo:
    """A task's pre-grasp IK solutions and approach paths by grasp id (None: none found), from
    its first try on. Every try of the expert starts from the same reset (the same objects'
    poses, arm configuration and rng state), so a later try reuses them and only solves for
    grasps it has not met; a try whose untried grasps all have none ends at once."""

    key: tuple
    q_pre: dict = field(default_factory=dict)
    approach: dict = field(default_factory=dict)


_MEMO: list = [None]  # the process's memo (one env, one task at a time)


def _candidate_memo(task, q_now: np.ndarray, T_base_objects: list, rng, config: SolveConfig) -> CandidateMemo:
    """The memo of this start and config (``SolveConfig.reuse_candidates``); another empties it."""
    key = (task.to_json(), np.asarray(q_now).tobytes(), b"".join(np.asarray(T).tobytes() for T in T_base_objects),
           repr(rng.bit_generator.state), repr(config))
    if _MEMO[0] is None or _MEMO[0].key != key:
        _MEMO[0] = CandidateMemo(key)
    return _MEMO[0]


@functools.lru_cache(maxsize=64)
def _object_attachment(object_id: str) -> Attachment:
    """An object's carried balls in its own frame (``SolveConfig.attachment_per_object``), from
    a seed of its id: the same balls for every grasp of it, in any process."""
    from ..objects.loading import load_object

    seed = int(sha256_bytes(object_id.encode())[:8], 16) % 2**31
    return Attachment.from_convex_parts(load_object(object_id).convex_parts, seed=seed)


def _plan_failure(plan) -> str:
    """The failure class of a failed plan: a wall-clock safety net is ``timeout``, anything
    else (budget spent, invalid start, no valid goal) ``motion_planning_failure``."""
    return "timeout" if plan.status == "timeout" else "motion_planning_failure"


def _plan_and_move(state: EpisodeState, ex: "Executor", rng, checker, q_start, q_goals, spec: MethodSpec):
    """Plan with the method's planner (``spec.planner``: ``plan(PlanRequest)``, seeded from the
    episode's rng) and move along the plan when it succeeded. A budgeted planner (RRTConnect,
    trajopt) may spend ``plan_checks_per_try`` collision checks at most, and what the episode
    has left, which the checks it spent are taken from. An executing planner (MPPI) moves while
    it plans: every replan executes a second of its plan from where the robot really is; its
    ``planning_time`` is its computation only."""
    cfg, planner = state.config, spec.planner
    plan_fn = load(planner.entry)

    def execute(path):
        ex.follow(path, cfg.speed_scale, settle_steps=0)
        return ex.q

    request = PlanRequest(checker, q_start, q_goals, seed=int(rng.integers(2**31)),
                          max_checks=max(0, min(cfg.plan_checks_per_try, state.checks_left)),
                          checks_per_try=cfg.plan_checks_per_try, time_limit=cfg.plan_safety_seconds,
                          start_tolerance=cfg.start_escape_depth, speed_scale=cfg.speed_scale, collision=spec.collision,
                          options={name: getattr(cfg, name) for name in planner.options},
                          execute=execute if planner.executes else None)
    if planner.executes:
        plan = plan_fn(request)
        state.computation_time += plan.planning_time
        return plan
    plan = state.timed(plan_fn, request)
    if planner.budgeted:
        state.checks_left -= plan.n_checked
    if plan.success:
        ex.follow(plan.path, cfg.speed_scale)
    return plan


def _return_home(env, spec: MethodSpec, state: EpisodeState, rng) -> bool:
    """Open the gripper and go back to the task's start configuration (for a retry)."""
    cfg, robot, u = state.config, robot_for_env(env), env.unwrapped
    ex = Executor(env, state)
    ex.hold(GRIPPER_OPEN, 0.5)
    world, _ = _world_model(env, spec, state)
    checker = CollisionChecker(robot, world, margin=cfg.margin)
    q_home = u.start_arm_qpos(0)
    if state.checks_left <= 0 and spec.planner.budgeted:
        return False
    plan = _plan_and_move(state, ex, rng, checker, ex.q, q_home, spec)
    return plan.success


def solve(env, seed: int | None = None, method: MethodSpec | str = "ga-mesh-rrt", retries: int = 1,
          config: SolveConfig | None = None, reset: bool = True, grasp_model: str | None = None) -> dict:
    """Run one FetchBench episode with a sense-plan-act baseline; returns its metrics.

    ``method``: its spec (``method_spec.MethodSpec``; a name is looked up once, here).
    ``retries`` is the number of tries in all (FetchBench's ``--retries 5``); a further try
    is made only if the target moved <= 0.12 m and nothing else moved >= 0.10 m.
    """
    spec = method if isinstance(method, MethodSpec) else method_spec(method)
    if spec.planner is None:
        raise ValueError(f"{spec.name} runs no sense-plan-act pipeline (it has no planner)")
    if retries < 1:
        raise ValueError(f"retries must be >= 1, got {retries}")
    if config is not None and config.grasp_order not in GRASP_ORDERS:
        raise ValueError(f"unknown grasp_order {config.grasp_order!r}; valid: {', '.join(GRASP_ORDERS)}")
    if spec.reads_clouds and env.unwrapped.obs_mode != "pointcloud":
        raise ValueError(f"{spec.name} reads the observed point clouds: make the env with obs_mode='pointcloud' "
                         f"(it has {env.unwrapped.obs_mode!r})")
    config = dataclasses.replace(config or SolveConfig(), retries=retries)
    if grasp_model is not None:
        config = dataclasses.replace(config, grasp_model=grasp_model)
    torch.set_num_threads(1)  # small batches: threads only add overhead here
    t_wall = time.perf_counter()
    if reset:
        env.reset(seed=seed)
    rng = np.random.default_rng(seed if seed is not None else 0)
    state = EpisodeState(config, checks_left=config.plan_checks_total)
    tried: set = set()
    failure, attempts = None, 0
    for attempts in range(1, retries + 1):
        outcome = _attempt(env, spec, state, rng, tried)
        # A retry that finds no untried grasp keeps the failure that made it retry.
        failure = failure if (outcome == "no_grasp_candidate" and attempts > 1) else outcome
        if failure is None or attempts == retries:
            break
        target_moved, others_moved = _moved(env)
        if target_moved > config.retry_target_moved or others_moved >= config.retry_others_moved:
            break
        if not _return_home(env, spec, state, rng):
            break
    verdict = judge(env, failure)
    state.phases["held_at_end"] = verdict.held_at_end
    task = env.unwrapped.tasks[0]
    return {
        "method": spec.name,
        "seed": seed,
        "task_seed": task.seed,
        "scene_type": task.scene_type,
        "category": task.target_label,
        "target_object": task.target.object_id,
        "success": verdict.success,
        "failure": verdict.failure,
        "computation_time": round(state.computation_time, 4),
        "cspace_length": round(state.cspace_length, 4),
        "attempts": attempts,
        "pipeline": config.pipeline,
        "improvements": list(config.improvements),
        "planning_checks": config.plan_checks_total - state.checks_left,
        "phases": state.phases,
        "grasp_source": state.grasp_source,
        "target_moved": verdict.target_moved,
        "max_others_moved": verdict.max_others_moved,
        "sim_steps": state.sim_steps,
        "notes": state.notes,
        "wall_time": round(time.perf_counter() - t_wall, 2),
    }
