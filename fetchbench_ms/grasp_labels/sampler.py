"""Antipodal grasp candidates for the Franka hand on one object.

Everything is computed on the object's convex collision parts, the shape that physics
simulates (the visual mesh may be an open scan). A candidate pairs a point ``p`` on the
surface of the union of parts with a point ``q`` where a ray from ``p``, sent into the
object inside the friction cone about the inward normal, leaves the union: the first
exit (one wall of a cup, a handle) or the last one within the hand's opening (across
the whole cup). The pair is antipodal when the exit normal also lies inside the cone about
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
    #: Share of rays whose far exit (a finger closing from outside the whole object) is used.
    far_exit_fraction: float = 0.5
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


class ConvexUnion:
    """The union of convex parts as half-space sets, for exact vectorised ray exits.

    Hand-written because trimesh's ray queries work on one triangle soup: on overlapping
    convex parts they stop at internal faces, and without embree they are slow. Clipping a
    ray against each part's planes is exact and fully vectorised.
    """

    def __init__(self, parts: tuple[trimesh.Trimesh, ...]):
        normals, offsets, owner = [], [], []
        for i, part in enumerate(parts):
            normals.append(part.face_normals)
            offsets.append(np.einsum("ij,ij->i", part.face_normals, part.triangles[:, 0]))
            owner.append(np.full(len(part.faces), i))
        self.normals = np.concatenate(normals)
        self.offsets = np.concatenate(offsets)
        self.owner = np.concatenate(owner)
        self.starts = np.concatenate([[0], np.cumsum([len(p.faces) for p in parts])[:-1]])
        self.n_parts = len(parts)

    def signed_distance_to_planes(self, points: np.ndarray) -> np.ndarray:
        """(N, P): max over each part's planes of n.x - b; < 0 strictly inside that part."""
        d = points @ self.normals.T - self.offsets
        return np.maximum.reduceat(d, self.starts, axis=1)

    def ray_exit(self, origins: np.ndarray, directions: np.ndarray, tol: float = 1e-6):
        """Where rays starting on or in the union leave it: (t, exit normal, valid)."""
        t_enter, t_exit, leaving = self._intervals(origins, directions, tol)
        # Walk the union of intervals from t = 0: extend while another part overlaps the end.
        t = np.zeros(len(origins))
        for _ in range(self.n_parts):
            reach = np.where((t_enter <= t[:, None] + tol) & (t_exit > t[:, None]), t_exit, -np.inf).max(axis=1)
            grown = np.maximum(t, reach)
            if np.array_equal(grown, t):
                break
            t = grown
        valid = t > tol
        exit_normal = self._exit_normals(t, t_enter, t_exit, leaving, tol)
        return t, exit_normal, valid

    def _intervals(self, origins, directions, tol):
        """Per ray and part, the parameter interval [t_enter, t_exit] inside the part (empty:
        enter = inf, exit = -inf), and per ray and plane the t where the ray leaves it."""
        num = self.offsets - origins @ self.normals.T  # (N, F): inside means t * den <= num
        den = directions @ self.normals.T
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = num / den
        leaving = np.where(den > 1e-12, ratio, np.inf)
        entering = np.where(den < -1e-12, ratio, -np.inf)
        parallel_outside = (np.abs(den) <= 1e-12) & (num < -tol)
        t_exit = np.minimum.reduceat(leaving, self.starts, axis=1)  # (N, P)
        t_enter = np.maximum.reduceat(entering, self.starts, axis=1)
        missed = np.logical_or.reduceat(parallel_outside, self.starts, axis=1) | (t_exit < t_enter)
        t_enter = np.where(missed, np.inf, t_enter)
        t_exit = np.where(missed, -np.inf, t_exit)
        return t_enter, t_exit, leaving

    def ray_last_exit(self, origins: np.ndarray, directions: np.ndarray, max_t: float, tol: float = 1e-6):
        """The farthest point within ``max_t`` where rays leave the union for good (nothing of the
        object follows before ``max_t``): the contact of a finger closing from outside,
        e.g. across a whole cup rather than one wall. Returns (t, exit normal, valid)."""
        t_enter, t_exit, leaving = self._intervals(origins, directions, tol)
        t = np.where((t_exit > tol) & (t_exit <= max_t), t_exit, -np.inf).max(axis=1)
        covered_after = ((t_enter <= t[:, None] + tol) & (t_exit > t[:, None] + tol)).any(axis=1)
        valid = np.isfinite(t) & (t > tol) & ~covered_after
        t = np.where(valid, t, 0.0)
        return t, self._exit_normals(t, t_enter, t_exit, leaving, tol), valid

    def _exit_normals(self, t, t_enter, t_exit, leaving, tol):
        """The exit face at ``t``: a plane crossed at t of a part whose interval ends at t."""
        ends_here = (t_enter <= t[:, None] + tol) & (np.abs(t_exit - t[:, None]) <= tol)
        part = np.argmax(ends_here, axis=1)
        gap = np.where(self.owner[None, :] == part[:, None], np.abs(leaving - t[:, None]), np.inf)
        return self.normals[np.argmin(gap, axis=1)]


def sample_union_surface(union: ConvexUnion, parts, count: int, rng: np.random.Generator):
    """Points on the union's outer surface (area-weighted) with outward normals."""
    soup = trimesh.util.concatenate(list(parts))
    points, faces = trimesh.sample.sample_surface(soup, count, seed=rng)
    normals = soup.face_normals[faces]
    owner = np.searchsorted(union.starts, faces, side="right") - 1
    depth = union.signed_distance_to_planes(points)
    depth[np.arange(len(points)), owner] = np.inf  # a point lies on its own part's boundary
    outer = depth.min(axis=1) > -1e-6  # not strictly inside any other part
    return points[outer], normals[outer]


