"""Differentiable sphere-vs-world distances in torch, batched over problems, on any device.

The torch planners' view of what ``checker.CollisionChecker`` decides one configuration at
a time: the same obstacles, the same robot spheres, but as tensors on one device, batched
over problems (``P``), and with gradients.

- ``TorchWorld``: the obstacles of ``P`` collision worlds (each with its own excluded
  groups), padded to common sizes. Boxes, cylinders, capsules and convex parts (half-space
  form) keep the exact formulas of ``world.py`` (a broad phase on bounding spheres, then the
  exact distance of the pairs within the horizon), so on the mesh world the two agree to
  float precision (with ``max_planes``, parts with more planes keep the most spread-out
  ones, capped by their bounding sphere: a conservative, cheaper polytope). A
  ``PointCloudField`` (the 5 mm cloud) becomes a truncated distance grid
  (``GRID_RESOLUTION``, within the arm's reach): an EDT of the occupied cells, refined to
  the exact nearest-voxel distance (the k-d tree's answer) at the grid vertices near the
  cloud, read by trilinear interpolation (``grid_sample``), so it is within about a cell
  of the checker's value and smooth enough for gradients. With ``baked_grid=RES`` the
  whole world (primitives and clouds alike) is read through one such grid over
  ``GRID_BOUNDS``, its vertices measured once per world by the exact formulas above
  (``baked_grid_values``): within half a cell diagonal of the exact distance (the distance
  is 1-Lipschitz), one interpolation per sphere however many obstacles, and the same grid
  shape for every world.
- ``TorchRobot``: batched FK of the Panda's spheres on the device, per problem finger
  opening, checked links and carried object (``checker.Attachment``); self-collision
  sphere pairs and carried-object-vs-arm pairs.

Distances are signed: < 0 is penetration. Values are exact (or as the checker's) below
the query horizon; beyond it, any value >= the horizon.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F

from .checker import CollisionChecker
from .robot import PandaModel
from .world import FAR, BoxSet, CollisionWorld, ConvexSet, CylinderSet, PointCloudField

GRID_RESOLUTION = 0.015  # m between distance-grid vertices (point-cloud worlds)
GRID_TRUNCATION = 0.10  # m: grid values are exact up to here, at least this beyond
GRID_EXACT_BAND = 0.04  # m: vertices this near the cloud (by the EDT) get the exact distance
# The grid covers the cloud only within the arm's reach (base frame, m): a scene cloud spans
# the floor metres around, and a 1.5 cm grid over all of it took seconds to build.
GRID_BOUNDS = ((-1.2, -1.2, -0.7), (1.2, 1.2, 1.5))
NEAR_MARGIN = 1e-4  # m: pairs are measured with gradients up to this beyond the cost's horizon (rounding)
MEASURE_NEAR_FIRST = True  # the differentiable pass only over pairs that cost something (False: for tests)
_FAR_CENTER = 1e3  # padding obstacles sit here with a zero bounding radius: never near


def _pad(arrays: list[np.ndarray], fill: float, tail: tuple[int, ...]) -> np.ndarray:
    """Stack per-problem arrays (n_p, *tail) into (P, max n_p, *tail), padded with ``fill``."""
    n = max([len(a) for a in arrays] + [1])
    out = np.full((len(arrays), n) + tail, fill, dtype=float)
    for i, a in enumerate(arrays):
        out[i, : len(a)] = np.asarray(a, dtype=float).reshape((-1,) + tail)
    return out


def _rotate(R: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``R @ x`` over the last axes, ``R`` (..., I, 3) and ``x`` (..., 3) broadcast: the sum of
    three products, in the order a batched matrix product adds them (the same values as
    ``einsum``), without its batched-GEMM call per tiny matrix (several times slower on a CPU)."""
    x = x.unsqueeze(-2)
    return R[..., 0] * x[..., 0] + R[..., 1] * x[..., 1] + R[..., 2] * x[..., 2]


def _smooth_norm(x: torch.Tensor) -> torch.Tensor:
    """|x| over the last axis with a finite gradient at 0."""
    return torch.sqrt((x * x).sum(-1) + 1e-12)


