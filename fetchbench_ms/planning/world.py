"""Collision worlds the planner queries: batched signed distances for many points.

Two kinds of obstacle sets, both answering ``distance(points_base) -> (N,)``:
- exact primitives (the furniture's boxes, cylinders, capsules) and convex parts in
  half-space form (objects, convex furniture pieces). For a convex part the largest
  plane distance is exact inside and never more than the true distance outside, so
  the world errs towards "too close": conservative;
- a point cloud as a 5 mm distance field (``PointCloudField``).

A ``CollisionWorld`` holds named groups ("scene", "object:<name>", "target", ...) so a
query can leave some out (the target while grasping it, the carried object).
All positions are in the robot base frame.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

FAR = 10.0  # distance reported where a set has nothing nearby (m)
#: ``torch.cdist`` point by point: its default matrix-product form rounds a pair's value
#: differently with the batch around it (and is slower for 3-D points)
EXACT_CDIST = "donot_use_mm_for_euclid_dist"


def _t(x) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


def quat_wxyz_to_matrix(q) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w]).as_matrix()


def pose_matrix(position, quat_wxyz=(1.0, 0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quat_wxyz_to_matrix(quat_wxyz)
    T[:3, 3] = position
    return T


def _cluster_balls(points: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Each run of ``size`` consecutive points' bounding sphere: centres (C, 3), radii (C,)."""
    if len(points) % size:
        raise ValueError(f"cluster_size {size} does not divide the {len(points)} points")
    clusters = points.reshape(-1, size, 3)
    center = (clusters.amax(dim=1) + clusters.amin(dim=1)) / 2
    return center, (clusters - center[:, None]).norm(dim=2).amax(dim=1)


