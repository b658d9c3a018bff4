"""Geometric checks of a generated ``SceneSpec``, used by the tests and by generator authors.

Each check returns a list of problems (human-readable strings, empty = pass), so a test
can show every defect of a scene at once:

- ``interpenetration_problems``: parts overlap by more than ~1 mm (exact fcl primitives;
  pairs inside the same non-empty ``Part.group`` are allowed to overlap).
- ``floor_problems``: a part reaches below the floor.
- ``support_problems``: every support surface lies on top of its ``supporting_part``
  (rays cast down through points of the polygon hit that part at the surface height),
  and nothing intrudes into the space above the polygon up to min(free_height, 8 cm)
  (drawer and basket walls may stand at the polygon's edges).
- ``free_height_problems``: every surface has >= 8 cm of clear space above it, and the
  space up to the free height it claims is really clear.
- ``reachability_problems``: on average over robot base poses sampled in the robot
  region, at least half of each surface's area lies in the Franka's reachable band
  (0.25-0.85 m horizontally from the base, 0.0-1.3 m above it).
- ``robot_region_problems``: no part stands where the robot base may stand.

``check_scene`` runs all of them; ``assert_scene_ok`` raises with every problem listed.
The checks are plain geometry (python-fcl, trimesh ray casts, shapely): no simulator.
"""
from __future__ import annotations

from dataclasses import dataclass

import fcl
import numpy as np
import trimesh

from .geometry import convex_fcl, fcl_object, part_aabb, part_mesh, polygon_prisms
from .spec import SceneSpec, SupportSurface

#: Overlap two parts may have (m): boards that touch are modelled flush, so anything
#: deeper than numerical noise is a modelling error.
PENETRATION_TOLERANCE = 0.001
#: How far a support polygon may sit from its part's top face (m).
SURFACE_HEIGHT_TOLERANCE = 0.002
#: Smallest clear height above a support surface (m): fits the benchmark's objects.
MIN_FREE_HEIGHT = 0.08
#: The Franka's reachable band around its base (m), as the task brief defines it.
REACH_RADIUS = (0.25, 0.85)
REACH_HEIGHT = (0.0, 1.3)
#: Share of every surface's area that must be reachable (averaged over base poses).
MIN_REACHABLE_FRACTION = 0.5
#: Drawer and basket walls may stand this far inside a support polygon's edges (m).
WALL_MARGIN = 0.005
#: Clearance kept around the robot base's footprint (m): the base link's radius is ~0.1 m.
ROBOT_BASE_RADIUS = 0.1
#: Height above the base that must be free of furniture in the robot region (m): the
#: first two links of the arm stand there.
ROBOT_BASE_HEIGHT = 0.35


@dataclass(frozen=True)
class Penetration:
    """Two parts overlapping by ``depth`` metres."""

    part_a: str
    part_b: str
    depth: float

    def __str__(self) -> str:
        return f"parts {self.part_a!r} and {self.part_b!r} interpenetrate by {self.depth * 1000:.1f} mm"


def _collision_depth(obj_a: fcl.CollisionObject, obj_b: fcl.CollisionObject) -> float:
    """Penetration depth of two fcl objects (0 when they only touch or are apart)."""
    request = fcl.CollisionRequest(num_max_contacts=8, enable_contact=True)
    result = fcl.CollisionResult()
    if fcl.collide(obj_a, obj_b, request, result) == 0:
        return 0.0
    return max((c.penetration_depth for c in result.contacts), default=0.0)


def penetrations(spec: SceneSpec, tolerance: float = PENETRATION_TOLERANCE) -> list[Penetration]:
    """Pairs of parts that overlap by more than ``tolerance``, deepest first.

    Candidate pairs are those whose bounding boxes overlap; each pair's depth comes from
    fcl's exact primitive-primitive or GJK/EPA solver.
    """
    objects = [fcl_object(p) for p in spec.parts]
    # Broad phase: axis-aligned bounds (grown by the tolerance) that overlap.
    bounds = np.array([part_aabb(p) for p in spec.parts])  # [N, 2, 3]
    low, high = bounds[:, 0] - tolerance, bounds[:, 1] + tolerance
    overlap = np.all((low[:, None] <= high[None]) & (low[None] <= high[:, None]), axis=-1)
    found: list[Penetration] = []
    for i, j in zip(*np.nonzero(np.triu(overlap, k=1))):
        a, b = spec.parts[i], spec.parts[j]
        if a.group and a.group == b.group:
            continue
        depth = _collision_depth(objects[i], objects[j])
        if depth > tolerance:
            found.append(Penetration(a.name, b.name, float(depth)))
    return sorted(found, key=lambda p: (-p.depth, p.part_a, p.part_b))


