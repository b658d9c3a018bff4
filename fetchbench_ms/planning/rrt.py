"""RRTConnect (OMPL) in the Panda's 7-D joint space on a CollisionChecker.

Edges are validated in one batched call per edge (a Python MotionValidator that
interpolates at ``resolution`` rad), which is far cheaper than OMPL's one-state-at-a-
time callbacks. Before searching, the straight segment to each goal is tried (free
space is common once the hand is out of the furniture). After a solution, OMPL's
PathSimplifier shortens it; the result is re-checked densely before it is returned.

Determinism: the ompl 2.0.1 bindings expose no per-planner seed or sampler hook, so
RRTConnect's samples come from OMPL's process-wide RNG; everything around it (goal
order, checks, simplification input) is deterministic.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .checker import CollisionChecker

STATUSES = ("solved", "direct", "start_invalid", "no_valid_goal", "timeout")


@dataclass
class PlanResult:
    status: str  # one of STATUSES
    path: np.ndarray | None  # (N, 7) waypoints, straight joint-space segments between them
    planning_time: float  # s
    n_checked: int  # configurations checked
    goal_index: int = -1  # which of the asked goals was reached

    @property
    def success(self) -> bool:
        return self.path is not None


def _to_np(state, dim: int = 7) -> np.ndarray:
    return np.array([state[i] for i in range(dim)])


def densify(path: np.ndarray, resolution: float) -> np.ndarray:
    """Waypoints with no joint moving more than ``resolution`` between neighbours."""
    out = [path[:1]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.abs(b - a).max() / resolution)))
        out.append(a + np.linspace(0, 1, n + 1)[1:, None] * (b - a))
    return np.concatenate(out)


def path_valid(checker: CollisionChecker, path: np.ndarray, resolution: float) -> bool:
    return bool(checker.valid(densify(np.asarray(path, float), resolution)).all())


def plan_rrtconnect(checker: CollisionChecker, q_start, q_goals, time_limit: float = 10.0,
                    resolution: float = 0.02, simplify: bool = True, try_direct: bool = True,
                    restart_after: float = 5.0, planner_range: float | None = None) -> PlanResult:
    """Plan from ``q_start`` to any of ``q_goals`` ((7,) or (K, 7)), best goals first.

    RRTConnect's run time is heavy-tailed (a tree that grew into a pocket rarely gets
    out), so the search restarts with fresh trees every ``restart_after`` seconds until
    ``time_limit``. ``planner_range`` is RRTConnect's step (OMPL's default, a fifth of
    the space's extent, did best into a shelf cell; 0.3-1.0 rad did worse).
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
        return result("start_invalid")
    goal_ok = checker.valid(q_goals) if len(q_goals) else np.zeros(0, bool)
    goal_ids = np.flatnonzero(goal_ok)
    if len(goal_ids) == 0:
        return result("no_valid_goal")
    if try_direct:
        for g in goal_ids:
            if checker.motion_valid(q_start, q_goals[g], resolution):
                return result("direct", np.stack([q_start, q_goals[g]]), int(g))

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
    while not pdef.hasExactSolution() and time.perf_counter() < deadline:
        pdef.clearSolutionPaths()
        planner = og.RRTConnect(si)
        if planner_range is not None:
            planner.setRange(planner_range)
        planner.setProblemDefinition(pdef)
        planner.setup()
        stop = min(deadline, time.perf_counter() + restart_after)
        planner.solve(ob.PlannerTerminationCondition(lambda: time.perf_counter() > stop))
    if not pdef.hasExactSolution():
        return result("timeout")
    path_geo = pdef.getSolutionPath()
    if simplify:
        og.PathSimplifier(si).simplifyMax(path_geo)
    path = np.stack([_to_np(path_geo.getState(i)) for i in range(path_geo.getStateCount())])
    end = path[-1]
    goal_index = int(goal_ids[np.argmin(np.abs(q_goals[goal_ids] - end).max(axis=1))])
    if not path_valid(checker, path, resolution):
        return result("timeout")  # never expected: the same validator accepted every edge
    return result("solved", path, goal_index)
