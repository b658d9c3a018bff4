"""Hand-made box worlds in the robot base frame, for tests and benchmarks of the planner
before (and independently of) the procedural scenes: a robot table and a three-board
shelf with sides and a back, standing in front of the robot."""
from __future__ import annotations

import numpy as np

from .exact import ExactWorld
from .world import CollisionWorld, box_set, pose_matrix


def shelf_boxes(x_front: float = 0.55, depth: float = 0.32, width: float = 0.8,
                board_z=(0.0, 0.3, 0.6), board: float = 0.02) -> list[tuple[str, np.ndarray, tuple]]:
    """(name, T_base_box, full size) of the robot table and a shelf; z is relative to the base."""
    xc = x_front + depth / 2
    height = board_z[-1] - board_z[0] + board
    zc = (board_z[-1] + board_z[0]) / 2
    boxes = [("robot_table", pose_matrix([-0.1, 0.0, -0.06]), (0.5, 0.7, 0.1))]
    boxes += [(f"board{i}", pose_matrix([xc, 0.0, z]), (depth, width, board)) for i, z in enumerate(board_z)]
    boxes += [(f"side{i}", pose_matrix([xc, s * (width / 2 + board / 2), zc]), (depth, board, height))
              for i, s in enumerate((-1, 1))]
    boxes.append(("back", pose_matrix([x_front + depth + board / 2, 0.0, zc]), (board, width + 2 * board, height)))
    return boxes


def shelf_worlds(**kwargs) -> tuple[CollisionWorld, ExactWorld]:
    """The shelf as a sphere-query world and as an exact fcl world."""
    boxes = shelf_boxes(**kwargs)
    world = CollisionWorld()
    world.add("scene", box_set(np.stack([b[1] for b in boxes]), [b[2] for b in boxes]))
    exact = ExactWorld()
    for name, T, size in boxes:
        exact.add_box(name, T, size)
    return world, exact


def hand_pose(position, approach=(1.0, 0.0, 0.0), closing=(0.0, 1.0, 0.0)) -> np.ndarray:
    """T_base_tcp with the hand's z axis along ``approach`` and fingers closing along ``closing``."""
    z = np.asarray(approach, float) / np.linalg.norm(approach)
    y = np.asarray(closing, float) - np.dot(closing, z) * z
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([np.cross(y, z), y, z])
    T[:3, 3] = position
    return T