def _cluster_pairs(points: torch.Tensor, balls: tuple[torch.Tensor, torch.Tensor], obstacle_set,
                   horizon: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The (point, obstacle) pairs of ``CollisionWorld.distance``'s broad phase, found cluster
    by cluster (consecutive runs of points, ``balls`` their bounding spheres). A cluster's bounding sphere (centre c,
    radius r) is tested against each obstacle's bounding sphere, then by the obstacle's exact
    distance at c: every exact distance here is 1-Lipschitz, so d(p) >= d(c) - r for each point
    p of the cluster, and a pair dropped here is beyond ``horizon`` for all its points (1e-6 of
    slack for rounding). The pairs kept are then tested point by point as the flat broad phase
    does, so every distance below ``horizon`` comes from the same obstacle and formula."""
    center, radius = balls
    size = len(points) // len(center)
    gap = torch.cdist(center, obstacle_set.bound_center) - obstacle_set.bound_radius - radius[:, None]
    idx_c, idx_o = torch.nonzero(gap < horizon + 1e-6, as_tuple=True)
    if len(idx_c):
        near = obstacle_set.exact(center, idx_c, idx_o) - radius[idx_c] < horizon + 1e-6
        idx_c, idx_o = idx_c[near], idx_o[near]
    idx_p = (idx_c[:, None] * size + torch.arange(size)).reshape(-1)
    idx_o = idx_o.repeat_interleave(size)
    coarse = (points[idx_p] - obstacle_set.bound_center[idx_o]).norm(dim=1) - obstacle_set.bound_radius[idx_o]
    keep = coarse < horizon
    return idx_p[keep], idx_o[keep]


def bounding_ball(bound_center: torch.Tensor, bound_radius: torch.Tensor) -> tuple[np.ndarray, float]:
    """A ball holding every member's bounding sphere (the centres' box centre)."""
    if len(bound_center) == 0:
        return np.zeros(3), 0.0
    center = (bound_center.amin(dim=0) + bound_center.amax(dim=0)) / 2
    return center.numpy(), float(((bound_center - center).norm(dim=1) + bound_radius).max())


class _BoundAll:
    """``bound_all``: the set's one bounding ball, from its members' (computed once)."""

    @property
    def bound_all(self) -> tuple[np.ndarray, float]:
        cached = self.__dict__.get("_bound_all")
        if cached is None:
            cached = self.__dict__["_bound_all"] = bounding_ball(self.bound_center, self.bound_radius)
        return cached


class BoxSet(_BoundAll):
    """Oriented boxes, exact signed distance."""

    def __init__(self, T_base_box: np.ndarray, half_size: np.ndarray):
        T = np.asarray(T_base_box, dtype=float).reshape(-1, 4, 4)
        self.T_box_base = _t(np.linalg.inv(T))
        self.half_size = _t(np.asarray(half_size, dtype=float).reshape(-1, 3))
        self.bound_center = _t(T[:, :3, 3])
        self.bound_radius = self.half_size.norm(dim=1)

    def __len__(self):
        return len(self.half_size)

    def _local(self, points: torch.Tensor, idx_p, idx_o) -> torch.Tensor:
        T = self.T_box_base[idx_o]
        return torch.einsum("nij,nj->ni", T[:, :3, :3], points[idx_p]) + T[:, :3, 3]

    def exact(self, points, idx_p, idx_o):
        q = self._local(points, idx_p, idx_o).abs() - self.half_size[idx_o]
        outside = q.clamp(min=0).norm(dim=1)
        inside = q.amax(dim=1).clamp(max=0)
        return outside + inside


class CylinderSet(_BoundAll):
    """Capped cylinders (axis = local z) or capsules, exact signed distance."""

    def __init__(self, T_base_cyl: np.ndarray, radius, half_length, capsule: bool = False):
        T = np.asarray(T_base_cyl, dtype=float).reshape(-1, 4, 4)
        self.T_cyl_base = _t(np.linalg.inv(T))
        self.radius = _t(np.asarray(radius, dtype=float).reshape(-1))
        self.half_length = _t(np.asarray(half_length, dtype=float).reshape(-1))
        self.capsule = capsule
        self.bound_center = _t(T[:, :3, 3])
        self.bound_radius = self.half_length + self.radius

    def __len__(self):
        return len(self.radius)

    def exact(self, points, idx_p, idx_o):
        T = self.T_cyl_base[idx_o]
        p = torch.einsum("nij,nj->ni", T[:, :3, :3], points[idx_p]) + T[:, :3, 3]
        r, h = self.radius[idx_o], self.half_length[idx_o]
        if self.capsule:
            z = p[:, 2].clamp(-h, h)
            return torch.stack([p[:, 0], p[:, 1], p[:, 2] - z], 1).norm(dim=1) - r
        d = torch.stack([p[:, :2].norm(dim=1) - r, p[:, 2].abs() - h], 1)
        return d.clamp(min=0).norm(dim=1) + d.amax(dim=1).clamp(max=0)


class ConvexSet(_BoundAll):
    """Convex parts as half-spaces n.x <= d: distance = max_k (n_k.x - d_k).

    Exact inside and on faces; outside near edges and corners it is below the true
    distance (never above), so collision answers are conservative.
    """

    def __init__(self, hulls_base: list[trimesh.Trimesh], convex: list[bool] | None = None):
        """``convex``: whether each mesh is convex, when known (a rigid motion keeps it so);
        None: each is tested, and a mesh that is not is replaced by its convex hull."""
        planes = []
        centers, radii = [], []
        for i, hull in enumerate(hulls_base):
            hull = hull if (hull.is_convex if convex is None else convex[i]) else hull.convex_hull
            normals = np.asarray(hull.face_normals)
            offsets = np.einsum("ij,ij->i", normals, hull.vertices[hull.faces[:, 0]])
            # Coplanar triangles give the same plane: keep one.
            nd = np.column_stack([normals, offsets])
            _, first = np.unique(np.round(nd, 6), axis=0, return_index=True)
            planes.append(nd[np.sort(first)])
            center = hull.vertices.mean(axis=0)
            centers.append(center)
            radii.append(np.linalg.norm(hull.vertices - center, axis=1).max())
        n_max = max((len(p) for p in planes), default=1)
        padded = np.zeros((len(planes), n_max, 4))
        padded[:, :, 3] = 1e9  # padding planes never bind: n = 0, d huge -> -1e9
        for i, p in enumerate(planes):
            padded[i, : len(p)] = p
        self.planes = _t(padded)
        self.bound_center = _t(np.asarray(centers).reshape(-1, 3))
        self.bound_radius = _t(np.asarray(radii))

    def __len__(self):
        return len(self.planes)

    def plane_counts(self) -> np.ndarray:
        """(parts,) each part's planes without the padding."""
        return (self.planes[:, :, 3] < 1e8).sum(dim=1).numpy()

    def subset(self, index) -> "ConvexSet":
        """The parts ``index``, padded only to their own largest plane count (the same
        distances: a padding plane never binds)."""
        index = np.asarray(index, dtype=int)
        part = ConvexSet.__new__(ConvexSet)
        k = max(int(self.plane_counts()[index].max()) if len(index) else 1, 1)
        part.planes = self.planes[index, :k].clone()
        part.bound_center, part.bound_radius = self.bound_center[index].clone(), self.bound_radius[index].clone()
        return part

    def exact(self, points, idx_p, idx_o):
        P = self.planes[idx_o]  # (n, K, 4)
        return (torch.einsum("nkj,nj->nk", P[..., :3], points[idx_p]) - P[..., 3]).amax(dim=1)


