"""The small toolkit every furniture piece and scene type is written with.

``SceneBuilder`` collects parts and support surfaces in the scene frame (floor z = 0,
furniture at x > 0, the robot looks along +x) and turns them into a ``SceneSpec``:
it computes each surface's free height from the parts above it, the robot region from
the surfaces (the original's rule: base x = front edge of the supports minus an offset,
y = their middle plus an offset, z = the lowest support minus a drop) and the camera
target box around the surfaces.

Conventions of the pieces: a piece is placed by the middle of its front face at the
floor (or at whatever it stands on): ``x0`` front, ``y0`` centre, ``z0`` bottom; its
depth runs along +x. Boards that touch are modelled exactly flush.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Mapping

import numpy as np
import shapely
from shapely.geometry import Polygon, box as shapely_box
from shapely.geometry.polygon import orient

from ..geometry import part_aabb
from ..params import ParamSpec
from ..spec import CameraTargetRegion, Material, Part, RobotRegion, SceneSpec, SupportSurface

#: Free height reported for a surface with nothing above it (m): more than any object needs.
OPEN_FREE_HEIGHT = 0.6
#: The Franka's reach above its base (m); the robot region is clamped so the highest
#: support stays below this (with a margin) from the lowest base pose.
REACH_ABOVE_BASE = 1.3
REACH_MARGIN = 0.05
#: The robot base's radius plus a margin (m), and the height above the base its first
#: links occupy: furniture in that column in front of the base sets where the region ends.
ROBOT_CLEARANCE = 0.12
ROBOT_SHOULDER_HEIGHT = 0.4
#: Half the widest robot table of the original (y size up to 1.0 m): its top is just under
#: the base and it may reach a little in front of it.
ROBOT_TABLE_HALF_WIDTH = 0.5
#: Smallest piece of a split support polygon that is kept (m^2): smaller slivers hold no object.
MIN_SURFACE_AREA = 0.012
#: Version of the generators: bump when any type's geometry for a given seed changes.
GENERATOR_VERSION = "2"  # 2: every derived number on the 1 um grid (SceneSpec.on_grid)

IDENTITY_QUAT = (1.0, 0.0, 0.0, 0.0)


def yaw_quat(yaw: float) -> tuple[float, float, float, float]:
    """wxyz quaternion of a rotation by ``yaw`` about +z."""
    return (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))


# --------------------------------------------------------------------------- materials
#: Colour ranges (r, g, b lows/highs, roughness, metallic) per kind of material.
MATERIAL_KINDS = {
    # Light birch to dark walnut, plus painted white/black boards (IKEA's usual finishes).
    "wood": ((0.25, 0.95), (0.18, 0.85), (0.1, 0.75), (0.45, 0.9), (0.0, 0.05)),
    "paint": ((0.1, 0.95), (0.1, 0.95), (0.1, 0.95), (0.3, 0.85), (0.0, 0.15)),
    "metal": ((0.2, 0.85), (0.2, 0.85), (0.2, 0.85), (0.2, 0.6), (0.5, 1.0)),
    "wicker": ((0.45, 0.9), (0.3, 0.7), (0.15, 0.5), (0.6, 0.95), (0.0, 0.05)),
    "fabric": ((0.15, 0.9), (0.15, 0.9), (0.15, 0.9), (0.7, 1.0), (0.0, 0.02)),
    "wall": ((0.7, 0.98), (0.7, 0.98), (0.65, 0.98), (0.7, 0.95), (0.0, 0.02)),
}


def material_params(group: str, kind: str) -> tuple[ParamSpec, ...]:
    """Five parameters (RGB, roughness, metallic) of one material group."""
    if kind not in MATERIAL_KINDS:
        raise ValueError(f"unknown material kind {kind!r}; valid: {', '.join(MATERIAL_KINDS)}")
    (r, g, b, rough, metal) = MATERIAL_KINDS[kind]
    return (
        ParamSpec(f"{group}_r", *r, "1", f"red channel of the {group} material ({kind})"),
        ParamSpec(f"{group}_g", *g, "1", f"green channel of the {group} material ({kind})"),
        ParamSpec(f"{group}_b", *b, "1", f"blue channel of the {group} material ({kind})"),
        ParamSpec(f"{group}_roughness", *rough, "1", f"roughness of the {group} material"),
        ParamSpec(f"{group}_metallic", *metal, "1", f"metallic factor of the {group} material"),
    )


def material(v: Mapping[str, float], group: str) -> Material:
    return Material(
        rgba=(v[f"{group}_r"], v[f"{group}_g"], v[f"{group}_b"], 1.0),
        roughness=v[f"{group}_roughness"],
        metallic=v[f"{group}_metallic"],
    )


# --------------------------------------------------------------------------- robot region
def robot_params(
    x_gap: tuple[float, float] = (0.12, 0.18),
    x_span: tuple[float, float] = (0.03, 0.08),
    y_half: tuple[float, float] = (0.02, 0.1),
    y_shift: tuple[float, float] = (-0.05, 0.05),
    z_drop: tuple[float, float] = (0.2, 0.4),
    z_span: tuple[float, float] = (0.05, 0.15),
    yaw_half: tuple[float, float] = (0.0, 0.1),
) -> tuple[ParamSpec, ...]:
    """The robot-region offsets of one type (ranges per type, as in the original)."""
    return (
        ParamSpec("robot.x_gap", *x_gap, "m", "nearest base distance in front of the supports' front edge"),
        ParamSpec("robot.x_span", *x_span, "m", "depth of the base region along x"),
        ParamSpec("robot.y_half", *y_half, "m", "half width of the base region along y"),
        ParamSpec("robot.y_shift", *y_shift, "m", "shift of the base region from the supports' middle along y"),
        ParamSpec("robot.z_drop", *z_drop, "m", "smallest drop of the base below the lowest support"),
        ParamSpec("robot.z_span", *z_span, "m", "height span of the base region"),
        ParamSpec("robot.yaw_half", *yaw_half, "rad", "half range of the base yaw around facing +x"),
    )


# --------------------------------------------------------------------------- polygons
def rect(x0: float, x1: float, y0: float, y1: float) -> Polygon:
    return shapely_box(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1))


def simple_pieces(region, min_area: float = MIN_SURFACE_AREA) -> list[Polygon]:
    """Split ``region`` (a polygon, maybe with holes, or several) into simple polygons.

    SupportSurface polygons have no holes; a hole (e.g. a basket standing in the middle
    of a table) is cut away by splitting along the line y = hole centre, which keeps each
    piece as near to the robot as the whole (the robot looks along +x).
    """
    from shapely.ops import split
    from shapely.geometry import LineString

    todo = list(getattr(region, "geoms", [region]))
    out: list[Polygon] = []
    while todo:
        poly = todo.pop(0)
        if poly.is_empty or poly.geom_type != "Polygon" or poly.area < min_area:
            continue
        if not poly.interiors:
            out.append(orient(poly, 1.0))
            continue
        hole_y = Polygon(poly.interiors[0]).centroid.y
        x0, _, x1, _ = poly.bounds
        for piece in split(poly, LineString([(x0 - 1, hole_y), (x1 + 1, hole_y)])).geoms:
            todo.append(piece)
    return sorted(out, key=lambda p: (round(p.bounds[1], 6), round(p.bounds[0], 6)))


def polygon_coords(poly: Polygon) -> tuple[tuple[float, float], ...]:
    poly = orient(poly, 1.0)
    coords = list(poly.exterior.coords)[:-1]
    return tuple((float(x), float(y)) for x, y in coords)


# --------------------------------------------------------------------------- the builder
@dataclass
class _PendingSurface:
    name: str
    label: str
    polygon: Polygon
    height: float
    supporting_part: str
    wall_top: float | None


@dataclass
class SceneBuilder:
    """Collects parts and surfaces; ``finish`` makes the ``SceneSpec``."""

    parts: list[Part] = field(default_factory=list)
    surfaces: list[_PendingSurface] = field(default_factory=list)

    # ---- parts
    def box(self, name, size, center, mat: Material, quat=IDENTITY_QUAT, group: str = "") -> Part:
        part = Part(
            name=name,
            shape="box",
            size=tuple(float(s) for s in size),
            position=tuple(float(c) for c in center),
            quat_wxyz=tuple(float(q) for q in quat),
            material=mat,
            group=group,
        )
        self.parts.append(part)
        return part

    def box_between(self, name, lo, hi, mat: Material, group: str = "") -> Part:
        """An axis-aligned box from corner ``lo`` to corner ``hi``."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return self.box(name, hi - lo, (lo + hi) / 2, mat, group=group)

    def cylinder(self, name, radius, z_bottom, z_top, xy, mat: Material, shape="cylinder", group: str = "") -> Part:
        """A vertical cylinder (or capsule) standing from ``z_bottom`` to ``z_top``."""
        length = z_top - z_bottom
        if shape == "capsule":  # the caps are part of the height
            length -= 2 * radius
        part = Part(
            name=name,
            shape=shape,
            size=(float(radius), float(length)),
            position=(float(xy[0]), float(xy[1]), float((z_bottom + z_top) / 2)),
            material=mat,
            group=group,
        )
        self.parts.append(part)
        return part

    def prism(self, name, polygon: Polygon, z_bottom: float, z_top: float, mat: Material, group: str = "") -> Part:
        """A vertical prism over a convex polygon (a ``convex_mesh``: no primitive fits)."""
        coords = np.asarray(polygon.exterior.coords)[:-1]
        center = np.array([*coords.mean(axis=0), (z_bottom + z_top) / 2])
        half = (z_top - z_bottom) / 2
        verts = [(x - center[0], y - center[1], dz) for dz in (-half, half) for x, y in coords]
        part = Part(
            name=name,
            shape="convex_mesh",
            size=(),
            position=tuple(float(c) for c in center),
            material=mat,
            mesh_vertices=tuple(tuple(float(c) for c in v) for v in verts),
            group=group,
        )
        self.parts.append(part)
        return part

    # ---- surfaces
    def surface(self, name, label, polygon: Polygon, height, supporting_part, wall_top=None) -> None:
        """One support surface (a simple polygon); pieces with holes go through ``surface_region``."""
        self.surfaces.append(_PendingSurface(name, label, polygon, float(height), supporting_part, wall_top))

    def surface_region(self, name, label, region, height, supporting_part, wall_top=None) -> int:
        """Add every usable simple piece of ``region`` (named ``name``, ``name_1``...); returns how many."""
        pieces = simple_pieces(region)
        for i, poly in enumerate(pieces):
            self.surface(name if i == 0 else f"{name}_{i}", label, poly, height, supporting_part, wall_top)
        return len(pieces)

    # ---- the finished scene
    def _free_heights(self) -> list[float]:
        if not self.surfaces:
            return []
        bounds = np.array([part_aabb(p) for p in self.parts])  # [N, 2, 3]
        out = []
        for s in self.surfaces:
            probe = s.polygon.buffer(-0.0005, join_style="mitre")  # thinner than the checks' 1 mm tolerance
            x0, y0, x1, y1 = probe.bounds
            above = bounds[:, 0, 2] > s.height + 1e-4
            near = (bounds[:, 0, 0] < x1) & (bounds[:, 1, 0] > x0) & (bounds[:, 0, 1] < y1) & (bounds[:, 1, 1] > y0)
            free = OPEN_FREE_HEIGHT
            for i in np.nonzero(above & near)[0]:
                gap = bounds[i, 0, 2] - s.height
                if gap < free and probe.intersects(_footprint(self.parts[i])):
                    free = gap
            out.append(float(free))
        return out

    def finish(self, scene_type: str, values: Mapping[str, float]) -> SceneSpec:
        names = [p.name for p in self.parts]
        if len(set(names)) != len(names):
            dup = sorted({n for n in names if names.count(n) > 1})
            raise AssertionError(f"{scene_type}: duplicate part names {dup}")
        if not self.surfaces:
            raise AssertionError(f"{scene_type}: the generator made no support surface")
        free = self._free_heights()
        surfaces = tuple(
            SupportSurface(
                name=s.name,
                label=s.label,
                polygon_xy=polygon_coords(s.polygon),
                height=s.height,
                free_height=f,
                supporting_part=s.supporting_part,
                wall_top=None if s.wall_top is None else float(s.wall_top),
            )
            for s, f in zip(self.surfaces, free)
        )
        return SceneSpec(
            scene_type=scene_type,
            seed=None,
            params={k: values[k] for k in sorted(values)},
            parts=tuple(self.parts),
            support_surfaces=surfaces,
            robot_region=robot_region(surfaces, values, np.array([part_aabb(p) for p in self.parts])),
            camera_target=camera_target(surfaces),
            generator_version=GENERATOR_VERSION,
        )