class _Primitives:
    """One kind of obstacle for all problems: (P, O, ...) tensors and bounding spheres."""

    def __init__(self, kind: str, tensors: dict[str, np.ndarray], bound_c: np.ndarray, bound_r: np.ndarray,
                 device, dtype):
        self.kind = kind
        self.reduced = False
        self.t = {k: torch.as_tensor(v, device=device, dtype=dtype) for k, v in tensors.items()}
        self.bound_c = torch.as_tensor(bound_c, device=device, dtype=dtype)
        self.bound_r = torch.as_tensor(bound_r, device=device, dtype=dtype)
        self.O = self.bound_r.shape[1]
        # Flat (P * O, ...) views: a pair's row is one index_select (multi-tensor indexing and
        # its backward are several times slower on a CPU).
        self.flat = {k: v.flatten(0, 1) for k, v in self.t.items()}
        self.flat_bound_c, self.flat_bound_r = self.bound_c.flatten(0, 1), self.bound_r.flatten(0, 1)

    def exact(self, x: torch.Tensor, p: torch.Tensor, o: torch.Tensor) -> torch.Tensor:
        """Signed distance of points ``x`` (M, 3) to obstacle ``o`` of problem ``p`` (the
        formulas of world.py)."""
        po = p * self.O + o

        def take(name):
            return self.flat[name].index_select(0, po)

        if self.kind == "convex":
            planes = take("planes")  # (M, K, 4)
            d = (_rotate(planes[..., :3], x) - planes[..., 3]).amax(dim=1)
            if self.reduced:  # fewer planes bound a larger polytope: the bounding sphere caps it
                d = torch.maximum(d, _smooth_norm(x - self.flat_bound_c.index_select(0, po))
                                  - self.flat_bound_r.index_select(0, po))
            return d
        local = _rotate(take("R"), x) + take("t")
        if self.kind == "box":
            q = local.abs() - take("half")
            return _smooth_norm(q.clamp(min=0)) + q.amax(dim=1).clamp(max=0)
        r, h, capsule = take("radius"), take("half_length"), take("capsule") > 0.5
        z = torch.maximum(torch.minimum(local[:, 2], h), -h)
        d_capsule = _smooth_norm(torch.stack([local[:, 0], local[:, 1], local[:, 2] - z], 1)) - r
        d = torch.stack([_smooth_norm(local[:, :2]) - r, local[:, 2].abs() - h], 1)
        d_cylinder = _smooth_norm(d.clamp(min=0)) + d.amax(dim=1).clamp(max=0)
        return torch.where(capsule, d_capsule, d_cylinder)

    def pairs(self, points: torch.Tensor, horizon: float, radii: torch.Tensor | None = None,
              groups: "SphereGroups | None" = None, prepared: tuple | None = None, ordered: bool = True
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """(flat point index into P*N, signed distance) of every (point, obstacle) pair whose
        bounding sphere is within ``horizon`` (+ the point's radius in ``radii`` (P, N)).
        With ``groups`` the points are tested group by group first (the same pairs, each
        point's in ascending obstacle order, as without, less pairs beyond ``horizon`` by
        their exact distance); ``prepared``: ``groups.prepare(points, radii)`` when known;
        ``ordered=False``: the same pairs in any order (for order-free reductions)."""
        return self.pair_distances(points, *self.candidates(points, horizon, radii, groups, prepared, ordered))

    def candidates(self, points: torch.Tensor, horizon: float, radii: torch.Tensor | None = None,
                   groups: "SphereGroups | None" = None, prepared: tuple | None = None, ordered: bool = True
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(p, n, o) of the pairs ``pairs`` measures, ordered by point, then obstacle (with
        ``ordered``; else in any order)."""
        with torch.no_grad():
            if groups is None:
                coarse = torch.cdist(points.detach(), self.bound_c) - self.bound_r[:, None, :]  # (P, N, O)
                if radii is not None:
                    coarse = coarse - radii[..., None]
                return torch.nonzero(coarse < horizon, as_tuple=True)
            return groups.candidates(points.detach(), radii, self, horizon, prepared, ordered)

    def near(self, points: torch.Tensor, radii: torch.Tensor, horizon: float, p: torch.Tensor, n: torch.Tensor,
             o: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The pairs (p, n, o) whose exact distance, less the point's radius in ``radii``
        (P, N), is below ``horizon`` (+ ``NEAR_MARGIN`` for float rounding), in their order:
        measured without gradients, so that the differentiable pass (and its backward) is
        the few pairs that cost something. The pairs left out cost exactly 0 with a zero
        gradient, and a sum that skips them is bitwise the sum over all (x + 0 = x, and the
        sums start at +0)."""
        with torch.no_grad():
            pn, d = self.pair_distances(points.detach(), p, n, o)
            keep = torch.nonzero(d - radii.reshape(-1).index_select(0, pn) < horizon + NEAR_MARGIN,
                                 as_tuple=True)[0]
        return p.index_select(0, keep), n.index_select(0, keep), o.index_select(0, keep)

    def pair_distances(self, points: torch.Tensor, p: torch.Tensor, n: torch.Tensor, o: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor]:
        """(flat point index into P*N, signed distance) of the pairs (point ``n`` of problem
        ``p``, obstacle ``o``)."""
        P, N, _ = points.shape
        pn = p * N + n
        return pn, self.exact(points.reshape(P * N, 3).index_select(0, pn), p, o)


def _fewer_planes(planes: np.ndarray, max_planes: int | None) -> np.ndarray:
    """At most ``max_planes`` of a convex part's planes (K, 4), padding dropped: the ones
    whose normals are spread farthest apart (greedy farthest-point on the unit sphere).
    Dropping planes only enlarges the polytope, so distances only shrink: conservative."""
    planes = planes[np.abs(planes[:, 3]) < 1e8]
    if max_planes is None or len(planes) <= max_planes:
        return planes
    normals = planes[:, :3]
    chosen = [int(np.argmax(normals[:, 2]))]
    nearest = normals @ normals[chosen[0]]  # cosine to the nearest chosen normal
    for _ in range(max_planes - 1):
        i = int(np.argmin(nearest))
        chosen.append(i)
        nearest = np.maximum(nearest, normals @ normals[i])
    return planes[sorted(chosen)]


def _set_fewer_planes(convex: ConvexSet, max_planes: int | None) -> list[np.ndarray]:
    """``_fewer_planes`` of each part of ``convex``, kept on the set (as its torch grid is on a
    cloud): a world's sets outlive a plan, and the thinning was a millisecond a part per plan."""
    cache = convex.__dict__.setdefault("_fewer_planes", {})
    if max_planes not in cache:
        cache[max_planes] = [_fewer_planes(part, max_planes) for part in convex.planes.numpy()]
    return cache[max_planes]


def _grid_from_cloud(field: PointCloudField, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """(origin (3,), values (nx, ny, nz)) of a truncated distance grid around the cloud."""
    from scipy.ndimage import distance_transform_edt

    centers = field.centers
    lo = np.maximum(centers.min(axis=0) - GRID_TRUNCATION, GRID_BOUNDS[0])
    hi = np.minimum(centers.max(axis=0) + GRID_TRUNCATION, GRID_BOUNDS[1])
    shape = np.maximum(np.ceil((hi - lo) / resolution).astype(int) + 1, 2)
    occupied = np.zeros(shape, dtype=bool)
    idx = np.round((centers - lo) / resolution).astype(int)
    inside = ((idx >= 0) & (idx < shape)).all(axis=1)
    occupied[tuple(idx[inside].T)] = True
    if not inside.any():  # nothing within reach
        return lo, np.full(shape, GRID_TRUNCATION)
    # EDT between vertices: within half a cell diagonal of the exact distance to the cloud.
    values = distance_transform_edt(~occupied, sampling=resolution)
    values = np.minimum(values - field.half_diagonal - 0.5 * np.sqrt(3) * resolution, GRID_TRUNCATION)
    near = np.nonzero(values < GRID_EXACT_BAND)
    if len(near[0]):
        vertices = lo + np.stack(near, 1) * resolution
        d, _ = field.tree.query(vertices, distance_upper_bound=GRID_TRUNCATION + field.half_diagonal)
        values[near] = np.minimum(np.where(np.isfinite(d), d - field.half_diagonal, GRID_TRUNCATION),
                                  GRID_TRUNCATION)
    return lo, values


def plane_max(x: torch.Tensor, planes: torch.Tensor) -> torch.Tensor:
    """max over the last axis of ``planes`` (..., K, 4) of n . x - offset, ``x`` (..., 1, 3)
    broadcast against them. Written as products and sums, not a matrix product: under
    ``torch.compile`` (``trajopt.TrajoptConfig.compile_backend``) the whole expression and its maximum
    fuse into one kernel that never stores the (..., K) distances (the largest tensors of an
    iteration: every sphere, its nearest parts, every plane), and the backward recomputes them.
    Eager, the batched matrix product is faster; the two agree to float rounding."""
    return (x[..., 0] * planes[..., 0] + x[..., 1] * planes[..., 1] + x[..., 2] * planes[..., 2]
            - planes[..., 3]).amax(dim=-1)


def distance_to_every(kind, x: torch.Tensor) -> torch.Tensor:
    """(P, A, O) exact distance of points ``x`` (P, A, 3) to every obstacle of ``kind``."""
    P, A, _ = x.shape
    O = kind.O
    if kind.kind == "convex":  # one batched matrix product per problem: every point, every plane
        planes = kind.t["planes"]  # (P, O, K, 4)
        if torch.compiler.is_compiling():
            d = plane_max(x[:, :, None, None], planes[:, None])
        else:
            d = torch.einsum("pai,poki->paok", x, planes[..., :3]) - planes[:, None, :, :, 3]
            d = d.amax(dim=3)
        if kind.reduced:
            d = torch.maximum(d, torch.cdist(x, kind.bound_c) - kind.bound_r[:, None])
        return d
    p = torch.arange(P, device=x.device)[:, None, None].expand(P, A, O).reshape(-1)
    o = torch.arange(O, device=x.device).expand(P, A, O).reshape(-1)
    return kind.exact(x[:, :, None].expand(P, A, O, 3).reshape(-1, 3), p, o).reshape(P, A, O)


# Grid vertices measured per call while baking: bounds the broad phase's memory (vertices x
# obstacles); a GPU takes larger calls (each call reads pair counts back to the host once per
# obstacle kind). The values do not depend on it. On an H200 a val world bakes in a median
# 16.8 ms at 2^19, 12.4 ms at 2^20 (1.6 GB peak), 11.4 ms at 2^21 (3.1 GB)
# (results/planning/bench-world-grid-h200-val40.json): 2^20, the memory of 16 workers a GPU.
BAKED_CHUNK = {"cpu": 1 << 17, "cuda": 1 << 20}
BAKED_CACHE = 4  # baked grids kept per world (by resolution, device and included obstacle sets)


def grid_shape(resolution: float) -> np.ndarray:
    """Vertices per axis of a grid over ``GRID_BOUNDS`` at ``resolution``."""
    lo, hi = np.asarray(GRID_BOUNDS[0]), np.asarray(GRID_BOUNDS[1])
    return np.ceil((hi - lo) / resolution - 1e-9).astype(int) + 1


def baked_grid_values(world: CollisionWorld, exclude: tuple[str, ...], resolution: float, device=None,
                      dtype=torch.float32, max_planes: int | None = None) -> torch.Tensor:
    """(nx, ny, nz) distance of the vertices of a grid over ``GRID_BOUNDS`` to ``world`` (less
    ``exclude``), as ``TorchWorld.distance`` measures it (bounding spheres first, the exact
    formulas within the truncation), truncated at ``GRID_TRUNCATION``. Kept on the world
    (``BAKED_CACHE`` per world, with the obstacle sets they were measured from, so that a set
    added or replaced is a new entry): the plans of one task share a world."""
    sets = [s for g, ss in world.groups.items() if g not in exclude for s in ss]
    device = torch.device(device or "cpu")
    key = (resolution, max_planes, str(device), dtype, tuple(id(s) for s in sets))
    cache = world.__dict__.setdefault("_baked_grids", {})
    if key in cache:
        return cache[key][1]
    shape = grid_shape(resolution)
    exact = TorchWorld([world], [exclude], device, dtype, max_planes=max_planes)
    axes = [torch.arange(n, device=device, dtype=torch.float64) * resolution + lo
            for n, lo in zip(shape, GRID_BOUNDS[0])]
    vertices = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(1, -1, 3).to(dtype)
    chunk = BAKED_CHUNK.get(device.type, BAKED_CHUNK["cpu"])
    values = torch.empty(vertices.shape[1], device=device, dtype=dtype)
    with torch.no_grad():
        for i in range(0, vertices.shape[1], chunk):
            d = exact.distance(vertices[:, i: i + chunk], horizon=GRID_TRUNCATION)
            values[i: i + chunk] = d[0].clamp(max=GRID_TRUNCATION)
    values = values.reshape(*shape)
    cache[key] = (sets, values)  # the sets held: their ids cannot be reused while cached
    while len(cache) > BAKED_CACHE:
        cache.pop(next(iter(cache)))
    return values


class TorchWorld:
    """The obstacles of ``P`` worlds as device tensors; see the module docstring."""

    def __init__(self, worlds: Sequence[CollisionWorld], excludes: Sequence[tuple[str, ...]] | None = None,
                 device=None, dtype=torch.float32, grid_resolution: float = GRID_RESOLUTION,
                 max_planes: int | None = None, baked_grid: float | None = None):
        excludes = list(excludes) if excludes is not None else [()] * len(worlds)
        if len(excludes) != len(worlds):
            raise ValueError(f"{len(worlds)} worlds but {len(excludes)} exclude tuples")
        self.P, self.device, self.dtype = len(worlds), torch.device(device or "cpu"), dtype
        if baked_grid is not None:  # every obstacle through one grid (module docstring)
            values = torch.stack([baked_grid_values(w, tuple(e), baked_grid, self.device, dtype, max_planes)
                                  for w, e in zip(worlds, excludes)])
            self.kinds = []
            self._set_grid(values, np.tile(GRID_BOUNDS[0], (self.P, 1)), (grid_shape(baked_grid) - 1) * baked_grid)
            return
        boxes, cyls, convex, clouds = [], [], [], []
        for world, exclude in zip(worlds, excludes):
            sets = [s for g, ss in world.groups.items() if g not in exclude for s in ss]
            boxes.append([s for s in sets if isinstance(s, BoxSet)])
            cyls.append([s for s in sets if isinstance(s, CylinderSet)])
            convex.append([s for s in sets if isinstance(s, ConvexSet)])
            clouds.append([s for s in sets if isinstance(s, PointCloudField) and len(s)])
        kinds = (self._boxes(boxes), self._cylinders(cyls), self._convex(convex, max_planes))
        self.kinds = [k for k in kinds if k is not None]
        self._grids(clouds, grid_resolution)

    # -- building -------------------------------------------------------------------------
    def _make(self, kind, per_problem: list[dict[str, np.ndarray]], tails: dict, fills: dict) -> _Primitives | None:
        if not any(len(d["bound_r"]) for d in per_problem):
            return None
        tensors = {k: _pad([d[k] for d in per_problem], fills.get(k, 0.0), tail) for k, tail in tails.items()}
        bound_c = _pad([d["bound_c"] for d in per_problem], _FAR_CENTER, (3,))
        bound_r = _pad([d["bound_r"] for d in per_problem], 0.0, ())
        return _Primitives(kind, tensors, bound_c, bound_r, self.device, self.dtype)

    @staticmethod
    def _cat(sets, fn) -> np.ndarray:
        parts = [np.asarray(fn(s)) for s in sets]
        return np.concatenate(parts) if parts else np.zeros((0,))

    def _boxes(self, per_problem):
        data = [dict(R=self._cat(s, lambda b: b.T_box_base[:, :3, :3].numpy()).reshape(-1, 3, 3),
                     t=self._cat(s, lambda b: b.T_box_base[:, :3, 3].numpy()).reshape(-1, 3),
                     half=self._cat(s, lambda b: b.half_size.numpy()).reshape(-1, 3),
                     bound_c=self._cat(s, lambda b: b.bound_center.numpy()).reshape(-1, 3),
                     bound_r=self._cat(s, lambda b: b.bound_radius.numpy())) for s in per_problem]
        return self._make("box", data, {"R": (3, 3), "t": (3,), "half": (3,)}, {})

    def _cylinders(self, per_problem):
        data = [dict(R=self._cat(s, lambda c: c.T_cyl_base[:, :3, :3].numpy()).reshape(-1, 3, 3),
                     t=self._cat(s, lambda c: c.T_cyl_base[:, :3, 3].numpy()).reshape(-1, 3),
                     radius=self._cat(s, lambda c: c.radius.numpy()),
                     half_length=self._cat(s, lambda c: c.half_length.numpy()),
                     capsule=self._cat(s, lambda c: np.full(len(c), float(c.capsule))),
                     bound_c=self._cat(s, lambda c: c.bound_center.numpy()).reshape(-1, 3),
                     bound_r=self._cat(s, lambda c: c.bound_radius.numpy())) for s in per_problem]
        return self._make("cylinder", data, {"R": (3, 3), "t": (3,), "radius": (), "half_length": (),
                                             "capsule": ()}, {})

    def _convex(self, per_problem, max_planes: int | None):
        data = []
        for sets in per_problem:
            planes = [part for s in sets for part in _set_fewer_planes(s, max_planes)]
            data.append(dict(planes=planes, bound_c=self._cat(sets, lambda c: c.bound_center.numpy()).reshape(-1, 3),
                             bound_r=self._cat(sets, lambda c: c.bound_radius.numpy())))
        k = max([len(p) for d in data for p in d["planes"]] + [1])
        for d in data:
            padded = np.zeros((len(d["planes"]), k, 4))
            padded[:, :, 3] = 1e9  # padding planes never bind: n = 0, d huge
            for i, p in enumerate(d["planes"]):
                padded[i, : len(p)] = p
            d["planes"] = padded
        kind = self._make("convex", data, {"planes": (k, 4)}, {"planes": 0.0})
        if kind is not None:
            kind.reduced = max_planes is not None
        return kind

    def _grids(self, clouds: list[list[PointCloudField]], resolution: float) -> None:
        self.grid = None
        if not any(clouds):
            return
        grids = []
        for fields in clouds:
            if not fields:
                grids.append((np.zeros(3), np.full((2, 2, 2), FAR)))  # no cloud: nothing near
                continue
            # Built once per set of fields (a plan's world is asked again by later plans).
            cache = fields[0].__dict__.setdefault("_torch_grids", {})
            key = (resolution, tuple(id(f) for f in fields))
            if key not in cache:
                field = fields[0] if len(fields) == 1 else PointCloudField(  # several clouds: one field
                    np.concatenate([f.centers for f in fields]), fields[0].voxel)
                cache[key] = _grid_from_cloud(field, resolution)
            grids.append(cache[key])
        shape = np.max([g[1].shape for g in grids], axis=0)
        values = np.full((len(grids),) + tuple(shape), GRID_TRUNCATION)
        for i, (_, v) in enumerate(grids):
            values[i] = v.max()  # beyond a smaller grid: as far as its truncation (or FAR: no cloud)
            values[i, : v.shape[0], : v.shape[1], : v.shape[2]] = v
        self._set_grid(torch.as_tensor(values, device=self.device, dtype=self.dtype), np.stack([g[0] for g in grids]),
                       (shape - 1) * resolution)

    def _set_grid(self, values: torch.Tensor, origin: np.ndarray, span: np.ndarray) -> None:
        """The grids ``grid_distance`` reads: ``values`` (P, nx, ny, nz) with vertex 0 at ``origin``
        (P, 3), the last ``span`` (3,) beyond it."""
        # grid_sample reads (N, C, D, H, W) with sample coordinates ordered (W, H, D) = (x, y, z).
        self.grid = values.permute(0, 3, 2, 1)[:, None].contiguous()
        self.grid_origin = torch.as_tensor(np.asarray(origin), device=self.device, dtype=self.dtype)
        self.grid_span = torch.as_tensor(np.asarray(span), device=self.device, dtype=self.dtype)

    # -- queries --------------------------------------------------------------------------
    def grid_distance(self, points: torch.Tensor) -> torch.Tensor:
        """(P, N) interpolated point-cloud distance, exact to about a cell up to
        GRID_TRUNCATION, at least that beyond (FAR for problems without a cloud)."""
        u = 2 * (points - self.grid_origin[:, None]) / self.grid_span - 1  # (P, N, 3) in [-1, 1]
        out = F.grid_sample(self.grid, u[:, None, None], mode="bilinear", padding_mode="border", align_corners=True)
        return out[:, 0, 0, 0]  # outside the grid: the border's value, >= the truncation

    def pairs(self, points: torch.Tensor, horizon: float, radii: torch.Tensor | None = None,
              groups: "SphereGroups | None" = None, ordered: bool = True
              ) -> list[tuple[torch.Tensor | None, torch.Tensor]]:
        """Per obstacle kind: (flat point index or None for one value per point, distance);
        ``ordered=False``: each kind's pairs in any order."""
        prepared = groups.prepare(points.detach(), radii) if groups is not None and self.kinds else None
        out = [kind.pairs(points, horizon, radii, groups, prepared, ordered) for kind in self.kinds]
        if self.grid is not None:
            out.append((None, self.grid_distance(points).reshape(-1)))
        return out

    def distance(self, points: torch.Tensor, horizon: float = 0.2, groups: "SphereGroups | None" = None
                 ) -> torch.Tensor:
        """Signed distance (P, N) of points (P, N, 3) to the nearest obstacle of their problem."""
        P, N, _ = points.shape
        out = torch.full((P * N,), FAR, device=points.device, dtype=points.dtype)
        # The smallest value does not depend on the pairs' order: no sort.
        for idx, d in self.pairs(points, horizon, groups=groups, ordered=False):
            out = torch.minimum(out, d) if idx is None else out.scatter_reduce(0, idx, d, reduce="amin")
        return out.reshape(P, N)

    def penalty(self, points: torch.Tensor, radii: torch.Tensor, eta: float,
                groups: "SphereGroups | None" = None, cache: "PairCache | None" = None) -> torch.Tensor:
        """(P, N): sum over obstacles of ``collision_cost(distance - radius, eta)`` per sphere
        of centre ``points`` (P, N, 3) and radius ``radii`` (P, N). With ``cache`` (and
        ``groups``), the broad phase's pairs are reused across calls (``PairCache``): the same
        values."""
        P, N, _ = points.shape
        r = radii.reshape(-1)
        out = torch.zeros(P * N, device=points.device, dtype=points.dtype)
        if (cache is not None and groups is not None) or points.requires_grad:
            if cache is not None and groups is not None:
                found = cache.candidates(self, groups, points.detach(), radii.reshape(P, N), eta)
            else:
                prepared = groups.prepare(points.detach(), radii.reshape(P, N)) if groups is not None else None
                found = [kind.candidates(points, eta, radii.reshape(P, N), groups, prepared) for kind in self.kinds]
            if points.requires_grad and MEASURE_NEAR_FIRST:  # differentiate only the pairs that cost
                found = [kind.near(points, radii, eta, *pno) for kind, pno in zip(self.kinds, found)]
            pairs = [kind.pair_distances(points, *pno) for kind, pno in zip(self.kinds, found)]
            if self.grid is not None:
                pairs.append((None, self.grid_distance(points).reshape(-1)))
        else:
            pairs = self.pairs(points, eta, radii.reshape(P, N), groups)
        for idx, d in pairs:
            if idx is None:
                out = out + collision_cost(d - r, eta)
            else:
                out = out.index_add(0, idx, collision_cost(d - r[idx], eta))
        return out.reshape(P, N)


class SphereGroups:
    """A two-level broad phase for points that come in fixed groups: the points (P, N, 3)
    are (P, C, S, 3), C configurations of S spheres, sphere s in group ``group_of[s]`` (the
    robot's spheres by link). Per configuration and group: the centre (the mean of its
    members) and a radius that holds every member sphere (computed from the points, so it
    needs no rigid-link assumption); an obstacle whose bounding sphere is beyond
    ``horizon`` of a group's sphere is beyond it for every member, so only the members of
    groups near an obstacle are tested sphere by sphere. The pairs are those of the flat
    test (up to float rounding at the horizon, where the cost is zero)."""

    SLACK = 1e-5  # m: the group test is widened by this (float rounding of the triangle inequality)

    def __init__(self, group_of: np.ndarray, device=None, dtype=torch.float32):
        group_of = np.asarray(group_of, dtype=np.int64)
        self.S, self.G = len(group_of), int(group_of.max()) + 1
        members = [np.flatnonzero(group_of == g) for g in range(self.G)]
        self.table = torch.as_tensor(_pad(members, 0, ()).astype(np.int64), device=device)  # (G, W)
        self.valid = torch.as_tensor(_pad([np.ones(len(m)) for m in members], 0, ()) > 0, device=device)
        mean = np.zeros((self.G, self.S))
        for g, m in enumerate(members):
            mean[g, m] = 1.0 / len(m)
        self.mean = torch.as_tensor(mean, device=device, dtype=dtype)

    def prepare(self, points: torch.Tensor, radii: torch.Tensor | None) -> tuple[torch.Tensor, ...]:
        """Per configuration and group of ``points`` (P, N, 3): the group's centre (P, C, G, 3),
        each member's reach from it (P, C, G, W: distance + radius) and the largest (P, C, G);
        what ``candidates`` needs for every obstacle kind."""
        P, N, _ = points.shape
        S, G = self.S, self.G
        C = N // S
        x = points.reshape(P, C, S, 3)
        centre = torch.einsum("gs,pcsi->pcgi", self.mean, x)  # (P, C, G, 3)
        flat_table = self.table.reshape(-1)
        member = (x.index_select(2, flat_table).reshape(P, C, G, -1, 3) - centre[:, :, :, None]).norm(dim=-1)
        if radii is not None:
            member = member + radii.reshape(P, C, S).index_select(2, flat_table).reshape(P, C, G, -1)
        reach = member.masked_fill(~self.valid, -FAR).amax(dim=3)  # (P, C, G)
        return centre, member, reach

    def candidates(self, points: torch.Tensor, radii: torch.Tensor | None, kind: "_Primitives",
                   horizon: float, prepared: tuple | None = None, ordered: bool = True
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(p, n, o) of the (point, obstacle) pairs within ``horizon`` (bounding spheres)
        whose obstacle is within ``horizon`` of the point's group sphere (exact distance),
        ordered by point, then obstacle (``ordered=False``: in any order). The pairs the second
        test drops are beyond ``horizon`` by their exact distance too (it is 1-Lipschitz), so
        their cost and its gradient are zero."""
        bound_c, bound_r = kind.bound_c, kind.bound_r
        P, N, _ = points.shape
        S, G = self.S, self.G
        C = N // S
        O = bound_c.shape[1]
        centre, member, reach = prepared if prepared is not None else self.prepare(points, radii)
        coarse = torch.cdist(centre.reshape(P, C * G, 3), bound_c) - bound_r[:, None, :] - reach.reshape(P, -1, 1)
        p, cg, o = torch.nonzero(coarse < horizon + self.SLACK, as_tuple=True)
        group_reach = reach.reshape(P * C * G).index_select(0, p * (C * G) + cg)
        exact = kind.exact(centre.reshape(P * C * G, 3).index_select(0, p * (C * G) + cg), p, o)
        near = exact - group_reach < horizon + self.SLACK
        p, cg, o, exact = p[near], cg[near], o[near], exact[near]
        c, g = cg // G, cg % G
        # A member is as far from the obstacle as the group's centre, less its own reach
        # (1-Lipschitz): the members beyond ``horizon`` by that bound are dropped too.
        own = member.reshape(P * C * G, -1).index_select(0, p * (C * G) + cg)  # (F, W)
        keep = self.valid.index_select(0, g) & (exact[:, None] - own < horizon + self.SLACK)
        pn = ((p * N + c * S)[:, None] + self.table.index_select(0, g))[keep]
        po = (p * O + o)[:, None].expand_as(keep)[keep]
        d = ((points.reshape(P * N, 3).index_select(0, pn) - bound_c.reshape(P * O, 3).index_select(0, po)).norm(dim=1)
             - bound_r.reshape(P * O).index_select(0, po))
        if radii is not None:
            d = d - radii.reshape(P * N).index_select(0, pn)
        near = d < horizon
        key = pn[near] * O + (po[near] % O)  # the flat test's order: problem, point, obstacle
        if ordered:  # (else the caller sorts fewer pairs later, or needs no order)
            key = key.sort().values
        pn, o = key // O, key % O
        return pn // N, pn % N, o


class PairCache:
    """The broad phase's pairs kept across calls on configurations that move a little (an
    optimiser's iterations): found with the horizon widened by ``slack`` and reused for a
    configuration while none of its spheres is more than ``slack`` from where it was tested.
    A pair left out was beyond ``horizon + slack`` by its exact distance (the tests are
    conservative, the distance 1-Lipschitz), so it is still beyond ``horizon``: its cost and
    gradient are zero. The pairs kept are ordered as ``SphereGroups.candidates`` orders them,
    so the summed costs and gradients are bitwise those of a fresh broad phase; only the
    configurations that moved farther are searched again. For one set of points (the same
    shape, groups, radii and world on every call)."""

    def __init__(self, slack: float = 0.03):
        self.slack = slack
        self.ref: torch.Tensor | None = None  # (P, C, S, 3) where each configuration was tested
        self.keys: list[torch.Tensor] = []  # per obstacle kind: sorted (p * N + n) * O + o
        self.searches = 0  # configurations searched (a count for tests and profiles)
        self.self_ref: torch.Tensor | None = None  # (M, S, 3), for the self-collision pairs
        self.self_key: torch.Tensor | None = None
        self.exact_filter = True  # keep only the pairs within the widened horizon by their exact distance

    def self_keys(self, robot: "TorchRobot", c: torch.Tensor, within: float) -> torch.Tensor:
        """``robot.self_keys(c, within, within)`` of configurations ``c`` (M, S, 3) (and some
        pairs beyond ``within``): a pair's distance changes by at most twice the farthest
        move of a sphere, so pairs are searched within ``within + 2 slack``."""
        wide = within + 2 * self.slack
        if self.self_ref is None or self.self_ref.shape != c.shape:
            self.self_key = robot.self_keys(c, wide, wide)
            self.self_ref = c.clone()
            return self.self_key
        moved = (c - self.self_ref).norm(dim=2).amax(dim=1) > self.slack - SphereGroups.SLACK  # (M,)
        m = torch.nonzero(moved, as_tuple=True)[0]
        if len(m):
            LP, W = robot.pair_valid.shape
            new = robot.self_keys(c.index_select(0, m), wide, wide)
            row = new // (LP * W)
            new = (m.index_select(0, row) * LP * W) + new % (LP * W)
            old = self.self_key[~moved.index_select(0, self.self_key // (LP * W))]
            self.self_key = torch.cat([old, new]).sort().values
            self.self_ref[m] = c.index_select(0, m)
        return self.self_key

    def _near(self, kind: _Primitives, points, radii, wide: float, p, n, o):
        """The pairs nearer than ``wide`` by their exact distance (``_Primitives.near``): a
        pair beyond it stays beyond ``horizon`` until a sphere moves ``slack`` (the distance
        is 1-Lipschitz), so the cache keeps fewer pairs to measure every call."""
        return kind.near(points, radii, wide, p, n, o) if self.exact_filter else (p, n, o)

    def candidates(self, world: "TorchWorld", groups: SphereGroups, points: torch.Tensor, radii: torch.Tensor,
                   horizon: float) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Per obstacle kind of ``world``: (p, n, o) of every pair ``groups.candidates`` gives
        within ``horizon`` (and some beyond it), ordered by point, then obstacle."""
        P, N, _ = points.shape
        S = groups.S
        C = N // S
        x = points.reshape(P, C, S, 3)
        wide = horizon + self.slack
        # The broad phase's pairs unordered: the kept keys are sorted after the exact filter (fewer).
        if self.ref is None or self.ref.shape != x.shape:
            prepared = groups.prepare(points, radii)
            found = [self._near(kind, points, radii, wide,
                                *groups.candidates(points, radii, kind, wide, prepared, ordered=False))
                     for kind in world.kinds]
            self.keys = [((p * N + n) * kind.O + o).sort().values for kind, (p, n, o) in zip(world.kinds, found)]
            self.ref = x.clone()
            self.searches += P * C
            return self._decode(world, N)
        # Float rounding of the displacement: a configuration is searched again a little early.
        moved = (x - self.ref).norm(dim=3).amax(dim=2) > self.slack - groups.SLACK  # (P, C)
        p_moved, c_moved = torch.nonzero(moved, as_tuple=True)
        if len(p_moved):
            self.searches += len(p_moved)
            # The moved configurations, packed per problem (padding far from everything).
            counts = torch.bincount(p_moved, minlength=P)
            K = int(counts.max())
            rank = torch.arange(len(p_moved), device=x.device) - (torch.cumsum(counts, 0) - counts)[p_moved]
            sub = torch.full((P, K, S, 3), -_FAR_CENTER, device=x.device, dtype=x.dtype)
            sub[p_moved, rank] = x[p_moved, c_moved]
            sub_r = torch.zeros((P, K, S), device=x.device, dtype=x.dtype)
            sub_r[p_moved, rank] = radii.reshape(P, C, S)[p_moved, c_moved]
            config = torch.zeros((P, K), device=x.device, dtype=torch.long)
            config[p_moved, rank] = c_moved
            sub, sub_r = sub.reshape(P, K * S, 3), sub_r.reshape(P, K * S)
            prepared = groups.prepare(sub, sub_r)
            stale = moved.reshape(-1)
            for i, kind in enumerate(world.kinds):
                p, n, o = self._near(kind, sub, sub_r, wide,
                                     *groups.candidates(sub, sub_r, kind, wide, prepared, ordered=False))
                n = config[p, n // S] * S + n % S
                old = self.keys[i]
                old = old[~stale.index_select(0, old // (kind.O * S))]
                self.keys[i] = torch.cat([old, (p * N + n) * kind.O + o]).sort().values
            self.ref[p_moved, c_moved] = x[p_moved, c_moved]
        return self._decode(world, N)

    def _decode(self, world: "TorchWorld", N: int) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """(p, n, o) per obstacle kind of the sorted keys."""
        out = []
        for kind, key in zip(world.kinds, self.keys):
            pn, o = key // kind.O, key % kind.O
            out.append((pn // N, pn % N, o))
        return out


def collision_cost(d: torch.Tensor, eta: float) -> torch.Tensor:
    """CHOMP's / cuRobo's smooth obstacle cost of a signed distance: 0 beyond ``eta``,
    quadratic in (0, eta], linear (slope 1) in penetration."""
    return torch.where(d <= 0, -d + 0.5 * eta,
                       torch.where(d <= eta, (d - eta) ** 2 / (2 * eta), torch.zeros_like(d)))


class TorchRobot:
    """The Panda's spheres on a device, for ``P`` problems at once.

    Per problem (from its ``CollisionChecker``): finger opening, the links checked against
    the world (``ignore_links``), the carried object's spheres. Spheres a problem does not
    check get radius -1 m (they never come near anything).
    """

    def __init__(self, robot: PandaModel, checkers: Sequence[CollisionChecker], device=None,
                 dtype=torch.float32):
        self.robot, self.device, self.dtype = robot, torch.device(device or "cpu"), dtype
        dd = dict(device=self.device, dtype=dtype)
        self.fk = robot.fk.to(self.device, dtype)
        sp = robot.spheres
        self.links = sp.links
        self.link_index = torch.as_tensor(sp.link_index, device=self.device)
        self.centers_link = torch.as_tensor(sp.centers_link, **dd)
        self.radii = torch.as_tensor(sp.radii, **dd)
        self.groups = SphereGroups(sp.link_index, self.device, dtype)  # the world broad phase, link by link
        assert (np.diff(sp.link_index) >= 0).all()  # spheres are stored link by link
        table, valid = self.groups.table.cpu().numpy(), self.groups.valid.cpu().numpy()
        self.centers_link_padded = torch.as_tensor(sp.centers_link[table] * valid[..., None], **dd)  # (L, W, 3)
        self.sphere_slots = torch.as_tensor(np.flatnonzero(valid.reshape(-1)), device=self.device)
        self.P = len(checkers)
        self.finger = torch.as_tensor([c.finger for c in checkers], **dd)
        self.margin = torch.as_tensor([c.margin for c in checkers], **dd)
        # Gripper joint values (P, G), once: computing them reads the finger openings back to
        # the host (not capturable in a CUDA graph, and a sync per call on a GPU).
        self.gripper = robot.gripper_q(self.finger)
        world_mask = torch.stack([c.world_mask for c in checkers]).to(self.device)
        self.world_radii = torch.where(world_mask, self.radii, torch.full_like(self.radii, -1.0))  # (P, S)
        self._init_self_pairs(robot)
        # Carried objects, padded: centres at the hand origin, radius -1.
        atts = [c.attachment for c in checkers]
        self.att_c = torch.as_tensor(_pad([a.centers_hand if a else np.zeros((0, 3)) for a in atts], 0.0, (3,)), **dd)
        self.att_r = torch.as_tensor(_pad([a.radii if a else np.zeros(0) for a in atts], -1.0, ()), **dd)
        self.has_attachment = any(a is not None for a in atts)
        arm = robot.sphere_mask(robot.proximal_links)
        self.att_arm = torch.as_tensor(np.flatnonzero(arm), device=self.device)

    def spheres(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Robot sphere centres (P, B, S, 3) and carried-object centres (P, B, M, 3) or None,
        for configurations ``q`` (P, B, 7)."""
        P, B, _ = q.shape
        gripper = self.gripper.to(q)  # (P, G)
        G = gripper.shape[1]
        poses = self.fk.forward(torch.cat([q, gripper[:, None].expand(P, B, G)], dim=2).reshape(P * B, 7 + G))
        T = torch.stack([poses[l] for l in self.links], dim=1)  # (PB, L, 4, 4)
        # Per link, its spheres (padded (L, W)), then the valid ones in sphere order (link-major).
        centers = torch.einsum("nlij,lwj->nlwi", T[..., :3, :3], self.centers_link_padded) + T[..., None, :3, 3]
        centers = centers.flatten(1, 2).index_select(1, self.sphere_slots)
        att = None
        if self.has_attachment:
            H = poses[self.robot.hand_link].reshape(P, B, 4, 4)
            att = torch.einsum("pbij,pmj->pbmi", H[..., :3, :3], self.att_c) + H[..., None, :3, 3]
        return centers.reshape(P, B, -1, 3), att

    def _init_self_pairs(self, robot: PandaModel) -> None:
        """Self-collision sphere pairs grouped by link pair (a padded table), and each link's
        bounding sphere (about the mean of its sphere centres), for a broad phase."""
        sp = robot.spheres
        la = sp.link_index[robot.self_collision_pairs[:, 0]]
        lb = sp.link_index[robot.self_collision_pairs[:, 1]]
        link_pairs = sorted(set(zip(la.tolist(), lb.tolist())))
        blocks = [robot.self_collision_pairs[(la == a) & (lb == b)] for a, b in link_pairs]
        table = _pad(blocks, 0, (2,)).astype(np.int64)
        valid = _pad([np.ones(len(b)) for b in blocks], 0, ()) > 0
        self.link_pairs = torch.as_tensor(np.asarray(link_pairs, dtype=np.int64).reshape(-1, 2), device=self.device)
        self.pair_table = torch.as_tensor(table, device=self.device)
        self.pair_valid = torch.as_tensor(valid, device=self.device)
        L = len(sp.links)
        mean = np.zeros((L, len(sp.radii)))
        bound_r = np.zeros(L)
        for l in range(L):
            members = np.flatnonzero(sp.link_index == l)
            mean[l, members] = 1.0 / len(members)
            c = sp.centers_link[members].mean(axis=0)
            bound_r[l] = (np.linalg.norm(sp.centers_link[members] - c, axis=1) + sp.radii[members]).max()
        self.link_mean = torch.as_tensor(mean, device=self.device, dtype=self.dtype)
        self.link_bound_r = torch.as_tensor(bound_r, device=self.device, dtype=self.dtype)

    def self_keys(self, c: torch.Tensor, horizon: float, within: float | None = None) -> torch.Tensor:
        """The self-collision sphere pairs of configurations ``c`` (M, S, 3) whose links'
        bounding spheres are within ``horizon`` (and, with ``within``, whose own distance is
        below it) as sorted keys ``(m * link pairs + link pair) * W + slot`` (``pair_key``)."""
        return self._self_keys(c, horizon, within)[0]

    def _self_keys(self, c: torch.Tensor, horizon: float, within: float | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``self_keys`` and, with ``within``, the kept pairs' distances (measured without gradients)."""
        S = c.shape[1]
        LP, W = self.pair_valid.shape
        d = None
        with torch.no_grad():
            bound = torch.einsum("ls,nsi->nli", self.link_mean, c)
            a, b = self.link_pairs[:, 0], self.link_pairs[:, 1]
            clear = (bound[:, a] - bound[:, b]).norm(dim=2) - self.link_bound_r[a] - self.link_bound_r[b]
            n, lp = torch.nonzero(clear < horizon, as_tuple=True)
            valid = self.pair_valid[lp]  # (F, W)
            key = ((n * LP + lp)[:, None] * W + torch.arange(W, device=c.device))[valid]
            if within is not None:
                n, sa, sb = self.pair_key(key)
                flat = c.reshape(-1, 3)
                d = _smooth_norm(flat.index_select(0, n * S + sa) - flat.index_select(0, n * S + sb)) \
                    - self.radii.index_select(0, sa) - self.radii.index_select(0, sb)
                near = d < within
                key, d = key[near], d[near]
        return key, d

    def pair_key(self, key: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(configuration, sphere a, sphere b) of ``self_keys``' keys."""
        LP, W = self.pair_valid.shape
        row, slot = key // W, key % W
        lp = row % LP
        return row // LP, self.pair_table[lp, slot, 0], self.pair_table[lp, slot, 1]

    def self_pairs(self, centers: torch.Tensor, horizon: float, within: float | None = None,
                   cache: "PairCache | None" = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(flat configuration index into P*B, signed distance) of the self-collision sphere
        pairs whose links' bounding spheres are within ``horizon``; with ``within``, only the
        pairs whose own distance is below it (measured without gradients first, so that the
        differentiable part is the few pairs that matter: the same values, in the same order);
        ``cache`` (with ``within``) keeps them between calls (``PairCache``)."""
        S = centers.shape[-2]
        c = centers.reshape(-1, S, 3)
        if cache is not None and within is not None:
            n, sa, sb = self.pair_key(cache.self_keys(self, c.detach(), within))
            if c.requires_grad and MEASURE_NEAR_FIRST:  # the cache's pairs reach farther than ``within``
                with torch.no_grad():
                    keep = torch.nonzero(self._pair_distance(c.detach(), n, sa, sb) < within, as_tuple=True)[0]
                n, sa, sb = n.index_select(0, keep), sa.index_select(0, keep), sb.index_select(0, keep)
        elif within is not None and not c.requires_grad:  # the distances the search measured
            key, d = self._self_keys(c, horizon, within)
            return self.pair_key(key)[0], d
        else:
            n, sa, sb = self.pair_key(self.self_keys(c.detach(), horizon, within))
        return n, self._pair_distance(c, n, sa, sb)

    def _pair_distance(self, c: torch.Tensor, n: torch.Tensor, sa: torch.Tensor, sb: torch.Tensor) -> torch.Tensor:
        """Signed distances of sphere ``sa`` to sphere ``sb`` of configuration ``n`` of ``c`` (M, S, 3)."""
        S = c.shape[1]
        flat = c.reshape(-1, 3)  # rows by one index_select each: advanced indexing's backward is slower
        return _smooth_norm(flat.index_select(0, n * S + sa) - flat.index_select(0, n * S + sb)) \
            - self.radii.index_select(0, sa) - self.radii.index_select(0, sb)

    def self_distance(self, centers: torch.Tensor, horizon: float = 0.05) -> torch.Tensor:
        """(P, B) smallest self-collision sphere-pair distance (>= ``horizon`` where no
        link pair is that near)."""
        P, B = centers.shape[:2]
        n, d = self.self_pairs(centers, horizon)
        out = torch.full((P * B,), FAR, device=centers.device, dtype=centers.dtype)
        return out.scatter_reduce(0, n, d, reduce="amin").reshape(P, B)

    def attachment_arm_distance(self, centers: torch.Tensor, att: torch.Tensor) -> torch.Tensor:
        """(P, B, M, A) carried-object sphere vs arm sphere signed distances."""
        arm = centers[:, :, self.att_arm]  # (P, B, A, 3)
        d = _smooth_norm(att[:, :, :, None] - arm[:, :, None])
        return d - self.att_r[:, None, :, None] - self.radii[self.att_arm]

    def clearance(self, q: torch.Tensor, world: TorchWorld, horizon: float = 0.2,
                  self_tolerance: float = 0.0) -> torch.Tensor:
        """(P, B) smallest signed clearance (world, sphere self-collision, carried object),
        as ``CollisionChecker.clearance`` with ``exact_self_collision=False``; self-collision
        sphere overlap up to ``self_tolerance`` is allowed."""
        P, B, _ = q.shape
        centers, att = self.spheres(q)
        S = centers.shape[2]
        d = world.distance(centers.reshape(P, B * S, 3), horizon, self.groups).reshape(P, B, S) - self.world_radii[:, None]
        clear = torch.minimum(d.amin(dim=2), self.self_distance(centers, horizon) + self_tolerance)
        if att is not None:
            M = att.shape[2]
            d_att = world.distance(att.reshape(P, B * M, 3), horizon).reshape(P, B, M) - self.att_r[:, None]
            clear = torch.minimum(clear, d_att.amin(dim=2))
            clear = torch.minimum(clear, self.attachment_arm_distance(centers, att).flatten(2).amin(dim=2))
        return clear
