"""The plain data object every consumer of the object library receives.

An ``ObjectAsset`` is one fetchable object in its own frame: metres, z-up as built
(standing or lying as the object would on a table), origin at the centre of the
axis-aligned bounding box of its convex parts (the centre of mass is given separately):
a visual mesh, the convex collision parts that physics and planning use, mass
properties at unit density, stable resting poses and its bounding dimensions.
It carries no simulator objects; the env and the grasp labeller build bodies from it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

SOURCES = ("ycb", "blob", "procedural")
SPLITS = ("train", "test")


@dataclass(frozen=True)
class ObjectRecord:
    """Catalog row: enough to list, filter and split objects without building meshes."""

    object_id: str  # e.g. "ycb/025_mug", "blob/0042", "procedural/mug/0007"
    category: str
    source: str
    split: str
    extents: tuple[float, float, float]  # axis-aligned bounding box of the object frame, m


@dataclass(frozen=True)
class ObjectAsset:
    record: ObjectRecord
    visual_mesh: trimesh.Trimesh
    convex_parts: tuple[trimesh.Trimesh, ...]  # each convex and watertight, object frame
    center_of_mass: np.ndarray  # (3,), object frame, uniform density over convex parts
    volume: float  # m^3, of the union of convex parts (sum; parts are disjoint or nearly)
    stable_poses: np.ndarray  # (K, 4, 4) T_support_object resting poses, most likely first
    stable_probs: np.ndarray  # (K,) probabilities, sum to 1
    rgba: tuple[float, float, float, float] | None = None  # suggested colour (procedural objects)
    grasp_width: float = float("nan")  # narrowest width the hand could close across, m
    metadata: dict = field(default_factory=dict)  # source details: parameters, scan name, file

    @property
    def object_id(self) -> str:
        return self.record.object_id

    @property
    def category(self) -> str:
        return self.record.category

    @property
    def source(self) -> str:
        return self.record.source

    @property
    def split(self) -> str:
        return self.record.split

    @property
    def extents(self) -> np.ndarray:
        return np.asarray(self.record.extents, dtype=np.float64)

    def mass(self, density: float) -> float:
        return float(density * self.volume)

    def collision_mesh(self) -> trimesh.Trimesh:
        """All convex parts in one mesh (not a union: parts may touch or overlap)."""
        return trimesh.util.concatenate(list(self.convex_parts))

    def surface_mesh(self) -> trimesh.Trimesh:
        """The watertight outer surface of what physics simulates: the boolean union of
        the convex parts (manifold3d). Scans are not all watertight; this always is, so
        ray casts and inside tests (grasp sampling) behave."""
        if len(self.convex_parts) == 1:
            return self.convex_parts[0].copy()
        return trimesh.boolean.union(list(self.convex_parts), engine="manifold")