def interpenetration_problems(spec: SceneSpec, tolerance: float = PENETRATION_TOLERANCE) -> list[str]:
    return [str(p) for p in penetrations(spec, tolerance)]


def floor_problems(spec: SceneSpec, tolerance: float = PENETRATION_TOLERANCE) -> list[str]:
    problems = []
    for part in spec.parts:
        z_min = float(part_mesh(part).bounds[0, 2])
        if z_min < -tolerance:
            problems.append(f"part {part.name!r} reaches {-z_min * 1000:.1f} mm below the floor")
    return problems


def _probe_points(surface: SupportSurface, inset: float, grid: int = 7) -> np.ndarray:
    """Points (x, y) of the polygon shrunk by ``inset``: its corners and an interior grid."""
    from shapely.geometry import Point

    inner = surface.polygon.buffer(-inset, join_style="mitre")
    if inner.is_empty:
        inner = surface.polygon.buffer(-surface.polygon.length * 1e-4)
    if inner.geom_type != "Polygon":  # a pinched polygon: keep its largest piece
        inner = max(inner.geoms, key=lambda g: g.area)
    corners = np.asarray(inner.exterior.coords)[:-1]
    x0, y0, x1, y1 = inner.bounds
    xs, ys = np.meshgrid(np.linspace(x0, x1, grid), np.linspace(y0, y1, grid))
    interior = [(x, y) for x, y in zip(xs.ravel(), ys.ravel()) if inner.contains(Point(x, y))]
    rep = inner.representative_point()
    return np.vstack([corners, np.asarray(interior).reshape(-1, 2), [[rep.x, rep.y]]])


def _surface_on_part_problems(spec: SceneSpec, surface: SupportSurface, tolerance: float) -> list[str]:
    try:
        part = spec.part(surface.supporting_part)
    except KeyError:
        return [f"surface {surface.name!r}: supporting part {surface.supporting_part!r} does not exist"]
    mesh = part_mesh(part)
    points = _probe_points(surface, inset=2 * tolerance)
    # Rays start above the whole part, so they meet its top face first even when the
    # surface is wrongly placed inside the part.
    start_z = max(surface.height, float(mesh.bounds[1, 2])) + 0.01
    origins = np.column_stack([points, np.full(len(points), start_z)])
    directions = np.tile([0.0, 0.0, -1.0], (len(points), 1))
    hits, ray_ids, _ = mesh.ray.intersects_location(origins, directions, multiple_hits=False)
    top_z = np.full(len(points), np.nan)
    top_z[ray_ids] = hits[:, 2]
    problems = []
    missing = np.isnan(top_z)
    if missing.any():
        x, y = points[np.argmax(missing)]
        problems.append(
            f"surface {surface.name!r}: {int(missing.sum())}/{len(points)} points of its polygon are not above "
            f"part {part.name!r} (e.g. ({x:.3f}, {y:.3f}))"
        )
    off = np.abs(top_z - surface.height) > tolerance  # False where nothing was hit (NaN)
    if off.any():
        worst = int(np.nanargmax(np.where(off, np.abs(top_z - surface.height), -np.inf)))
        problems.append(
            f"surface {surface.name!r} at z={surface.height:.4f}: part {part.name!r}'s top under "
            f"({points[worst, 0]:.3f}, {points[worst, 1]:.3f}) is at z={top_z[worst]:.4f}"
        )
    return problems


