"""Export a ``SceneSpec`` as a triangle-mesh scene (GLB or OBJ) for outside tools.

Every part becomes one named geometry of a ``trimesh.Scene`` (boxes, cylinders, capsules
and convex meshes, placed in the scene frame, z up, metres) coloured with its material.
With ``with_surfaces`` the support surfaces are added as thin slabs named
``surface:<name>`` in their label's highlight colour.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from ..utils.io import atomic_write_bytes
from .geometry import part_mesh_local, surface_slab
from .render import LABEL_COLORS, OVERLAY_LIFT, OVERLAY_THICKNESS
from .spec import SceneSpec

#: File formats ``export_scene`` writes, by suffix.
EXPORT_FORMATS = ("glb", "obj")


def _colored(mesh: trimesh.Trimesh, rgba) -> trimesh.Trimesh:
    color = np.round(np.clip(np.asarray(rgba, dtype=float), 0.0, 1.0) * 255).astype(np.uint8)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.tile(color, (len(mesh.faces), 1)))
    return mesh


def scene_to_trimesh(spec: SceneSpec, with_surfaces: bool = False) -> trimesh.Scene:
    """A trimesh scene with one node per part (mesh in the part frame, node at its pose)."""
    scene = trimesh.Scene()
    for part in spec.parts:
        mesh = _colored(part_mesh_local(part), part.material.rgba)
        scene.add_geometry(mesh, node_name=part.name, geom_name=part.name, transform=part.transform())
    if with_surfaces:
        for surface in spec.support_surfaces:
            slab = _colored(surface_slab(surface, OVERLAY_THICKNESS, OVERLAY_LIFT), (*LABEL_COLORS[surface.label], 0.6))
            name = f"surface:{surface.name}"
            scene.add_geometry(slab, node_name=name, geom_name=name)
    return scene


def export_scene(spec: SceneSpec, path: str | Path, with_surfaces: bool = False) -> Path:
    """Write ``spec`` to ``path`` (.glb or .obj, by suffix) and return the path.

    OBJ has no scene graph: the parts are written as separate objects (``o`` lines) with
    their poses applied and colours as vertex colours.
    """
    path = Path(path)
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in EXPORT_FORMATS:
        raise ValueError(f"cannot export to {path.name!r}; valid suffixes: {', '.join('.' + f for f in EXPORT_FORMATS)}")
    scene = scene_to_trimesh(spec, with_surfaces)
    if suffix == "glb":
        data = scene.export(file_type="glb")
    else:
        data = trimesh.exchange.obj.export_obj(scene, include_color=True, include_texture=False)
    atomic_write_bytes(path, data if isinstance(data, bytes) else data.encode())
    return path
