"""Builds the content of FetchBench tasks into a ManiSkill scene, one task per sub-scene.

The builder is written to ManiSkill's batched API so the same code serves the CPU
simulator (one sub-scene) and the GPU simulator (``num_envs`` sub-scenes, each with a
different procedural scene and different objects):

- object slots: every sub-scene gets the same number of dynamic object actors (the
  env's object count, or the largest among the tasks if larger; shorter tasks are padded
  with small parked placeholder boxes without visuals), built per sub-scene with ``set_scene_idxs`` and merged across
  sub-scenes into one ``Actor`` per slot (``object_0`` ... ``object_{S-1}``), so state
  names are stable and every state leaf has batch size ``num_envs``;
- the target: a second merged view over the target slot of each sub-scene;
- camera mounts: one kinematic actor per camera and sub-scene (merged), whose pose is
  set per episode, so each sub-scene has its own camera poses;
- furniture, robot table and floor: static, per sub-scene, built after the dynamic
  actors so the segmentation ids of the robot and the object slots are the same in
  every sub-scene.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import sapien
import torch
from mani_skill.utils.building.ground import build_ground
from mani_skill.utils.structs.actor import Actor
from mani_skill.utils.structs.pose import Pose

from ..scenes.sapien_build import add_scene_parts
from ..sim.bodies import add_object_shapes, box_half_size
from ..tasks.spec import TaskSpec

PLACEHOLDER_HALF_SIZE = 0.01  # m
#: Points sampled on the target's collision surface, for the reward's TCP-to-surface
#: distance (a 10 cm object gets about one point per 1.5 cm^2).
TARGET_SURFACE_POINTS = 512
ROBOT_TABLE_RGBA = (0.35, 0.35, 0.38, 1.0)


def placeholder_position(slot: int) -> list[float]:
    """Where an unused object slot is parked: on the floor behind the robot and its table,
    out of the cameras' views, and within 2.5 m of the origin (on GPU, sub-scenes are
    5 m apart in one physics scene: anything further would reach a neighbour)."""
    return [-1.8, -1.8 + 0.05 * slot, PLACEHOLDER_HALF_SIZE]


@dataclass
class BuiltTasks:
    """What the builder made, as batched tensors ([num_envs, num_slots, ...])."""

    slots: list[Actor]  # merged actor per slot
    target: Actor  # merged view of each sub-scene's target
    camera_mounts: dict[str, Actor]  # "left" / "right"
    furniture: list[Actor]  # per sub-scene (static)
    robot_tables: list[Actor]  # per sub-scene (static)
    initial_pose: torch.Tensor  # [B, S, 7] raw poses (p, q wxyz) the episode starts from
    com_local: torch.Tensor  # [B, S, 3] centre of mass in each body's frame
    valid: torch.Tensor  # [B, S] bool: the slot holds a task object (not a placeholder)
    target_index: torch.Tensor  # [B] long
    target_radius: torch.Tensor  # [B] largest distance from the target's centre of mass to its surface
    target_surface: torch.Tensor  # [B, P, 3] points on the target's collision surface, body frame
    camera_pose: dict[str, torch.Tensor]  # "left"/"right" -> [B, 7]
    base_pose: torch.Tensor  # [B, 7]


def build_tasks(env, tasks: list[TaskSpec], scene_specs, min_slots: int = 0, with_visual: bool = True) -> BuiltTasks:
    """Build ``tasks[i]`` into sub-scene i. ``min_slots`` pads the object slots to a fixed
    count, so state observations keep their size from task to task. ``with_visual=False``
    leaves out the objects' and furniture's render meshes (nothing will render them)."""
    scene = env.scene
    with_visual = with_visual and scene.can_render()
    num_envs = len(tasks)
    num_slots = max([min_slots] + [len(t.objects) for t in tasks])
    device = env.device

    initial_pose = np.zeros((num_envs, num_slots, 7))
    valid = np.zeros((num_envs, num_slots), dtype=bool)
    com_local = np.zeros((num_envs, num_slots, 3))
    per_slot: list[list[Actor]] = [[] for _ in range(num_slots)]
    for k in range(num_slots):
        for i, task in enumerate(tasks):
            builder = scene.create_actor_builder()
            if k < len(task.objects):
                placement = task.objects[k]
                add_object_shapes(builder, placement.object_id, placement, with_visual=with_visual)
                pose = sapien.Pose(p=list(placement.position), q=list(placement.quat_wxyz))
                valid[i, k] = True
            else:
                builder.add_box_collision(half_size=[PLACEHOLDER_HALF_SIZE] * 3, density=200.0)
                pose = sapien.Pose(p=placeholder_position(k))
            builder.initial_pose = pose  # always set: overlapping start poses break GPU set-up
            builder.set_scene_idxs([i])
            actor = builder.build(name=f"object_{k}-env{i}")
            env.remove_from_state_dict_registry(actor)
            per_slot[k].append(actor)
            initial_pose[i, k, :3] = pose.p
            initial_pose[i, k, 3:] = pose.q
            body = actor._objs[0].find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
            com_local[i, k] = body.cmass_local_pose.p
    slots = []
    for k in range(num_slots):
        merged = Actor.merge(per_slot[k], name=f"object_{k}")
        env.add_to_state_dict_registry(merged)
        slots.append(merged)
    target = Actor.merge([per_slot[t.target_index][i] for i, t in enumerate(tasks)], name="target")
    target_radius = [
        float(np.linalg.norm(_collision_vertices(per_slot[t.target_index][i]) - com_local[i, t.target_index],
                             axis=1).max())
        for i, t in enumerate(tasks)
    ]

    target_surface = [_surface_points(per_slot[t.target_index][i], TARGET_SURFACE_POINTS) for i, t in enumerate(tasks)]

    camera_mounts, camera_pose = {}, {}
    for side in ("left", "right"):
        mounts = []
        poses = np.zeros((num_envs, 7))
        for i, task in enumerate(tasks):
            cam = task.camera_left if side == "left" else task.camera_right
            builder = scene.create_actor_builder()
            builder.initial_pose = sapien.Pose(p=list(cam.position), q=list(cam.quat_wxyz))
            builder.set_scene_idxs([i])
            mount = builder.build_kinematic(name=f"camera_mount_{side}-env{i}")
            env.remove_from_state_dict_registry(mount)
            mounts.append(mount)
            poses[i, :3], poses[i, 3:] = cam.position, cam.quat_wxyz
        camera_mounts[side] = Actor.merge(mounts, name=f"camera_mount_{side}")
        env.add_to_state_dict_registry(camera_mounts[side])
        camera_pose[side] = torch.tensor(poses, dtype=torch.float32, device=device)

    furniture, robot_tables = [], []
    for i, (task, spec) in enumerate(zip(tasks, scene_specs)):
        builder = scene.create_actor_builder()
        add_scene_parts(builder, spec, with_visual=with_visual)
        builder.initial_pose = sapien.Pose()
        builder.set_scene_idxs([i])
        furniture.append(builder.build_static(name=f"furniture-env{i}"))
        builder = scene.create_actor_builder()
        half = box_half_size(task.robot_table_size)
        builder.add_box_collision(half_size=half)
        if with_visual:
            builder.add_box_visual(half_size=half, material=_robot_table_material())
        builder.initial_pose = sapien.Pose(p=list(task.robot_table_center), q=list(task.robot_base_quat_wxyz))
        builder.set_scene_idxs([i])
        robot_tables.append(builder.build_static(name=f"robot_table-env{i}"))
    build_ground(scene, floor_width=20)

    base_pose = torch.tensor(
        [list(t.robot_base_position) + list(t.robot_base_quat_wxyz) for t in tasks], dtype=torch.float32, device=device
    )
    return BuiltTasks(
        slots=slots,
        target=target,
        camera_mounts=camera_mounts,
        furniture=furniture,
        robot_tables=robot_tables,
        initial_pose=torch.tensor(initial_pose, dtype=torch.float32, device=device),
        com_local=torch.tensor(com_local, dtype=torch.float32, device=device),
        valid=torch.tensor(valid, device=device),
        target_index=torch.tensor([t.target_index for t in tasks], dtype=torch.long, device=device),
        target_radius=torch.tensor(target_radius, dtype=torch.float32, device=device),
        target_surface=torch.tensor(np.stack(target_surface), dtype=torch.float32, device=device),
        camera_pose=camera_pose,
        base_pose=base_pose,
    )


@functools.lru_cache(maxsize=None)
def _robot_table_material():
    # Made once: a RenderMaterial costs ~40 ms on a CPU (lavapipe) renderer.
    return sapien.render.RenderMaterial(base_color=list(ROBOT_TABLE_RGBA), roughness=0.8)


def _collision_vertices(actor: Actor) -> np.ndarray:
    """(N, 3) vertices of an actor's convex collision shapes, in its body frame."""
    body = actor._objs[0].find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
    points = []
    for shape in body.collision_shapes:
        vertices = shape.get_vertices() * shape.scale
        points.append(vertices @ shape.local_pose.to_transformation_matrix()[:3, :3].T + shape.local_pose.p)
    return np.concatenate(points)