class PointCloudField:
    """Distance to an observed point cloud at ``voxel`` resolution.

    The cloud is reduced to occupied voxel centres; the distance of a query point is its
    distance to the nearest occupied centre minus the voxel's half diagonal, so any
    surface point inside an occupied voxel is at least that far (conservative). A k-d
    tree answers the field lazily: a dense 5 mm grid (EDT) over the arm's reach would be
    ~40 M voxels, seconds per scene on this CPU, while the tree is exact at the same
    resolution and built in milliseconds.
    """

    def __init__(self, points_base: np.ndarray, voxel: float = 0.005):
        points_base = np.asarray(points_base, dtype=float).reshape(-1, 3)
        self.voxel = voxel
        keys = np.unique(np.floor(points_base / voxel).astype(np.int64), axis=0)
        self.centers = (keys + 0.5) * voxel
        self.tree = cKDTree(self.centers) if len(self.centers) else None
        self.half_diagonal = 0.5 * voxel * np.sqrt(3.0)

    def __len__(self):
        return len(self.centers)

    def distance(self, points: torch.Tensor, horizon: float) -> torch.Tensor:
        if self.tree is None:
            return torch.full((len(points),), FAR, dtype=torch.float64)
        d, _ = self.tree.query(points.detach().numpy(), distance_upper_bound=horizon + self.half_diagonal)
        d = np.where(np.isfinite(d), d - self.half_diagonal, FAR)
        return torch.as_tensor(d, dtype=torch.float64)