def _intrusion_problems(
    spec: SceneSpec,
    surface: SupportSurface,
    bottom: float,
    top: float,
    depth_tolerance: float,
    wall_margin: float,
    space: str = "the space above it",
) -> list[str]:
    """Parts reaching into the polygon's prism between z = ``bottom`` and ``top``."""
    # The probe is the polygon shrunk a little (more where walls line its edges).
    inset = wall_margin if surface.wall_top is not None else depth_tolerance
    polygon = surface.polygon.buffer(-inset, join_style="mitre")
    if top <= bottom:
        return []
    prisms = polygon_prisms(polygon, bottom, top)
    if not prisms:
        return [f"surface {surface.name!r}: nothing left of its polygon after a {inset * 1000:.0f} mm inset"]
    identity = fcl.Transform(np.eye(3), np.zeros(3))
    probes = [fcl.CollisionObject(convex_fcl(p), identity) for p in prisms]
    problems = []
    for part in spec.parts:
        obj = fcl_object(part)
        depth = max(_collision_depth(obj, probe) for probe in probes)
        if depth > depth_tolerance:
            problems.append(
                f"surface {surface.name!r}: part {part.name!r} intrudes {depth * 1000:.1f} mm into "
                f"{space} (z {bottom:.3f}-{top:.3f})"
            )
    return problems


def support_problems(
    spec: SceneSpec,
    height_tolerance: float = SURFACE_HEIGHT_TOLERANCE,
    depth_tolerance: float = PENETRATION_TOLERANCE,
    wall_margin: float = WALL_MARGIN,
) -> list[str]:
    """Each surface lies on its supporting part's top face and has clear space above it."""
    problems = []
    names = [s.name for s in spec.support_surfaces]
    for name in sorted({n for n in names if names.count(n) > 1}):
        problems.append(f"support surface name {name!r} is used more than once")
    for surface in spec.support_surfaces:
        if not surface.polygon.is_valid:
            problems.append(f"surface {surface.name!r}: polygon is not valid (self-intersecting?)")
            continue
        problems += _surface_on_part_problems(spec, surface, height_tolerance)
        # The space objects need, from 1 mm above the surface.
        top = surface.height + min(surface.free_height, MIN_FREE_HEIGHT)
        problems += _intrusion_problems(spec, surface, surface.height + depth_tolerance, top, depth_tolerance, wall_margin)
        if surface.wall_top is not None and surface.wall_top <= surface.height:
            problems.append(f"surface {surface.name!r}: wall top {surface.wall_top:.3f} is not above it")
    if not spec.support_surfaces:
        problems.append("the scene has no support surface")
    return problems


def free_height_problems(
    spec: SceneSpec,
    min_free_height: float = MIN_FREE_HEIGHT,
    depth_tolerance: float = PENETRATION_TOLERANCE,
    wall_margin: float = WALL_MARGIN,
) -> list[str]:
    """Every surface has >= ``min_free_height`` of space, and the free height it claims is
    really clear (above the first 8 cm, which ``support_problems`` covers) up to 1 mm
    below its end: task samplers trust it to fit objects."""
    problems = []
    for s in spec.support_surfaces:
        if s.free_height < min_free_height:
            problems.append(f"surface {s.name!r}: free height {s.free_height:.3f} m < {min_free_height} m")
        if not s.polygon.is_valid:
            continue  # support_problems reports it
        bottom = s.height + min(s.free_height, MIN_FREE_HEIGHT)
        top = s.height + s.free_height - depth_tolerance
        space = f"its claimed free height of {s.free_height:.3f} m"
        problems += _intrusion_problems(spec, s, bottom, top, depth_tolerance, wall_margin, space)
    return problems


def sample_base_positions(spec: SceneSpec, n: int = 32, seed: int = 0) -> np.ndarray:
    """``n`` robot base positions [n, 3] drawn uniformly from the robot region."""
    rng = np.random.default_rng(seed)
    region = spec.robot_region
    low = [region.x_range[0], region.y_range[0], region.z_range[0]]
    high = [region.x_range[1], region.y_range[1], region.z_range[1]]
    return rng.uniform(low, high, size=(n, 3))