def _surface_points(actor: Actor, n: int) -> np.ndarray:
    """(n, 3) points on an actor's convex collision shapes, body frame: their vertices,
    then area-weighted samples of their triangles (seeded by the shapes alone, so the
    same object gives the same points)."""
    body = actor._objs[0].find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
    vertices, triangles = [], []
    for shape in body.collision_shapes:
        local = shape.get_vertices() * shape.scale
        local = local @ shape.local_pose.to_transformation_matrix()[:3, :3].T + shape.local_pose.p
        triangles.append(local[shape.get_triangles()])
        vertices.append(local)
    vertices, triangles = np.concatenate(vertices), np.concatenate(triangles)  # (V, 3), (T, 3, 3)
    if len(vertices) >= n:
        return vertices[np.linspace(0, len(vertices) - 1, n).astype(int)]
    area = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
    rng = np.random.default_rng(len(vertices))
    picked = rng.choice(len(triangles), size=n - len(vertices), p=area / area.sum())
    u, v = rng.random((2, len(picked), 1))
    flip = (u + v) > 1  # fold the unit square onto the triangle
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    tri = triangles[picked]
    samples = tri[:, 0] + u * (tri[:, 1] - tri[:, 0]) + v * (tri[:, 2] - tri[:, 0])
    return np.concatenate([vertices, samples])


def initialize_tasks(built: BuiltTasks, env_idx: torch.Tensor) -> None:
    """Put every object slot and camera mount of the sub-scenes ``env_idx`` at its episode start."""
    for k, slot in enumerate(built.slots):
        slot.set_pose(Pose.create(built.initial_pose[env_idx, k]))
    for side, mount in built.camera_mounts.items():
        mount.set_pose(Pose.create(built.camera_pose[side][env_idx]))
