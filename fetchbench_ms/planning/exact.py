"""Exact collision checks with python-fcl: the robot's own collision meshes against
boxes, cylinders and convex meshes. Slow (one configuration at a time) and used to
validate what the sphere model plans: by tests, and by callers that want a final check.
"""
from __future__ import annotations

import weakref

import fcl
import numpy as np
import trimesh

from .robot import PandaModel


def _bvh(mesh: trimesh.Trimesh) -> fcl.BVHModel:
    model = fcl.BVHModel()
    model.beginModel(len(mesh.vertices), len(mesh.faces))
    model.addSubModel(np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int32))
    model.endModel()
    return model


def _transform(T: np.ndarray) -> fcl.Transform:
    return fcl.Transform(np.asarray(T[:3, :3], float), np.asarray(T[:3, 3], float))


class ExactWorld:
    """Obstacles as fcl objects in the base frame."""

    def __init__(self):
        self.objects: list[tuple[str, fcl.CollisionObject]] = []

    def add_box(self, name: str, T_base_box: np.ndarray, size) -> "ExactWorld":
        self.objects.append((name, fcl.CollisionObject(fcl.Box(*map(float, size)), _transform(T_base_box))))
        return self

    def add_mesh(self, name: str, mesh_base: trimesh.Trimesh) -> "ExactWorld":
        self.objects.append((name, fcl.CollisionObject(_bvh(mesh_base), fcl.Transform())))
        return self

    def add_parts(self, parts, T_base_scene: np.ndarray) -> "ExactWorld":
        """SceneSpec parts (boxes, cylinders, capsules, convex meshes)."""
        from .world import pose_matrix

        for part in parts:
            T = T_base_scene @ pose_matrix(part.position, part.quat_wxyz)
            if part.shape == "box":
                self.add_box(part.name, T, part.size)
            elif part.shape == "cylinder":
                self.objects.append((part.name, fcl.CollisionObject(fcl.Cylinder(*part.size), _transform(T))))
            elif part.shape == "capsule":
                self.objects.append((part.name, fcl.CollisionObject(fcl.Capsule(*part.size), _transform(T))))
            else:
                hull = trimesh.Trimesh(np.asarray(part.mesh_vertices)).convex_hull
                self.add_mesh(part.name, hull.apply_transform(T))
        return self


#: Each robot model's link BVHs, built once: checkers are made per planning call, and the
#: same (immutable) geometry serves every collision object posed from it.
_LINK_GEOMETRY: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


class ExactRobot:
    """The Panda's URDF collision meshes as fcl objects, posed by the planner's FK."""

    def __init__(self, robot: PandaModel, links: tuple[str, ...] | None = None):
        self.robot = robot
        self.links = links = robot.world_links if links is None else links
        geometry = _LINK_GEOMETRY.setdefault(robot, {})
        for l in links:
            if l not in geometry:
                geometry[l] = _bvh(robot.collision_meshes[l])
        self.objects = {l: fcl.CollisionObject(geometry[l], fcl.Transform()) for l in links}

    def pose(self, q, finger: float) -> None:
        poses = self.robot.link_poses(np.asarray(q, float).reshape(1, 7), finger)
        for l, obj in self.objects.items():
            obj.setTransform(_transform(poses[l][0].numpy()))

    def set_link_pose(self, link: str, T_base_link: np.ndarray) -> None:
        self.objects[link].setTransform(_transform(T_base_link))

    def world_collisions(self, q, world: ExactWorld, finger: float = 0.04) -> list[tuple[str, str]]:
        """(link, obstacle) pairs in contact at ``q``."""
        self.pose(q, finger)
        hits = []
        for l, obj in self.objects.items():
            for name, obstacle in world.objects:
                if fcl.collide(obj, obstacle, fcl.CollisionRequest(), fcl.CollisionResult()):
                    hits.append((l, name))
        return hits

    def link_pair_collides(self, a: str, b: str) -> bool:
        return bool(fcl.collide(self.objects[a], self.objects[b], fcl.CollisionRequest(), fcl.CollisionResult()))
