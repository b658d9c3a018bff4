"""World models of one FetchBench episode, in the robot base frame.

- ``mesh_world``: the oracle. Furniture parts from the task's SceneSpec (exact boxes,
  cylinders, capsules, convex pieces), the robot table and the floor as boxes, every
  object's convex parts at its current simulated pose (one group per object, the target
  in the group "target").
- ``pointcloud_world``: what the cameras saw. The segmented scene cloud (furniture and
  other objects; robot points are already labelled apart) as a 5 mm distance field, the
  target's points as their own group "target". The robot table and floor are not assumed
  known: they are in the cloud where the cameras see them.
"""
from __future__ import annotations

import numpy as np

from .world import (CollisionWorld, PointCloudField, box_set, convex_set_from_parts, obstacle_sets_from_parts,
                    pose_matrix)

FLOOR_THICKNESS = 0.1  # m: a slab under z = 0 stands for the floor


def _raw_pose_matrix(raw) -> np.ndarray:
    raw = np.asarray(raw, dtype=float).reshape(7)
    return pose_matrix(raw[:3], raw[3:])


def T_world_base(env) -> np.ndarray:
    return _raw_pose_matrix(env.unwrapped.agent.robot.pose.raw_pose[0].cpu().numpy())


def object_poses_base(env) -> list[np.ndarray]:
    """Current T_base_object of every task object, in task order."""
    u = env.unwrapped
    T_base_world = np.linalg.inv(T_world_base(env))
    task = u.tasks[0]
    return [T_base_world @ _raw_pose_matrix(u.object_slots[k].pose.raw_pose[0].cpu().numpy())
            for k in range(len(task.objects))]


def mesh_world(env, pose_tolerance: float = 0.0) -> CollisionWorld:
    """The oracle world now; ``pose_tolerance`` > 0: see ``MeshWorldCache.sets``."""
    u = env.unwrapped
    return task_mesh_world(u.tasks[0], np.linalg.inv(T_world_base(env)), object_poses_base(env), pose_tolerance)


class MeshWorldCache:
    """The obstacle sets of one task's mesh worlds, reused while the task stays the same.

    The expert builds the oracle world at every try of a task and again after each grasp, and
    the building (convex hulls, their planes) is most of it: the furniture's sets depend only on
    the task and the base pose, an object's on its id and its pose. Entries are keyed by the
    exact bytes of those inputs, so a cached set is the one the same inputs build (the same
    worlds, the same plans: ``tests/test_demos.py``); an object that moved is built anew. The
    sets are never modified after they are built (the planner only queries them). A new task
    empties the cache, so it holds one task's sets at a time.

    ``pose_tolerance`` > 0 (the expert's ``SolveConfig.world_pose_tolerance``) also reuses an
    object's last set while its pose matrix is within that of the pose the set was built at
    (largest entry difference: metres of translation, about radians of rotation). After a grasp
    the objects the hand did not touch have moved by PhysX's float noise, and their sets are
    most of the world's building; the target and anything pushed are built anew."""

    def __init__(self, max_objects: int = 256):
        self.max_objects = max_objects
        self.task_key: tuple | None = None
        self.T_base_world: np.ndarray | None = None
        self.scene: list = []
        self.objects: dict = {}
        self.last: dict = {}  # object slot -> (object id, pose, set) of its last set
        self.hits = self.misses = 0

    def sets(self, task, T_base_world: np.ndarray, T_base_objects: list[np.ndarray],
             pose_tolerance: float = 0.0) -> tuple[list, list]:
        from ..objects.loading import load_object

        T_base_world = np.asarray(T_base_world, dtype=float)
        key = (task.to_json(), T_base_world.tobytes())
        # The robot's base is fixed, yet PhysX reports its pose with float32 noise once the
        # arm has moved: within the tolerance it is the same base.
        near = (pose_tolerance > 0 and self.task_key is not None and key[0] == self.task_key[0]
                and np.abs(T_base_world - self.T_base_world).max() <= pose_tolerance)
        if key != self.task_key and not near:
            self.task_key, self.T_base_world, self.objects, self.last = key, T_base_world, {}, {}
            self.scene = _scene_sets(task, T_base_world)
            self.misses += 1
        else:
            self.hits += 1
        objects = []
        for k, (placement, T) in enumerate(zip(task.objects, T_base_objects)):
            T = np.asarray(T, dtype=float)
            last = self.last.get(k)
            if (pose_tolerance > 0 and last is not None and last[0] == placement.object_id
                    and np.abs(T - last[1]).max() <= pose_tolerance):
                objects.append(last[2])
                continue
            object_key = (placement.object_id, T.tobytes())
            if object_key not in self.objects:
                if len(self.objects) >= self.max_objects:
                    self.objects.pop(next(iter(self.objects)))  # the oldest
                self.objects[object_key] = convex_set_from_parts(load_object(placement.object_id).convex_parts, T)
            self.last[k] = (placement.object_id, T, self.objects[object_key])
            objects.append(self.objects[object_key])
        return self.scene, objects