def canonical_part(part: trimesh.Trimesh) -> trimesh.Trimesh:
    """The same convex part, triangulated and ordered canonically.

    Surface sampling walks triangles in order and places points from their corners, so
    the candidates would change whenever a hull routine lists or triangulates the same
    polytope differently; labels must be a function of the shape and the seed alone.
    Each planar facet is re-triangulated as a fan from its smallest corner, corners in
    angular order; vertices and triangles are then sorted."""
    vertices = np.round(np.asarray(part.vertices, dtype=np.float64), 9)
    # Facets: adjacent triangles on the same plane to 1e-9 (trimesh's ``facets`` also
    # merges nearly coplanar ones, which would flatten curved blades when re-triangulated).
    normals = part.face_normals
    offsets = np.einsum("ij,ij->i", normals, part.triangles[:, 0])
    a, b = part.face_adjacency.T
    same_plane = (np.abs(normals[a] - normals[b]).max(axis=1) < 1e-9) & (np.abs(offsets[a] - offsets[b]) < 1e-9)
    groups = trimesh.graph.connected_components(part.face_adjacency[same_plane], nodes=np.arange(len(part.faces)), min_len=1)
    triangles = []
    for group in groups:
        normal = part.face_normals[group[0]]
        corners = np.unique(vertices[np.unique(part.faces[group])], axis=0)  # sorted, no duplicates
        u = corners[-1] - corners[0]
        u = u - normal * (u @ normal)
        if len(corners) < 3 or np.linalg.norm(u) < 1e-12:
            continue  # a degenerate sliver: no area to sample
        u /= np.linalg.norm(u)
        ring = corners[_convex_ring(np.c_[corners @ u, corners @ np.cross(normal, u)])]
        triangles += [(ring[0], ring[i], ring[i + 1]) for i in range(1, len(ring) - 1)]
    corners = np.array(triangles).reshape(-1, 3)
    unique, inverse = np.unique(corners, axis=0, return_inverse=True)  # sorted vertices
    faces = inverse.reshape(-1, 3)
    return trimesh.Trimesh(unique, faces[np.lexsort(faces.T[::-1])], process=False)


def _convex_ring(points_2d: np.ndarray) -> np.ndarray:
    """Indices of the 2D convex hull, counter-clockwise from the smallest index kept,
    without interior or collinear points (a cap's centre vertex, mid-edge points).
    Andrew's monotone chain."""
    order = np.lexsort(points_2d.T[::-1])
    lower, upper = [], []
    for chain, sequence in ((lower, order), (upper, order[::-1])):
        for i in sequence:
            while len(chain) >= 2:
                a, b = points_2d[chain[-2]], points_2d[chain[-1]]
                if (b[0] - a[0]) * (points_2d[i][1] - a[1]) - (b[1] - a[1]) * (points_2d[i][0] - a[0]) > 1e-15:
                    break
                chain.pop()
            chain.append(int(i))
    ring = np.array(lower[:-1] + upper[:-1])
    # Start at the smallest index kept (0 unless rounding dropped it as collinear).
    return np.roll(ring, -int(np.argmin(ring)))


def object_collision_manager(asset: ObjectAsset) -> trimesh.collision.CollisionManager:
    manager = trimesh.collision.CollisionManager()
    for i, part in enumerate(asset.convex_parts):
        manager.add_object(f"part{i}", part)
    return manager


def sample_candidates(asset: ObjectAsset, n: int, rng: np.random.Generator, config: SamplerConfig = SamplerConfig()) -> Candidates:
    """Up to ``n`` collision-free antipodal candidates on ``asset`` (fewer if the object has few)."""
    parts = tuple(canonical_part(p) for p in asset.convex_parts)
    union = ConvexUnion(parts)
    manager = object_collision_manager(asset)
    # The hand's BVH is built once and moved per pose (rebuilding it per query dominates otherwise).
    hand = trimesh.collision.CollisionManager()
    hand.add_object("hand", open_hand_mesh())
    cos_cone = np.cos(config.cone_half_angle)
    kept_T, kept_w, kept_c = [], [], []
    for _ in range(config.max_rounds):
        points, normals = sample_union_surface(union, parts, n * config.oversample, rng)
        inward = -normals
        closing = _directions_in_cone(inward, config.cone_half_angle, rng)
        t, exit_normal, valid = union.ray_exit(points, closing)
        # Half of the rays take the far side instead (across a whole cup, not one wall) where
        # that is a different contact; the near exit stays for the rest (rims, handles).
        t_far, normal_far, valid_far = union.ray_last_exit(points, closing, config.max_width)
        use_far = valid_far & (t_far > t + 1e-3) & (rng.random(len(t)) < config.far_exit_fraction)
        t = np.where(use_far, t_far, t)
        exit_normal = np.where(use_far[:, None], normal_far, exit_normal)
        valid = np.where(use_far, valid_far, valid)
        p, q, d, width = points, points + t[:, None] * closing, closing, t
        in_cone_q = np.einsum("ij,ij->i", exit_normal, d) >= cos_cone
        ok = valid & in_cone_q & (width >= config.min_width) & (width <= config.max_width)
        p, q, d, width = p[ok], q[ok], d[ok], width[ok]
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
