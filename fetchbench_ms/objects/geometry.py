"""Convex pieces and the checks every object must pass.

Objects are unions of convex, watertight parts because that is what PhysX simulates
for dynamic bodies (a triangle mesh on a dynamic body does not collide). The builders
here make such parts from a few numbers: convex hulls of point sets (qhull through
trimesh, deterministic for the same input), so a part is convex by construction.

The limits are those of the benchmark: the Franka hand opens 8 cm, objects weigh at
most ~1 kg at the densest material the env samples (400 kg/m^3), and stand under
25 cm in every dimension. PhysX cooks a convex part only when it is not degenerate,
not thinner than ~2 mm and not more oblong than 64:1 (GPU PhysX rejects those).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
import trimesh

#: Largest bounding-box extent of any object, m.
MAX_EXTENT = 0.25
#: Densest material the env samples, kg/m^3 (FetchBench: U(100, 400)).
MAX_DENSITY = 400.0
#: Heaviest object at MAX_DENSITY, kg.
MAX_MASS = 1.0
#: Some cross-section must be at most this wide to fit the 8 cm hand with 4 mm to spare
#: on each side, m (the YCB apple, orange and cracker box are 7.1-7.2 cm).
MAX_GRASP_WIDTH = 0.072
#: Thinnest convex part PhysX cooks reliably, m.
MIN_PART_WIDTH = 0.002
#: Most oblong convex part (longest extent over thinnest width).
MAX_PART_ASPECT = 64.0
#: Most convex parts per object: each becomes a PhysX shape of a dynamic body.
MAX_PARTS = 48
#: A part must hold at least this share of an object's volume to count as a grasp
#: handle in ``grasp_width`` (so a tiny knob does not make a large object "graspable").
GRASP_PART_MIN_SHARE = 0.02


def hull(points: np.ndarray) -> trimesh.Trimesh:
    """Convex hull of ``points`` as a watertight mesh with outward normals.

    Calls qhull (scipy) directly: ``trimesh``'s ``convex_hull`` gives the same mesh but
    spends ~15 ms per call re-validating it, ~30x qhull's own time, and the catalog
    takes tens of thousands of hulls. Degenerate (flat) input raises ValueError."""
    from scipy.spatial import ConvexHull, QhullError

    points = np.asarray(points, dtype=np.float64)
    try:
        qh = ConvexHull(points, qhull_options="Qt")
    except (QhullError, ValueError) as error:
        raise ValueError(f"degenerate point set for a convex hull ({len(points)} points): {str(error).splitlines()[0]}") from None
    used = np.unique(qh.simplices)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    faces = remap[qh.simplices]
    vertices = points[used]
    # qhull's facet equations hold outward normals: wind every triangle to agree.
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    flip = np.einsum("ij,ij->i", normals, qh.equations[:, :3]) < 0.0
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def ellipse_points(rx: float, ry: float, z: float, n: int, cx: float = 0.0, cy: float = 0.0) -> np.ndarray:
    angles = np.arange(n) * (2.0 * np.pi / n)
    return np.stack([cx + rx * np.cos(angles), cy + ry * np.sin(angles), np.full(n, z)], axis=1)


def frustum(r_bottom: float, r_top: float, z_bottom: float, z_top: float, n: int = 24, squash: float = 1.0) -> trimesh.Trimesh:
    """Solid of two horizontal ellipses (radius r in x, r * squash in y)."""
    return hull(
        np.concatenate(
            [
                ellipse_points(r_bottom, r_bottom * squash, z_bottom, n),
                ellipse_points(r_top, r_top * squash, z_top, n),
            ]
        )
    )


def stacked_profile(profile: Sequence[tuple[float, float]], n: int = 24, squash: float = 1.0) -> list[trimesh.Trimesh]:
    """A solid of revolution from (z, r) samples, bottom to top: one frustum per interval.

    Each frustum is convex; their union follows a profile that need not be (a bottle's
    neck is narrower than its body)."""
    return [
        frustum(r0, r1, z0, z1, n=n, squash=squash)
        for (z0, r0), (z1, r1) in zip(profile[:-1], profile[1:])
    ]


def shell_of_revolution(
    outer: Sequence[tuple[float, float]],
    thickness: float,
    sectors: int,
    arc_samples: int = 3,
) -> list[trimesh.Trimesh]:
    """A thin wall of revolution (cup, bowl, mug body) as ring-sector pieces.

    ``outer`` gives (z, r) of the outer surface bottom to top; the inner surface lies
    ``thickness`` further in, horizontally. Each piece spans one sector and one profile
    interval: the outer arc is sampled (``arc_samples`` points) and the inner edge is a
    chord, so the piece is convex and neighbours meet without gaps.
    """
    pieces = []
    step = 2.0 * np.pi / sectors
    for (z0, r0), (z1, r1) in zip(outer[:-1], outer[1:]):
        for k in range(sectors):
            a = k * step + np.linspace(0.0, step, arc_samples)
            pts = []
            for z, r in ((z0, r0), (z1, r1)):
                pts.append(np.stack([r * np.cos(a), r * np.sin(a), np.full(arc_samples, z)], axis=1))
                inner = max(r - thickness, 1e-4)
                ends = a[[0, -1]]
                pts.append(np.stack([inner * np.cos(ends), inner * np.sin(ends), np.full(2, z)], axis=1))
            pieces.append(hull(np.concatenate(pts)))
    return pieces


def swept_tube(path: np.ndarray, radii: Sequence[float], n: int = 12, squash: float = 1.0, up=(0.0, 0.0, 1.0)) -> list[trimesh.Trimesh]:
    """A tube along a polyline: one convex hull per pair of consecutive cross-sections.

    Cross-sections are ellipses (``radius`` by ``radius * squash``) normal to the path;
    ``up`` fixes their roll (the squashed axis lies along ``up`` x tangent)."""
    path = np.asarray(path, dtype=np.float64)
    up = np.asarray(up, dtype=np.float64)
    sections = []
    for i, centre in enumerate(path):
        tangent = path[min(i + 1, len(path) - 1)] - path[max(i - 1, 0)]
        tangent /= np.linalg.norm(tangent)
        side = np.cross(up, tangent)
        if np.linalg.norm(side) < 1e-9:
            side = np.cross([1.0, 0.0, 0.0], tangent)
        side /= np.linalg.norm(side)
        normal = np.cross(tangent, side)
        angles = np.arange(n) * (2.0 * np.pi / n)
        ring = centre + radii[i] * (np.cos(angles)[:, None] * normal + squash * np.sin(angles)[:, None] * side)
        sections.append(ring)
    return [hull(np.concatenate([a, b])) for a, b in zip(sections[:-1], sections[1:])]


def box(size: Sequence[float], center: Sequence[float] = (0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    half = np.asarray(size, dtype=np.float64) / 2.0
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
    return hull(corners * half + np.asarray(center, dtype=np.float64))


def rounded_box(size: Sequence[float], radius: float, center: Sequence[float] = (0.0, 0.0, 0.0), n: int = 6) -> trimesh.Trimesh:
    """Box with rounded vertical edges and chamfered top/bottom edges (a hull of rings)."""
    sx, sy, sz = (float(s) for s in size)
    radius = min(radius, sx / 2 - 1e-4, sy / 2 - 1e-4, sz / 2 - 1e-4)
    pts = []
    quarter = np.linspace(0.0, np.pi / 2, n)
    for z, inset in ((-sz / 2, radius * 0.4), (-sz / 2 + radius * 0.6, 0.0), (sz / 2 - radius * 0.6, 0.0), (sz / 2, radius * 0.4)):
        for qx, qy, a0 in ((1, 1, 0.0), (-1, 1, np.pi / 2), (-1, -1, np.pi), (1, -1, 1.5 * np.pi)):
            cx, cy = qx * (sx / 2 - radius), qy * (sy / 2 - radius)
            r = radius - inset
            pts.append(np.stack([cx + r * np.cos(a0 + quarter), cy + r * np.sin(a0 + quarter), np.full(n, z)], axis=1))
    return hull(np.concatenate(pts) + np.asarray(center, dtype=np.float64))


def ellipsoid(radii: Sequence[float], center: Sequence[float] = (0.0, 0.0, 0.0), subdivisions: int = 2) -> trimesh.Trimesh:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    return hull(sphere.vertices * np.asarray(radii, dtype=np.float64) + np.asarray(center, dtype=np.float64))


def transformed(mesh: trimesh.Trimesh, matrix: np.ndarray) -> trimesh.Trimesh:
    out = mesh.copy()
    out.apply_transform(matrix)
    return out


def rotation_x(angle: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, [1.0, 0.0, 0.0])


def rotation_y(angle: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, [0.0, 1.0, 0.0])


def rotation_z(angle: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, [0.0, 0.0, 1.0])


# --------------------------------------------------------------------------- checks


def min_width(points) -> float:
    """Smallest width of the convex hull of ``points`` (or of a convex mesh) over its
    face normals.

    The true minimum width of a polytope is reached along a face normal or an
    edge-edge direction; face normals alone give an upper bound that is tight for the
    shapes here (boxes, cylinders, shells) and errs on the safe side for the limits.
    """
    h = points if isinstance(points, trimesh.Trimesh) else hull(points)
    projections = h.vertices @ h.face_normals.T  # (V, F)
    return float(np.min(projections.max(axis=0) - projections.min(axis=0)))


@dataclass(frozen=True)
class PartReport:
    watertight: bool
    convex: bool
    volume: float
    min_width: float
    aspect: float

    def problems(self) -> list[str]:
        out = []
        if not self.watertight:
            out.append("not watertight")
        if not self.convex:
            out.append("not convex")
        if not self.volume > 0.0:
            out.append(f"volume {self.volume:.3g} <= 0")
        if self.min_width < MIN_PART_WIDTH:
            out.append(f"thinner than {MIN_PART_WIDTH * 1000:.0f} mm ({self.min_width * 1000:.2f} mm)")
        if self.aspect >= MAX_PART_ASPECT:
            out.append(f"more oblong than {MAX_PART_ASPECT:.0f}:1 ({self.aspect:.1f}:1)")
        return out


def thicken(part: trimesh.Trimesh, min_thickness: float = MIN_PART_WIDTH * 1.25) -> trimesh.Trimesh:
    """The part stretched about its centroid along its thinnest direction to at least
    ``min_thickness`` (scans and blobs have sliver pieces PhysX will not cook; a
    stretch by a fraction of a millimetre keeps the shape and keeps it convex)."""
    h = hull(part.vertices)
    for _ in range(3):  # a needle is thin in two directions: stretch each in turn
        projections = h.vertices @ h.face_normals.T
        widths = projections.max(axis=0) - projections.min(axis=0)
        k = int(np.argmin(widths))
        if widths[k] >= min_thickness:
            break
        normal = h.face_normals[k]
        stretch = np.eye(3) + (min_thickness / max(widths[k], 1e-6) - 1.0) * np.outer(normal, normal)
        centre = h.vertices.mean(axis=0)
        h = hull((h.vertices - centre) @ stretch.T + centre)
    return h


def check_part(part: trimesh.Trimesh, topology: bool = True) -> PartReport:
    """Measure one part. ``topology=False`` skips the (slow) watertight and convexity
    tests for parts made by ``hull``, which are both by construction."""
    width = min_width(part)
    longest = float(np.max(part.extents))
    return PartReport(
        watertight=bool(part.is_watertight) if topology else True,
        convex=bool(part.is_convex) if topology else True,
        volume=float(part.volume),
        min_width=width,
        aspect=longest / max(width, 1e-12),
    )


def grasp_width(parts: Sequence[trimesh.Trimesh]) -> float:
    """Narrowest width the hand could close across: the whole object's hull, or a part
    holding a real share of the volume (a mug's wall or handle, a bowl's rim)."""
    all_points = np.concatenate([p.vertices for p in parts])
    best = min_width(all_points)
    total = sum(float(p.volume) for p in parts)
    for p in parts:
        if float(p.volume) >= GRASP_PART_MIN_SHARE * total:
            best = min(best, min_width(p))
    return best


def limit_problems(extents: Iterable[float], volume: float, grasp_w: float, n_parts: int) -> list[str]:
    """Why an object cannot be fetched by the benchmark's robot (empty when it can)."""
    out = []
    extents = [float(e) for e in extents]
    if max(extents) > MAX_EXTENT:
        out.append(f"larger than {MAX_EXTENT} m (extents {np.round(extents, 3).tolist()})")
    if volume * MAX_DENSITY > MAX_MASS:
        out.append(f"heavier than {MAX_MASS} kg at {MAX_DENSITY:.0f} kg/m^3 ({volume * MAX_DENSITY:.2f} kg)")
    if grasp_w > MAX_GRASP_WIDTH:
        out.append(f"no cross-section narrower than {MAX_GRASP_WIDTH} m ({grasp_w:.3f} m)")
    if n_parts > MAX_PARTS or n_parts < 1:
        out.append(f"{n_parts} convex parts (1..{MAX_PARTS} allowed)")
    return out


def mass_properties(parts: Sequence[trimesh.Trimesh]) -> tuple[float, np.ndarray]:
    """Volume (sum over parts, as PhysX sums shape masses) and centre of mass at uniform density."""
    volumes = np.array([float(p.volume) for p in parts])
    centres = np.stack([p.center_mass for p in parts])
    total = float(volumes.sum())
    return total, (volumes[:, None] * centres).sum(axis=0) / total
