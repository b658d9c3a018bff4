"""FetchBench's reachability filter for tasks, on the planner's machinery.

A task is reachable when a collision-free IK solution exists for at least one grasp of
the target (the target's own collisions ignored, as in the original), in the oracle
mesh world. The task sampler can call this on a freshly reset env.
"""
from __future__ import annotations

import numpy as np

from ..planning.checker import CollisionChecker
from ..planning.ik import solve_ik
from ..planning.robot import robot_for_env
from .grasp_source import object_grasps, tcp_from_hand
from .worlds import mesh_world, object_poses_base


def reachable_grasps(env, max_grasps: int = 64, n_seeds: int = 8, seed: int = 0) -> np.ndarray:
    """Indices (into ``object_grasps(target)``) of grasps with a collision-free IK solution."""
    u = env.unwrapped
    task = u.tasks[0]
    robot = robot_for_env(env)
    checker = CollisionChecker(robot, mesh_world(env), exclude=("target",))
    T_object_hand = object_grasps(task.target.object_id).T_object_hand
    T_tcp = tcp_from_hand(object_poses_base(env)[task.target_index][None] @ T_object_hand)  # (N, 4, 4)
    # The open hand alone must be free first (cheap), then the arm.
    free = np.flatnonzero(checker.hand_clearance(T_tcp @ np.linalg.inv(tcp_from_hand(np.eye(4)))) > 0)[:max_grasps]
    if len(free) == 0:
        return free
    q_start = u.agent.robot.get_qpos()[0, :7].cpu().numpy().astype(float)
    result = solve_ik(robot, T_tcp[free], checker=checker, q_seed=q_start, n_seeds=n_seeds,
                      rng=np.random.default_rng(seed))
    return free[np.unique(result.target_index)]


def is_reachable(env, **kwargs) -> bool:
    return len(reachable_grasps(env, **kwargs)) > 0
