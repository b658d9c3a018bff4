"""Turn a ``SceneSpec`` into SAPIEN bodies.

Works with a plain ``sapien.Scene`` and with a ManiSkill scene (both hand out actor
builders with the same ``add_*`` methods), so tests, renders and the env share it.
The whole furniture is one static body, as in the original (one fixed scene actor).
"""
from __future__ import annotations

import functools

import numpy as np
import sapien
import trimesh

from ..utils.mesh_cache import mesh_file
from .spec import Part, SceneSpec

#: Friction of the furniture (the original's scene friction).
FURNITURE_FRICTION = 0.5

# SAPIEN's cylinders and capsules lie along their local x axis; ours along z. This
# rotation (-90 deg about y) takes x onto z.
_X_TO_Z = sapien.Pose(q=[np.cos(-np.pi / 4), 0.0, np.sin(-np.pi / 4), 0.0])


def part_pose(part: Part) -> sapien.Pose:
    return sapien.Pose(p=list(part.position), q=list(part.quat_wxyz))


@functools.lru_cache(maxsize=1024)
def _render_material(rgba: tuple, roughness: float, metallic: float):
    # Creating a RenderMaterial costs ~40 ms on a CPU (lavapipe) renderer; parts share few.
    return sapien.render.RenderMaterial(base_color=list(rgba), roughness=roughness, metallic=metallic)


def add_part(builder, part: Part, physx_material, with_visual: bool = True, rgba=None) -> None:
    """Add one part's collision (and visual) shape to an actor builder."""
    pose = part_pose(part)
    color = tuple(rgba if rgba is not None else part.material.rgba)
    render_material = (
        _render_material(color, part.material.roughness, part.material.metallic) if with_visual else None
    )
    if part.shape == "box":
        half = [s / 2 for s in part.size]
        builder.add_box_collision(pose=pose, half_size=half, material=physx_material)
        if with_visual:
            builder.add_box_visual(pose=pose, half_size=half, material=render_material)
    elif part.shape in ("cylinder", "capsule"):
        radius, length = part.size
        axis_pose = pose * _X_TO_Z
        if part.shape == "cylinder":
            builder.add_cylinder_collision(pose=axis_pose, radius=radius, half_length=length / 2, material=physx_material)
            if with_visual:
                builder.add_cylinder_visual(pose=axis_pose, radius=radius, half_length=length / 2, material=render_material)
        else:
            builder.add_capsule_collision(pose=axis_pose, radius=radius, half_length=length / 2, material=physx_material)
            if with_visual:
                builder.add_capsule_visual(pose=axis_pose, radius=radius, half_length=length / 2, material=render_material)
    elif part.shape == "convex_mesh":
        hull = trimesh.Trimesh(np.asarray(part.mesh_vertices)).convex_hull
        path = mesh_file(hull)
        builder.add_convex_collision_from_file(path, pose=pose, material=physx_material)
        if with_visual:
            builder.add_visual_from_file(path, pose=pose, material=render_material)
    else:  # Part.__post_init__ already rejects other shapes
        raise ValueError(f"unknown part shape {part.shape!r}")


def add_scene_parts(builder, spec: SceneSpec, physx_material=None, with_visual: bool = True) -> None:
    """Add every part of ``spec`` to ``builder`` (one body holding all furniture)."""
    if physx_material is None:
        physx_material = sapien.physx.PhysxMaterial(FURNITURE_FRICTION, FURNITURE_FRICTION, 0.0)
    for part in spec.parts:
        add_part(builder, part, physx_material, with_visual=with_visual)


def build_static_scene(scene, spec: SceneSpec, name: str = "furniture"):
    """Build the furniture of ``spec`` into ``scene`` as one static body and return it."""
    builder = scene.create_actor_builder()
    add_scene_parts(builder, spec)
    if hasattr(builder, "initial_pose"):  # ManiSkill builders warn without one
        builder.initial_pose = sapien.Pose()
    return builder.build_static(name=name)
