"""Geometry of ``SceneSpec`` parts outside the simulator: triangle meshes (export, ray
casts, renders of overlays) and exact python-fcl primitives (interpenetration checks).

Both follow the conventions of ``spec.py``: box ``size`` is the full extent, cylinders
and capsules are (radius, length) along the part's local z, a capsule's length is that
of its cylindrical middle (as SAPIEN's ``half_length`` and fcl's ``lz``).
"""
from __future__ import annotations

import fcl
import numpy as np
import trimesh

from .spec import Part, SupportSurface

#: Facets around a cylinder or capsule mesh. 64 keeps the rim within 0.1 mm of the true
#: circle for the 0.5 m radius of a round table top (sagitta r (1 - cos(pi/64))).
ROUND_SECTIONS = 64


def part_mesh_local(part: Part, sections: int = ROUND_SECTIONS) -> trimesh.Trimesh:
    """The part as a triangle mesh in its own frame."""
    if part.shape == "box":
        return trimesh.creation.box(extents=part.size)
    if part.shape == "cylinder":
        radius, length = part.size
        return trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    if part.shape == "capsule":
        radius, length = part.size
        return trimesh.creation.capsule(height=length, radius=radius, count=[sections, sections])
    if part.shape == "convex_mesh":
        return trimesh.Trimesh(np.asarray(part.mesh_vertices, dtype=float)).convex_hull
    raise ValueError(f"unknown part shape {part.shape!r}")


def part_mesh(part: Part, sections: int = ROUND_SECTIONS) -> trimesh.Trimesh:
    """The part as a triangle mesh in the scene frame."""
    mesh = part_mesh_local(part, sections)
    mesh.apply_transform(part.transform())
    return mesh


def part_aabb(part: Part) -> np.ndarray:
    """Axis-aligned bounds [[x0, y0, z0], [x1, y1, z1]] in the scene frame that contain the
    part (exact for boxes and meshes, the bounds of the enclosing box for round shapes)."""
    if part.shape == "convex_mesh":
        points = np.asarray(part.mesh_vertices, dtype=float)
    else:
        if part.shape == "box":
            half = np.asarray(part.size) / 2
        else:
            radius, length = part.size
            half_z = length / 2 + (radius if part.shape == "capsule" else 0.0)
            half = np.array([radius, radius, half_z])
        points = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * half
    T = part.transform()
    points = points @ T[:3, :3].T + T[:3, 3]
    return np.stack([points.min(axis=0), points.max(axis=0)])


def fcl_geometry(part: Part) -> fcl.CollisionGeometry:
    """The part's exact fcl primitive (a convex hull for ``convex_mesh`` parts)."""
    if part.shape == "box":
        return fcl.Box(*part.size)
    if part.shape == "cylinder":
        return fcl.Cylinder(part.size[0], part.size[1])
    if part.shape == "capsule":
        return fcl.Capsule(part.size[0], part.size[1])
    if part.shape == "convex_mesh":
        return convex_fcl(part_mesh_local(part))
    raise ValueError(f"unknown part shape {part.shape!r}")


def convex_fcl(mesh: trimesh.Trimesh) -> fcl.Convex:
    """An fcl convex shape from a convex triangle mesh."""
    faces = np.hstack([np.full((len(mesh.faces), 1), 3), mesh.faces]).ravel()
    return fcl.Convex(np.asarray(mesh.vertices, dtype=float), len(mesh.faces), faces)


def fcl_object(part: Part) -> fcl.CollisionObject:
    T = part.transform()
    return fcl.CollisionObject(fcl_geometry(part), fcl.Transform(T[:3, :3], T[:3, 3]))


def polygon_prisms(polygon, z_low: float, z_high: float) -> list[trimesh.Trimesh]:
    """Convex prisms that together fill ``polygon`` (shapely) extruded over [z_low, z_high].

    A convex polygon gives one prism; any other is split by a constrained Delaunay
    triangulation so that every piece is convex (fcl's GJK/EPA needs convex shapes).
    """
    import shapely

    if polygon.is_empty or z_high <= z_low:
        return []
    pieces = [polygon]
    if polygon.convex_hull.area - polygon.area > 1e-9 or len(polygon.interiors) > 0:
        pieces = list(shapely.constrained_delaunay_triangles(polygon).geoms)
    prisms = []
    for piece in pieces:
        prism = trimesh.creation.extrude_polygon(piece, height=z_high - z_low)
        prism.apply_translation([0.0, 0.0, z_low])
        prisms.append(prism)
    return prisms


def surface_slab(surface: SupportSurface, thickness: float, lift: float = 0.0) -> trimesh.Trimesh:
    """A thin slab with the surface's polygon as outline, ``lift`` above its height."""
    slab = trimesh.creation.extrude_polygon(surface.polygon, height=thickness)
    slab.apply_translation([0.0, 0.0, surface.height + lift])
    return slab
