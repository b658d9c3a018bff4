"""Antipodal grasp candidates for the Franka hand on one object.

A candidate pairs a surface point ``p`` with the point ``q`` where a ray from ``p``,
sent into the object inside the friction cone about the inward normal, leaves the
object again. The pair is antipodal when the exit normal also lies inside the cone about
the ray. The hand is centred on the pair with its closing (y) axis along ``p -> q``,
rolled at random about that axis and set at a random depth, and kept only if the open
hand does not touch the object's convex collision parts (python-fcl through trimesh's
CollisionManager). Physics decides later which candidates actually hold.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from ..objects.asset import ObjectAsset
from .hand import MAX_OPENING, TCP_OFFSET, open_hand_mesh


@dataclass(frozen=True)
class SamplerConfig:
    #: Half-angle of the friction cone, rad. Conservative against atan(0.6) = 31 deg, the
    #: lowest object friction of the benchmark.
    cone_half_angle: float = np.deg2rad(15.0)
    #: Widest grasp accepted: the opening minus 5 mm so the open fingers clear the surface.
    max_width: float = MAX_OPENING - 0.005
    #: Narrowest grasp: thinner than this the fingers end fully closed, which counts as a miss.
    min_width: float = 0.003
    #: TCP placed this far beyond / short of the contact midpoint along the approach, m.
    #: The finger pads span 0.094..0.113 m from the hand, the TCP is at 0.1034.
    depth_range: tuple[float, float] = (-0.008, 0.008)
    #: Surface points drawn per wanted candidate (most rays fail the cone or width test).
    oversample: int = 6
    #: Rounds of drawing before giving up on reaching the wanted number.
    max_rounds: int = 4


@dataclass(frozen=True)
class Candidates:
    """Collision-free antipodal hand poses on one object, all in the object frame."""

    T_object_hand: np.ndarray  # (N, 4, 4) panda_hand poses
    width: np.ndarray  # (N,) distance between the two contact points, m
    contacts: np.ndarray  # (N, 2, 3) contact points p (right finger, -y) and q (left finger, +y)

    def __len__(self) -> int:
        return len(self.width)


def _perpendicular_basis(axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each row of ``axes`` and to each other."""
    helper = np.where(np.abs(axes[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(axes, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(axes, u)


def _directions_in_cone(axes: np.ndarray, half_angle: float, rng: np.random.Generator) -> np.ndarray:
    """Unit vectors uniform (by solid angle) in the cone of ``half_angle`` about each axis."""
    cos_theta = rng.uniform(np.cos(half_angle), 1.0, size=len(axes))
    sin_theta = np.sqrt(1.0 - cos_theta**2)
    phi = rng.uniform(0.0, 2 * np.pi, size=len(axes))
    u, v = _perpendicular_basis(axes)
    return cos_theta[:, None] * axes + sin_theta[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)


def hand_poses(centers: np.ndarray, closing: np.ndarray, roll: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """``panda_hand`` poses (N, 4, 4) whose TCP is ``depth`` beyond ``centers`` along the approach,
    closing along ``closing`` (hand y) and rolled by ``roll`` about it."""
    u, v = _perpendicular_basis(closing)
    approach = np.cos(roll)[:, None] * u + np.sin(roll)[:, None] * v
    T = np.tile(np.eye(4), (len(centers), 1, 1))
    T[:, :3, 0] = np.cross(closing, approach)
    T[:, :3, 1] = closing
    T[:, :3, 2] = approach
    T[:, :3, 3] = centers + (depth - TCP_OFFSET)[:, None] * approach
    return T


def object_collision_manager(asset: ObjectAsset) -> trimesh.collision.CollisionManager:
    manager = trimesh.collision.CollisionManager()
    for i, part in enumerate(asset.convex_parts):
        manager.add_object(f"part{i}", part)
    return manager


def sample_candidates(asset: ObjectAsset, n: int, rng: np.random.Generator, config: SamplerConfig = SamplerConfig()) -> Candidates:
    """Up to ``n`` collision-free antipodal candidates on ``asset`` (fewer if the object has few)."""
    mesh = asset.visual_mesh
    manager = object_collision_manager(asset)
    # The hand's BVH is built once and moved per pose (rebuilding it per query dominates otherwise).
    hand = trimesh.collision.CollisionManager()
    hand.add_object("hand", open_hand_mesh())
    cos_cone = np.cos(config.cone_half_angle)
    kept_T, kept_w, kept_c = [], [], []
    for _ in range(config.max_rounds):
        count = n * config.oversample
        points, faces = trimesh.sample.sample_surface(mesh, count, seed=rng)
        inward = -mesh.face_normals[faces]
        closing = _directions_in_cone(inward, config.cone_half_angle, rng)
        # Start just inside the surface so the ray does not hit its own face.
        origins = points + 1e-4 * inward
        hit_points, ray_index, hit_faces = mesh.ray.intersects_location(origins, closing, multiple_hits=False)
        if len(ray_index) == 0:
            continue
        p, q = points[ray_index], hit_points
        # The closing axis is the line through both contacts (the ray started 0.1 mm inside).
        width = np.linalg.norm(q - p, axis=1)
        d = (q - p) / np.maximum(width, 1e-12)[:, None]
        in_cone_p = np.einsum("ij,ij->i", inward[ray_index], d) >= cos_cone
        in_cone_q = np.einsum("ij,ij->i", mesh.face_normals[hit_faces], d) >= cos_cone
        ok = in_cone_p & in_cone_q & (width >= config.min_width) & (width <= config.max_width)
        p, q, d, width = p[ok], q[ok], d[ok], width[ok]
        # Sort by ray index so the result does not depend on the ray engine's output order.
        order = np.argsort(ray_index[ok], kind="stable")
        p, q, d, width = p[order], q[order], d[order], width[order]
        roll = rng.uniform(0.0, 2 * np.pi, size=len(p))
        depth = rng.uniform(*config.depth_range, size=len(p))
        T = hand_poses((p + q) / 2, d, roll, depth)
        for i in range(len(T)):
            hand.set_transform("hand", T[i])
            if manager.in_collision_other(hand):
                continue
            kept_T.append(T[i])
            kept_w.append(width[i])
            kept_c.append((p[i], q[i]))
            if len(kept_T) == n:
                break
        if len(kept_T) == n:
            break
    return Candidates(
        T_object_hand=np.array(kept_T, dtype=float).reshape(-1, 4, 4),
        width=np.array(kept_w, dtype=float),
        contacts=np.array(kept_c, dtype=float).reshape(-1, 2, 3),
    )
