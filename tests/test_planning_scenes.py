"""The planner on procedural furniture (SceneSpec parts), checked against exact geometry."""
import numpy as np
import pytest
import torch

from fetchbench_ms.planning.checker import CollisionChecker
from fetchbench_ms.planning.demo_worlds import hand_pose
from fetchbench_ms.planning.exact import ExactRobot, ExactWorld
from fetchbench_ms.planning.ik import solve_ik
from fetchbench_ms.planning.robot import Q_DEFAULT, panda
from fetchbench_ms.planning.rrt import densify, plan_rrtconnect
from fetchbench_ms.planning.world import CollisionWorld, box_set, obstacle_sets_from_parts, pose_matrix
from fetchbench_ms.scenes import generate


@pytest.fixture(scope="module")
def shelf_scene():
    torch.set_num_threads(1)
    spec = generate("LargeShelf", 3)
    region = spec.robot_region
    base = [np.mean(region.x_range), np.mean(region.y_range), np.mean(region.z_range)]
    T_base_scene = np.linalg.inv(pose_matrix(base))
    world = CollisionWorld()
    for s in obstacle_sets_from_parts(spec.parts, T_base_scene):
        world.add("scene", s)
    # The floor, as the pipeline adds it.
    floor = T_base_scene @ pose_matrix([0.0, 0.0, -0.05])
    world.add("scene", box_set(floor, [4.0, 4.0, 0.1]))
    exact = ExactWorld().add_parts(spec.parts, T_base_scene).add_box("floor", floor, (4.0, 4.0, 0.1))
    return spec, T_base_scene, world, exact


def test_sphere_world_is_conservative_against_exact_meshes(shelf_scene):
    spec, T_base_scene, world, exact = shelf_scene
    robot = panda()
    checker = CollisionChecker(robot, world)
    exact_robot = ExactRobot(robot)
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.q_min, robot.q_max, (300, 7))
    valid = checker.valid(q)
    assert 0.1 < valid.mean() < 0.9  # the sample has both kinds
    for qi in q[valid]:
        assert not exact_robot.world_collisions(qi, exact), qi


def test_plan_onto_a_procedural_shelf_is_collision_free(shelf_scene):
    spec, T_base_scene, world, exact = shelf_scene
    robot = panda()
    checker = CollisionChecker(robot, world)
    # The middle of the upper cell (RRTConnect solves it in ~2 s; the lower cell's goal is
    # a narrow passage where 10 s runs time out about one time in five).
    layer = next(s for s in spec.support_surfaces if s.name == "shelf_layer_2")
    cx, cy = layer.polygon.centroid.coords[0]
    target_scene = np.array([cx, cy, layer.height + 0.08, 1.0])
    target_base = (T_base_scene @ target_scene)[:3]
    goals = solve_ik(robot, hand_pose(target_base), checker=checker, q_seed=Q_DEFAULT, n_seeds=64)
    assert goals.found
    result = plan_rrtconnect(checker, Q_DEFAULT, goals.q[:4])
    assert result.success, result.status
    exact_robot = ExactRobot(robot)
    for q in densify(result.path, 0.01):
        assert not exact_robot.world_collisions(q, exact)