#: The process's cache (one env a process: the demo generator's workers, the eval's).
#: ``FETCHBENCH_MESH_WORLD_CACHE=0`` builds every world from scratch (to measure the cache).
MESH_WORLD_CACHE = MeshWorldCache()


def _scene_sets(task, T_base_world: np.ndarray) -> list:
    """The furniture's obstacle sets, then the robot table and the floor as boxes (base frame)."""
    sets = list(obstacle_sets_from_parts(task.scene().parts, T_base_world))
    T_table = T_base_world @ pose_matrix(task.robot_table_center, task.robot_base_quat_wxyz)
    T_floor = T_base_world @ pose_matrix([0.0, 0.0, -FLOOR_THICKNESS / 2])
    sets.append(box_set(np.stack([T_table, T_floor]), [task.robot_table_size, [20.0, 20.0, FLOOR_THICKNESS]]))
    return sets


def task_mesh_world(task, T_base_world: np.ndarray, T_base_objects: list[np.ndarray],
                    pose_tolerance: float = 0.0) -> CollisionWorld:
    """The oracle world of ``task`` in the base frame, objects at ``T_base_objects`` (task
    order): furniture parts, robot table, floor, each object's convex parts. ``pose_tolerance``:
    ``MeshWorldCache.sets`` (with the cache on)."""
    import os

    from ..objects.loading import load_object

    if os.environ.get("FETCHBENCH_MESH_WORLD_CACHE", "1") != "0":
        scene, objects = MESH_WORLD_CACHE.sets(task, T_base_world, T_base_objects, pose_tolerance)
    else:
        scene = _scene_sets(task, np.asarray(T_base_world, dtype=float))
        objects = [convex_set_from_parts(load_object(p.object_id).convex_parts, np.asarray(T, dtype=float))
                   for p, T in zip(task.objects, T_base_objects)]
    world = CollisionWorld()
    for obstacle_set in scene:
        world.add("scene", obstacle_set)
    for k, obstacle_set in enumerate(objects):
        world.add("target" if k == task.target_index else f"object:{k}", obstacle_set)
    return world


def remove_robot_points(points_base: np.ndarray, q_full: np.ndarray, clearance: float = 0.01, robot=None) -> np.ndarray:
    """Points outside the robot's collision spheres (grown by ``clearance``) at ``q_full``
    (7 arm joints + finger opening). Segmentation already labels the robot, but pixels on
    its silhouette can carry a neighbour's label; left in, they put the robot's own start
    configuration in collision."""
    from .robot import panda

    robot = panda() if robot is None else robot
    centers = robot.sphere_centers(np.asarray(q_full[:7])[None], finger=float(q_full[7]))[0].numpy()
    radii = robot.spheres.radii + clearance
    points_base = np.asarray(points_base, dtype=float).reshape(-1, 3)
    inside = np.zeros(len(points_base), dtype=bool)
    for c, r in zip(centers, radii):
        inside |= np.einsum("ij,ij->i", points_base - c, points_base - c) < r * r
    return points_base[~inside]


def pointcloud_world(clouds, q_full: np.ndarray | None = None, voxel: float = 0.005, robot=None) -> CollisionWorld:
    """``clouds``: ``fetchbench_ms.envs.FetchClouds`` (base frame); ``q_full``: the robot's
    configuration when they were taken (its own points are then removed)."""
    scene = clouds.scene if q_full is None else remove_robot_points(clouds.scene, q_full, robot=robot)
    world = CollisionWorld()
    world.add("scene", PointCloudField(scene, voxel))
    world.add("target", PointCloudField(clouds.target, voxel))
    return world