def reachable_fractions(
    spec: SceneSpec,
    n_base_poses: int = 32,
    seed: int = 0,
    reach_radius: tuple[float, float] = REACH_RADIUS,
    reach_height: tuple[float, float] = REACH_HEIGHT,
) -> dict[str, float]:
    """Per surface: share of its area inside the reachable band, averaged over base poses.

    The band is an annulus around the base (yaw does not change it) and a height window
    above the base; the surface is reachable where it is inside both.
    """
    from shapely.geometry import Point

    bases = sample_base_positions(spec, n_base_poses, seed)
    rings = [Point(x, y).buffer(reach_radius[1], 128).difference(Point(x, y).buffer(reach_radius[0], 128)) for x, y, _ in bases]
    fractions = {}
    for surface in spec.support_surfaces:
        polygon, area = surface.polygon, surface.area
        shares = []
        for ring, (_, _, z) in zip(rings, bases):
            if not (reach_height[0] <= surface.height - z <= reach_height[1]) or area <= 0:
                shares.append(0.0)
            else:
                shares.append(polygon.intersection(ring).area / area)
        fractions[surface.name] = float(np.mean(shares))
    return fractions


def reachability_problems(
    spec: SceneSpec, min_fraction: float = MIN_REACHABLE_FRACTION, n_base_poses: int = 32, seed: int = 0
) -> list[str]:
    return [
        f"surface {name!r}: only {fraction:.0%} of its area is in reach (< {min_fraction:.0%})"
        for name, fraction in reachable_fractions(spec, n_base_poses, seed).items()
        if fraction < min_fraction
    ]


def robot_region_problems(
    spec: SceneSpec,
    base_radius: float = ROBOT_BASE_RADIUS,
    base_height: float = ROBOT_BASE_HEIGHT,
    tolerance: float = PENETRATION_TOLERANCE,
) -> list[str]:
    """No part in the column where the robot base (and its table) may stand."""
    region = spec.robot_region
    if region.x_range[1] < region.x_range[0] or region.y_range[1] < region.y_range[0] or region.z_range[1] < region.z_range[0]:
        return [f"robot region has an empty range: {region}"]
    x0, x1 = region.x_range[0] - base_radius, region.x_range[1] + base_radius
    y0, y1 = region.y_range[0] - base_radius, region.y_range[1] + base_radius
    z1 = region.z_range[1] + base_height
    column = fcl.CollisionObject(
        fcl.Box(x1 - x0, y1 - y0, z1), fcl.Transform(np.eye(3), np.array([(x0 + x1) / 2, (y0 + y1) / 2, z1 / 2]))
    )
    return [
        f"part {part.name!r} stands in the robot region (overlap {depth * 1000:.1f} mm)"
        for part in spec.parts
        if (depth := _collision_depth(fcl_object(part), column)) > tolerance
    ]


#: Every check by name, in the order they are reported.
CHECKS = {
    "interpenetration": interpenetration_problems,
    "floor": floor_problems,
    "support": support_problems,
    "free_height": free_height_problems,
    "reachability": reachability_problems,
    "robot_region": robot_region_problems,
}


def check_scene(spec: SceneSpec, checks: tuple[str, ...] | None = None) -> dict[str, list[str]]:
    """Run the named checks (all by default): check name -> its problems."""
    names = tuple(CHECKS) if checks is None else checks
    unknown = [n for n in names if n not in CHECKS]
    if unknown:
        raise ValueError(f"unknown scene check(s) {unknown}; valid: {', '.join(CHECKS)}")
    return {name: CHECKS[name](spec) for name in names}


def assert_scene_ok(spec: SceneSpec, checks: tuple[str, ...] | None = None) -> None:
    """Raise AssertionError listing every problem the checks find."""
    report = check_scene(spec, checks)
    lines = [f"  [{name}] {problem}" for name, problems in report.items() for problem in problems]
    if lines:
        raise AssertionError(f"{spec.scene_type} (seed {spec.seed}) fails its checks:\n" + "\n".join(lines))


def scene_trimesh(spec: SceneSpec) -> trimesh.Trimesh:
    """All parts as one triangle mesh (scene frame): handy for plots and quick looks."""
    return trimesh.util.concatenate([part_mesh(p) for p in spec.parts])