@dataclass
class CollisionWorld:
    """Named groups of obstacle sets; ``distance`` is the minimum over included groups."""

    groups: dict[str, list] = field(default_factory=dict)

    def add(self, group: str, obstacle_set) -> "CollisionWorld":
        if len(obstacle_set):
            self.groups.setdefault(group, []).append(obstacle_set)
        return self

    @property
    def group_names(self) -> tuple[str, ...]:
        return tuple(self.groups)

    def distance(self, points_base, horizon: float = 0.2, exclude: tuple[str, ...] = (),
                 cluster_size: int = 0) -> torch.Tensor:
        """Signed distance of each point to the nearest obstacle, (N,).

        Values are exact (or conservative) below ``horizon``; beyond it they may be
        any value >= horizon (broad phase skips far obstacles). ``cluster_size`` K > 0: the
        points come in consecutive clusters of K (a hand's points at each of many poses), and
        the broad phase first tests each cluster's bounding sphere (``_cluster_pairs``): the
        same values below ``horizon``, with far fewer point-obstacle tests.
        """
        unknown = set(exclude) - set(self.groups)
        if unknown and not all(u.startswith("object:") or u == "target" for u in unknown):
            raise KeyError(f"unknown world groups {sorted(unknown)}; valid: {', '.join(self.groups)}")
        points = torch.as_tensor(points_base, dtype=torch.float64).reshape(-1, 3)
        out = torch.full((len(points),), FAR, dtype=torch.float64)
        sets = [s for name, group in self.groups.items() if name not in exclude for s in group]
        bounded = [k for k, s in enumerate(sets) if getattr(s, "bound_all", None) is not None]
        # Each point against each set's one bounding ball, all sets in one batch: a point
        # farther than the horizon from a set's ball (with room for rounding) has no pair
        # the broad phase keeps, so the set's members are measured only from the points
        # near it. Distances point by point (no matrix-product form), so a pair's value does
        # not depend on the other points of the batch.
        near_set = {}
        if bounded and len(points):
            ball_c = torch.as_tensor(np.stack([sets[k].bound_all[0] for k in bounded]))
            ball_r = torch.as_tensor([sets[k].bound_all[1] for k in bounded], dtype=torch.float64)
            gap = torch.cdist(points, ball_c, compute_mode=EXACT_CDIST) - ball_r
            near_set = dict(zip(bounded, (gap < horizon + 1e-6).T))
        balls = _cluster_balls(points, cluster_size) if cluster_size and len(points) else None
        for k, obstacle_set in enumerate(sets):
            if isinstance(obstacle_set, PointCloudField):
                out = torch.minimum(out, obstacle_set.distance(points, horizon))
                continue
            near = near_set.get(k)
            if near is not None and not bool(near.any()):
                continue
            if balls is not None:
                idx_p, idx_o = _cluster_pairs(points, balls, obstacle_set, horizon)
            else:  # broad phase: bounding spheres within the horizon
                at = torch.arange(len(points)) if near is None else torch.nonzero(near, as_tuple=True)[0]
                coarse = torch.cdist(points[at], obstacle_set.bound_center, compute_mode=EXACT_CDIST)
                idx_p, idx_o = torch.nonzero(coarse - obstacle_set.bound_radius < horizon, as_tuple=True)
                idx_p = at[idx_p]
            if len(idx_p) == 0:
                continue
            d = obstacle_set.exact(points, idx_p, idx_o)
            out = out.scatter_reduce(0, idx_p, d, reduce="amin")
        return out


def obstacle_sets_from_parts(parts, T_base_scene: np.ndarray) -> list:
    """Obstacle sets for SceneSpec parts (boxes, cylinders, capsules, convex meshes), base frame."""
    boxes, box_sizes, cyl, caps, hulls = [], [], [], [], []
    for part in parts:
        T = T_base_scene @ pose_matrix(part.position, part.quat_wxyz)
        if part.shape == "box":
            boxes.append(T)
            box_sizes.append(np.asarray(part.size) / 2)
        elif part.shape in ("cylinder", "capsule"):
            (cyl if part.shape == "cylinder" else caps).append((T, part.size[0], part.size[1] / 2))
        elif part.shape == "convex_mesh":
            hull = trimesh.Trimesh(np.asarray(part.mesh_vertices)).convex_hull
            hulls.append(hull.apply_transform(T))
        else:
            raise ValueError(f"unknown part shape {part.shape!r}; valid: box, cylinder, capsule, convex_mesh")
    sets = []
    if boxes:
        sets.append(BoxSet(np.stack(boxes), np.stack(box_sizes)))
    for items, capsule in ((cyl, False), (caps, True)):
        if items:
            sets.append(CylinderSet(np.stack([i[0] for i in items]), [i[1] for i in items], [i[2] for i in items],
                                    capsule=capsule))
    if hulls:
        sets.append(ConvexSet(hulls))
    return sets


def convex_set_from_parts(convex_parts, T_base_object: np.ndarray) -> ConvexSet:
    """An object's convex parts (object frame) placed at ``T_base_object``. Whether a part is
    convex is asked of the part itself (trimesh keeps the answer with the mesh: an object's
    parts are tested once a process, not at every pose they are placed at)."""
    return ConvexSet([p.copy().apply_transform(T_base_object) for p in convex_parts],
                     convex=[bool(p.is_convex) for p in convex_parts])


def box_set(T_base_box, size) -> BoxSet:
    """Boxes given by full sizes (e.g. the robot table, the floor slab)."""
    return BoxSet(np.asarray(T_base_box).reshape(-1, 4, 4), np.asarray(size, dtype=float).reshape(-1, 3) / 2)
