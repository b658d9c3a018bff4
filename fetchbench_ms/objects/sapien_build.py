"""Build an ``ObjectAsset`` into SAPIEN as one dynamic body (convex parts as shapes).

Works with a plain ``sapien.Scene`` and with ManiSkill scenes (same builder methods).
Convex parts reach SAPIEN as files through the content-addressed mesh cache, since
its builders take meshes only as files.
"""
from __future__ import annotations

import math

import numpy as np
import sapien
import trimesh

from ..utils.mesh_cache import mesh_file
from ..utils.sapien_device import new_scene
from .asset import ObjectAsset

#: Material defaults: the middle of FetchBench's per-object randomisation ranges.
DEFAULT_DENSITY = 250.0
DEFAULT_FRICTION = 0.9


def add_object_shapes(builder, asset: ObjectAsset, density: float = DEFAULT_DENSITY, physx_material=None, with_visual: bool = True) -> None:
    """Add one convex collision shape per part (and the visual mesh) to ``builder``."""
    if physx_material is None:
        physx_material = sapien.physx.PhysxMaterial(DEFAULT_FRICTION, DEFAULT_FRICTION, 0.0)
    for part in asset.convex_parts:
        builder.add_convex_collision_from_file(mesh_file(part), material=physx_material, density=density)
    if with_visual:
        rgba = list(asset.rgba) if asset.rgba is not None else [0.65, 0.6, 0.55, 1.0]
        builder.add_visual_from_file(mesh_file(asset.visual_mesh), material=sapien.render.RenderMaterial(base_color=rgba))


def build_object_actor(scene, asset: ObjectAsset, pose: sapien.Pose | None = None, name: str | None = None, **kwargs):
    """A dynamic actor of ``asset`` at ``pose`` (object frame -> world)."""
    builder = scene.create_actor_builder()
    add_object_shapes(builder, asset, **kwargs)
    if hasattr(builder, "initial_pose"):  # ManiSkill builders warn without one
        builder.initial_pose = pose or sapien.Pose()
    actor = builder.build(name=name or asset.object_id)
    if pose is not None and hasattr(actor, "set_pose"):
        actor.set_pose(pose)
    return actor


def drop_on_plane(asset: ObjectAsset, pose_index: int = 0, drop_height: float = 0.005, seconds: float = 1.5, timestep: float = 1 / 120):
    """Drop ``asset`` in stable pose ``pose_index`` from ``drop_height`` onto a plane and
    simulate; return (actor, tilt in degrees between the start and end z axes, end
    height minus resting height in m). A stable pose leaves both small."""
    scene = new_scene()
    scene.set_timestep(timestep)
    scene.add_ground(0.0)
    T_start = asset.stable_poses[pose_index].copy()
    T_start[2, 3] += drop_height
    q_start = trimesh.transformations.quaternion_from_matrix(T_start)  # wxyz
    actor = build_object_actor(scene, asset, pose=sapien.Pose(T_start[:3, 3], q_start))
    for _ in range(int(round(seconds / timestep))):
        scene.step()
    T_end = actor.get_pose().to_transformation_matrix()
    tilt = math.degrees(math.acos(float(np.clip(T_start[:3, 2] @ T_end[:3, 2], -1.0, 1.0))))
    return actor, tilt, float(T_end[2, 3] - (T_start[2, 3] - drop_height))
