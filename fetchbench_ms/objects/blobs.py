"""The 1000 random "blob" objects shipped with pybullet (``pybullet_data/random_urdfs``).

Each OBJ is already a union of convex pieces (``o convex_<i>`` groups), so no
decomposition is needed; the URDFs scale them by 0.015 to metres. They are read from
the installed package at run time.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from . import geometry as g

#: URDF mesh scale of every blob (OBJ units -> metres).
BLOB_SCALE = 0.015
BLOB_COUNT = 1000


def blob_dir() -> Path:
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / "random_urdfs"


def blob_obj_path(number: int) -> Path:
    if not 0 <= number < BLOB_COUNT:
        raise ValueError(f"blob number {number} out of range; valid: 0..{BLOB_COUNT - 1}")
    return blob_dir() / f"{number:03d}" / f"{number:03d}.obj"


def read_obj_groups(path: str | os.PathLike) -> list[np.ndarray]:
    """Vertex arrays of each ``o`` group of an OBJ file (the vertices its faces use).

    Hand-parsed because trimesh merges the groups of these files into one mesh, and
    only the grouping (which vertices form one convex piece) is needed."""
    vertices: list[list[float]] = []
    groups: list[set[int]] = []
    with open(path, "r", encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.startswith("v "):
                vertices.append([float(x) for x in line.split()[1:4]])
            elif line.startswith("o ") or (line.startswith("f ") and not groups):
                groups.append(set())
                if line.startswith("f "):
                    groups[-1].update(int(tok.split("/")[0]) - 1 for tok in line.split()[1:])
            elif line.startswith("f "):
                groups[-1].update(int(tok.split("/")[0]) - 1 for tok in line.split()[1:])
    points = np.asarray(vertices, dtype=np.float64)
    return [points[sorted(idx)] for idx in groups if idx]


def blob_parts(number: int) -> list[trimesh.Trimesh]:
    """Convex parts of blob ``number`` in metres (OBJ frame, not centred).

    Raises ValueError for a broken file (non-finite vertices, flat pieces)."""
    groups = read_obj_groups(blob_obj_path(number))
    if not groups:
        raise ValueError(f"blob {number:03d}: no geometry")
    parts = []
    for points in groups:
        if not np.all(np.isfinite(points)):
            raise ValueError(f"blob {number:03d}: non-finite vertices")
        if len(points) < 4:
            raise ValueError(f"blob {number:03d}: a piece with {len(points)} vertices")
        try:
            parts.append(g.thicken(g.hull(points * BLOB_SCALE)))
        except Exception as error:  # qhull refuses flat or degenerate point sets
            raise ValueError(f"blob {number:03d}: degenerate piece ({error.__class__.__name__})") from None
    return parts
