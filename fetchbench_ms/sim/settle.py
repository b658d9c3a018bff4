"""Settle freshly placed objects in physics so a task starts at rest.

Used by the task sampler: the furniture, the robot table and the objects are built
into a private physics-only SAPIEN scene with the env's physics settings, simulated
until every object is still, and the resting poses are returned. Objects that leave
their support (fall more than 3 cm below it) or are still moving after the time limit
are removed and the rest settled again from their placed poses, so the result does
not depend on objects that are gone. A fresh scene each time keeps it deterministic.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import sapien

from ..scenes.sapien_build import add_scene_parts
from ..utils.canonical import canonical_lengths, canonical_quat
from .bodies import SIM_FREQ, add_object_shapes, apply_physx_config, box_half_size, default_sim_config

SETTLE_SECONDS = 2.0  # at most
CHECK_EVERY = 0.25  # s
REST_LINEAR = 0.005  # m/s: at rest below this
REST_ANGULAR = 0.05  # rad/s
FALL_DEPTH = 0.03  # m below its support height: the object left its support


def _build(scene_spec, placements, table_center, table_size):
    apply_physx_config(default_sim_config())
    scene = sapien.Scene(systems=[sapien.physx.PhysxCpuSystem()])
    scene.set_timestep(1.0 / SIM_FREQ)
    builder = scene.create_actor_builder()
    add_scene_parts(builder, scene_spec, with_visual=False)
    builder.add_plane_collision(sapien.Pose(q=[0.7071068, 0, -0.7071068, 0]))  # the floor, z = 0
    builder.add_box_collision(sapien.Pose(p=list(table_center)), half_size=box_half_size(table_size))
    builder.build_static(name="static")
    bodies = []
    for k, placement in enumerate(placements):
        builder = scene.create_actor_builder()
        add_object_shapes(builder, placement.object_id, placement, with_visual=False)
        builder.set_initial_pose(sapien.Pose(p=list(placement.position), q=list(placement.quat_wxyz)))
        entity = builder.build(name=f"object_{k}")
        bodies.append(entity.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent))
    return scene, bodies


def _simulate(scene, bodies):
    steps = int(round(CHECK_EVERY * SIM_FREQ))
    for _ in range(int(round(SETTLE_SECONDS / CHECK_EVERY))):
        for _ in range(steps):
            scene.step()
        moving = [
            np.linalg.norm(b.linear_velocity) > REST_LINEAR or np.linalg.norm(b.angular_velocity) > REST_ANGULAR
            for b in bodies
        ]
        if not any(moving):
            break
    return moving


def settle_placements(scene_spec, placements, table_center, table_size, rounds: int = 3):
    """(settled placements, report dict). Dropped objects are left out of the result.

    Poses go in and come out on the grids of ``utils.canonical``: contact dynamics turn a
    last-bit difference of a start pose into a different resting yaw (a lying jar spins),
    so the simulation must start from the same bits on every machine."""
    placements = [p.canonical() for p in placements]
    support_height = {s.name: s.height for s in scene_spec.support_surfaces}
    dropped = 0
    for _ in range(rounds):
        scene, bodies = _build(scene_spec, placements, table_center, table_size)
        moving = _simulate(scene, bodies)
        poses = [b.entity_pose for b in bodies]
        # Its centre of mass below its support surface: the object fell off.
        fell = [
            (pose * b.cmass_local_pose).p[2] < support_height[p.support_surface]
            for pose, b, p in zip(poses, bodies, placements)
        ]
        keep = [not (m or f) for m, f in zip(moving, fell)]
        if all(keep):
            settled = []
            for placement, pose in zip(placements, poses):
                settled.append(replace(placement, position=canonical_lengths(pose.p), quat_wxyz=canonical_quat(pose.q)))
            return settled, {"settle_dropped": dropped}
        dropped += len(keep) - sum(keep)
        placements = [p for p, k in zip(placements, keep) if k]
        if not placements:
            break
    return [], {"settle_dropped": dropped}
