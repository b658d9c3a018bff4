"""The start configuration of each other robot (``RobotSetup.q_home`` in
fetchbench_ms/robots/__init__.py): the arm's TCP where the Panda's start configuration
puts the Panda's TCP (same position and orientation in the base frame), or where the
arm's reach ends, the highest point straight below it (1 cm steps: the Gen3 with the
longer Robotiq cannot hold its TCP 0.6 m up 0.1 m in front of its base), free of
self-collision, the solution farthest from the joint limits (the largest smallest
margin, as a fraction of each joint's range) among 256 seeded IK starts.

    python scripts/maint/robot_home.py            # prints each robot's q_home
"""
from __future__ import annotations

import numpy as np

from fetchbench_ms.planning.checker import CollisionChecker
from fetchbench_ms.planning.ik import solve_ik
from fetchbench_ms.planning.robot import panda, robot_model
from fetchbench_ms.planning.world import CollisionWorld
from fetchbench_ms.robots import ROBOT_UIDS, SETUPS

def home(uid: str, seed: int = 0) -> np.ndarray:
    T_target = panda().tcp_pose(np.asarray(SETUPS["panda"].q_home)).numpy()[0]
    robot = robot_model(uid)
    checker = CollisionChecker(robot, CollisionWorld())
    for drop in range(0, 21):
        T = T_target.copy()
        T[2, 3] -= 0.01 * drop
        result = solve_ik(robot, T, checker=checker, n_seeds=256, rng=np.random.default_rng(seed), max_iters=300)
        if result.found:
            break
    else:
        raise SystemExit(f"{uid}: no IK solution within 0.2 m below the Panda's start TCP pose")
    span = robot.q_max - robot.q_min
    margin = np.minimum(result.q - robot.q_min, robot.q_max - result.q) / span
    return result.q[int(np.argmax(margin.min(axis=1)))]


def main() -> None:
    for uid in ROBOT_UIDS:
        if uid == "panda":
            continue
        q = home(uid)
        tcp = robot_model(uid).tcp_pose(q).numpy()[0, :3, 3]
        print(uid, "q_home =", "(" + ", ".join(f"{v:.4f}" for v in q) + ")", "TCP at", tcp.round(3).tolist())


if __name__ == "__main__":
    main()