def _footprint(part: Part) -> Polygon:
    """The part's shadow on the xy plane (exact for boxes and meshes, a polygon for round parts)."""
    T = part.transform()
    if part.shape == "convex_mesh":
        local = np.asarray(part.mesh_vertices, dtype=float)
    elif part.shape == "box":
        half = np.asarray(part.size) / 2
        local = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    else:
        radius, length = part.size
        half_z = length / 2 + (radius if part.shape == "capsule" else 0.0)
        angles = np.linspace(0, 2 * np.pi, 16, endpoint=False)
        ring = np.column_stack([radius * np.cos(angles) / np.cos(np.pi / 16), radius * np.sin(angles) / np.cos(np.pi / 16)])
        local = np.concatenate([np.column_stack([ring, np.full(16, z)]) for z in (-half_z, half_z)])
    points = local @ T[:3, :3].T + T[:3, 3]
    return shapely.MultiPoint(points[:, :2]).convex_hull


def _surface_bounds(surfaces: Iterable[SupportSurface]) -> np.ndarray:
    pts = np.concatenate([np.asarray(s.polygon_xy) for s in surfaces])
    return np.array([pts.min(axis=0), pts.max(axis=0)])


def robot_region(surfaces: tuple[SupportSurface, ...], v: Mapping[str, float], part_bounds: np.ndarray) -> RobotRegion:
    """The original's rule, from the ``robot.*`` offsets: x in front of the supports' front
    edge, y around their middle, z below the lowest one.

    Two adjustments keep it usable: x is measured from whatever furniture stands in front
    of the robot below its shoulders or beside it below its table (a desk edge in front of
    shelves standing on it, drawer handles) when that is nearer than the supports; z is clamped so the highest support
    stays within the arm's reach above the lowest base and the base stays above the floor.
    """
    (x_min, y_min), (x_max, y_max) = _surface_bounds(surfaces)
    heights = [s.height for s in surfaces]
    lowest, highest = min(heights), max(heights)
    y_mid = (y_min + y_max) / 2 + v["robot.y_shift"]
    y_lo, y_hi = y_mid - v["robot.y_half"], y_mid + v["robot.y_half"]
    z_hi = max(0.0, lowest - v["robot.z_drop"])
    z_lo = z_hi - v["robot.z_span"]
    z_lo = max(z_lo, highest - (REACH_ABOVE_BASE - REACH_MARGIN), 0.0)
    z_hi = max(z_hi, z_lo)
    # Parts in front of the base: in its column (base footprint, up to the arm's first
    # links), and in the wider box of the robot table (up to its top, just under the base).
    y_lo_part, y_hi_part = part_bounds[:, 0, 1], part_bounds[:, 1, 1]
    z_lo_part = part_bounds[:, 0, 2]
    in_way = (
        (y_lo_part < y_hi + ROBOT_CLEARANCE) & (y_hi_part > y_lo - ROBOT_CLEARANCE) & (z_lo_part < z_hi + ROBOT_SHOULDER_HEIGHT)
    ) | ((y_lo_part < y_hi + ROBOT_TABLE_HALF_WIDTH) & (y_hi_part > y_lo - ROBOT_TABLE_HALF_WIDTH) & (z_lo_part < z_hi))
    x_front = min(x_min, float(part_bounds[in_way, 0, 0].min())) if in_way.any() else x_min
    x_hi = x_front - v["robot.x_gap"]
    return RobotRegion(
        x_range=(x_hi - v["robot.x_span"], x_hi),
        y_range=(y_lo, y_hi),
        z_range=(z_lo, z_hi),
        yaw_range=(-v["robot.yaw_half"], v["robot.yaw_half"]),
    )


def camera_target(surfaces: tuple[SupportSurface, ...]) -> CameraTargetRegion:
    """The box holding every support surface and a bit of the space above it."""
    (x_min, y_min), (x_max, y_max) = _surface_bounds(surfaces)
    z_min = min(s.height for s in surfaces)
    z_max = max(s.height + min(s.free_height, 0.25) for s in surfaces)
    return CameraTargetRegion(
        center=((x_min + x_max) / 2, (y_min + y_max) / 2, (z_min + z_max) / 2),
        half_size=((x_max - x_min) / 2, (y_max - y_min) / 2, (z_max - z_min) / 2),
    )
