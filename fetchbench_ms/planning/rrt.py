"""RRTConnect (OMPL) in the Panda's 7-D joint space on a CollisionChecker.

Edges are validated in one batched call per edge (a Python MotionValidator that
interpolates at ``resolution`` rad), which is far cheaper than OMPL's one-state-at-a-
time callbacks. Before searching, the straight segment to each goal is tried (free
space is common once the hand is out of the furniture). After a solution, OMPL's
PathSimplifier shortens it; the result is re-checked densely before it is returned.

A start that the sphere model calls in collision (the spheres are conservative: the
simulated robot at rest, or holding an object that still touches its support, can be
"inside" furniture by a few cm) is escaped first, as MoveIt's start-state repair does:
a nearby valid configuration reached by a straight segment that never goes deeper than
the start, then the search from there (``start_tolerance``).

Determinism: the ompl 2.0.1 bindings expose no per-planner seed or sampler hook, so
RRTConnect's samples come from OMPL's process-wide RNG. The planner is made repeatable
(``seed``, 0 by default): OMPL's seed generator is re-seeded before the planner, its
sampler and the path simplifier are made (every RNG they create then draws the same seeds;
OMPL logs a misleading error for a re-seed, silenced here), and the restarts and the end of
the search count collision checks instead of seconds (``restart_checks``, ``max_checks``:
status ``budget`` when they run out), so the machine's speed and load change nothing. The
time limit is a safety net only: a search it stops ends with status ``timeout``, which
callers report as such. ``seed=None`` gives the old wall-clock search (restarts every
``restart_after`` seconds until the time limit), for interactive use only.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .checker import CollisionChecker

#: ``budget``: the search used its collision checks without a path; ``timeout``: the wall-clock
#: safety net stopped it (the machine was too slow or overloaded: not a planning verdict).
STATUSES = ("solved", "direct", "start_invalid", "no_valid_goal", "budget", "timeout")


@dataclass
class PlanResult:
    status: str  # one of STATUSES
    path: np.ndarray | None  # (N, 7) waypoints, straight joint-space segments between them
    planning_time: float  # s
    n_checked: int  # configurations checked
    goal_index: int = -1  # which of the asked goals was reached
    start_escaped: bool = False  # the path begins with a move out of an invalid start
    planner: str = "rrtconnect"  # what found the path: rrtconnect | trajopt | trajopt+rrtconnect (fallback) | mppi
    executed: bool = False  # the robot already moved along ``path`` (MPPI executes while it plans)
    # The planner's own notes on how it ran (trajopt: its loop, its ``phase_s`` timer): a report only
    extras: dict = field(default_factory=dict)

    @property
    def success(self) -> bool:
        # An executing planner (MPPI) returns the path it moved along even when it fell short.
        return self.path is not None and (not self.executed or self.status == "solved")


@dataclass(frozen=True)
class PlanRequest:
    """What the sense-plan-act pipeline asks every planner (``method_spec.PlannerSpec.entry``:
    ``plan(request) -> PlanResult``): a path from ``q_start`` to any of ``q_goals`` ((K, 7),
    best first) free in ``checker``. ``seed`` makes it repeatable; ``max_checks`` is what it
    may spend of the episode's collision checks (``checks_per_try``: a call's share at most);
    ``time_limit`` (s) is a safety net (status ``timeout``); ``start_tolerance``: how deep an
    invalid start may be escaped (0: it fails). An executing planner moves the robot along
    joint waypoints with ``execute(path) -> measured q`` at ``speed_scale`` of the velocity
    limits. ``collision``: the method's collision model; ``options``: the planner options it
    takes (``PlannerSpec.options``) as the run set them (None: its default)."""

    checker: CollisionChecker
    q_start: np.ndarray
    q_goals: np.ndarray
    seed: int
    max_checks: int
    checks_per_try: int
    time_limit: float
    start_tolerance: float = 0.0
    speed_scale: float = 0.4
    collision: str = "spheres"
    options: dict = field(default_factory=dict)
    execute: Optional[Callable[[np.ndarray], np.ndarray]] = None


def plan(request: PlanRequest) -> PlanResult:
    """RRTConnect for the pipeline: restarts every half try's checks (at most what is left)."""
    return plan_rrtconnect(request.checker, request.q_start, request.q_goals, request.time_limit,
                           start_tolerance=request.start_tolerance, seed=request.seed, max_checks=request.max_checks,
                           restart_checks=max(1, min(request.max_checks, request.checks_per_try // 2)))


def _to_np(state, dim: int = 7) -> np.ndarray:
    return np.array([state[i] for i in range(dim)])


def densify(path: np.ndarray, resolution: float) -> np.ndarray:
    """Waypoints with no joint moving more than ``resolution`` between neighbours."""
    out = [path[:1]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.abs(b - a).max() / resolution)))
        out.append(a + np.linspace(0, 1, n + 1)[1:, None] * (b - a))
    return np.concatenate(out)


def path_valid(checker: CollisionChecker, path: np.ndarray, resolution: float, first: int | None = None,
               certify: float | None = None) -> bool:
    """Every configuration of the path densified at ``resolution`` valid (``first``,
    ``certify``: as ``CollisionChecker.all_valid``'s)."""
    return checker.all_valid(densify(np.asarray(path, float), resolution), first, certify=certify)


ESCAPE_RADII = (0.03, 0.06, 0.12, 0.25)  # rad: the boxes around the start searched in turn
ESCAPE_SAMPLES = 64  # configurations tried per radius


def escape_start(checker: CollisionChecker, q_start, tolerance: float, resolution: float = 0.02,
                 seed: int = 0) -> np.ndarray | None:
    """A valid configuration near an invalid ``q_start`` whose straight segment from the start
    never goes deeper into collision than the start itself (so a real robot resting there
    can make that move), or None: the start is outside the joint limits, deeper than
    ``tolerance`` (m of sphere penetration beyond the checker's margin), or boxed in.
    Samples grow in radius and are tried nearest first; seeded, so the same every time."""
    q_start = np.asarray(q_start, float).reshape(7)
    robot = checker.robot
    if not robot.within_limits(q_start[None])[0]:
        return None
    depth = checker.margin - float(checker.clearance(q_start[None])[0])
    if depth > tolerance:
        return None
    rng = np.random.default_rng(seed)
    for radius in ESCAPE_RADII:
        q = np.clip(q_start + rng.uniform(-radius, radius, (ESCAPE_SAMPLES, 7)), robot.q_min, robot.q_max)
        ok = np.flatnonzero(checker.valid(q))
        for i in ok[np.argsort(np.abs(q[ok] - q_start).max(axis=1), kind="stable")]:
            segment = densify(np.stack([q_start, q[i]]), resolution)
            # Never deeper than at the start (a small slack for float noise), valid at the end.
            if bool((checker.clearance(segment) >= checker.margin - depth - 1e-4).all()):
                return q[i]
    return None


def plan_rrtconnect(checker: CollisionChecker, q_start, q_goals, time_limit: float = 300.0,
                    resolution: float = 0.02, simplify: bool = True, try_direct: bool = True,
                    restart_after: float = 5.0, planner_range: float | None = None,
                    start_tolerance: float = 0.0, seed: int | None = 0, restart_checks: int = 15000,
                    max_checks: int = 30000) -> PlanResult:
    """Plan from ``q_start`` to any of ``q_goals`` ((7,) or (K, 7)), best goals first.

    RRTConnect's run time is heavy-tailed (a tree that grew into a pocket rarely gets
    out), so the search restarts with fresh trees every ``restart_after`` seconds until
    ``time_limit``. ``planner_range`` is RRTConnect's step (OMPL's default, a fifth of
    the space's extent, did best into a shelf cell; 0.3-1.0 rad did worse).
    ``start_tolerance`` > 0: an invalid start up to that deep is escaped first
    (``escape_start``); the path then begins with that move (``start_escaped``).
    ``seed``: a repeatable search (module docstring), restarting every ``restart_checks``
    collision checks and giving up after ``max_checks`` (about 3,000-6,000 checks a second);
    ``time_limit`` (s) is then only a safety net. ``seed=None``: restarts every ``restart_after``
    seconds until ``time_limit`` (not repeatable).
    """
    import ompl.base as ob
    import ompl.geometric as og
    import ompl.util as ou

    ou.setLogLevel(ou.LOG_WARN)
    t0 = time.perf_counter()
    n0 = checker.n_checked
    q_start = np.asarray(q_start, float).reshape(7)
    q_goals = np.asarray(q_goals, float).reshape(-1, 7)

    def result(status, path=None, goal_index=-1):
        return PlanResult(status, path, time.perf_counter() - t0, checker.n_checked - n0, goal_index)

    if not checker.valid(q_start)[0]:
        q_free = escape_start(checker, q_start, start_tolerance, resolution) if start_tolerance > 0 else None
        if q_free is None:
            return result("start_invalid")
        rest = plan_rrtconnect(checker, q_free, q_goals, max(0.0, time_limit - (time.perf_counter() - t0)),
                               resolution, simplify, try_direct, restart_after, planner_range, seed=seed,
                               restart_checks=restart_checks, max_checks=max_checks)
        path = None if rest.path is None else np.concatenate([q_start[None], rest.path])
        return PlanResult(rest.status, path, time.perf_counter() - t0, checker.n_checked - n0, rest.goal_index,
                          start_escaped=True)
    goal_ok = checker.valid(q_goals) if len(q_goals) else np.zeros(0, bool)
    goal_ids = np.flatnonzero(goal_ok)
    if len(goal_ids) == 0:
        return result("no_valid_goal")
    if try_direct:
        for g in goal_ids:
            if checker.motion_valid(q_start, q_goals[g], resolution):
                return result("direct", np.stack([q_start, q_goals[g]]), int(g))

    if seed is not None:
        ou.setLogLevel(ou.LOG_NONE)
        ou.RNG.setSeed(int(seed) % (2**31 - 1) + 1)  # 0 would mean "from the clock"
        ou.setLogLevel(ou.LOG_WARN)
    robot = checker.robot
    space = ob.RealVectorStateSpace(7)
    bounds = ob.RealVectorBounds(7)
    for i in range(7):
        bounds.setLow(i, float(robot.q_min[i]))
        bounds.setHigh(i, float(robot.q_max[i]))
    space.setBounds(bounds)
    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(lambda s: bool(checker.valid(_to_np(s))[0]))

    class BatchedMotionValidator(ob.MotionValidator):
        def checkMotion(self, *args):
            if len(args) != 2:  # the (s1, s2, lastValid) form: answer conservatively
                return False
            return checker.motion_valid(_to_np(args[0]), _to_np(args[1]), resolution)

    validator = BatchedMotionValidator(si)
    si.setMotionValidator(validator)
    si.setup()
    pdef = ob.ProblemDefinition(si)
    start = space.allocState()
    for i in range(7):
        start[i] = float(q_start[i])
    pdef.addStartState(start)
    goals = ob.GoalStates(si)
    for g in goal_ids:
        s = space.allocState()
        for i in range(7):
            s[i] = float(q_goals[g, i])
        goals.addState(s)
    pdef.setGoal(goals)
    deadline = t0 + time_limit
    n_search = checker.n_checked
    while (not pdef.hasExactSolution() and time.perf_counter() < deadline
           and (seed is None or checker.n_checked - n_search < max_checks)):
        pdef.clearSolutionPaths()
        planner = og.RRTConnect(si)
        if planner_range is not None:
            planner.setRange(planner_range)
        planner.setProblemDefinition(pdef)
        planner.setup()
        if seed is None:
            stop = min(deadline, time.perf_counter() + restart_after)
            done = (lambda: time.perf_counter() > stop)
        else:
            stop_checks = min(checker.n_checked + restart_checks, n_search + max_checks)
            done = (lambda: checker.n_checked >= stop_checks or time.perf_counter() > deadline)
        planner.solve(ob.PlannerTerminationCondition(done))
    if not pdef.hasExactSolution():
        out_of_time = seed is None or time.perf_counter() >= deadline
        return result("timeout" if out_of_time else "budget")
    path_geo = pdef.getSolutionPath()
    if simplify:
        og.PathSimplifier(si).simplifyMax(path_geo)
    path = np.stack([_to_np(path_geo.getState(i)) for i in range(path_geo.getStateCount())])
    end = path[-1]
    goal_index = int(goal_ids[np.argmin(np.abs(q_goals[goal_ids] - end).max(axis=1))])
    if not path_valid(checker, path, resolution):
        return result("budget")  # never expected: the same validator accepted every edge
    return result("solved", path, goal_index)
