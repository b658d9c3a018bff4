"""Plain data objects that describe one procedural furniture scene.

A ``SceneSpec`` is everything downstream stages need to know about the furniture:
its parts (primitives with size, pose and material), its support surfaces (where
objects may be placed), the region where the robot base may stand and the region
the cameras look at. It holds numbers only; the simulator never appears here.

Frames and conventions (see docs/architecture.md):
- The scene frame is z-up, the floor is z = 0, the furniture stands at x > 0 and the
  robot faces +x from x < 0 (the original's convention).
- Metres, radians; quaternions are wxyz as in SAPIEN.
- Box ``size`` is the FULL extent (sx, sy, sz) in the part frame.
- Cylinder and capsule ``size`` is (radius, length) with the axis along the part's
  local z (SAPIEN's own primitives use x; the SAPIEN loader converts).
- A "convex_mesh" part carries its vertices in the part frame (``mesh_vertices``); used
  only where no primitive fits.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..utils.canonical import canonical_length
from ..utils.io import canonical_json, sha256_bytes

SHAPES = ("box", "cylinder", "capsule", "convex_mesh")
SUPPORT_LABELS = ("on_table", "on_shelf", "in_drawer", "in_basket")

Shape = Literal["box", "cylinder", "capsule", "convex_mesh"]
SupportLabel = Literal["on_table", "on_shelf", "in_drawer", "in_basket"]


def _floats(values, n: int | None = None) -> tuple[float, ...]:
    out = tuple(float(v) for v in np.asarray(values, dtype=float).reshape(-1))
    if n is not None and len(out) != n:
        raise ValueError(f"expected {n} numbers, got {len(out)}")
    return out


@dataclass(frozen=True)
class Material:
    """Visual material of a part. Physics friction is per part (see ``Part.friction``)."""

    rgba: tuple[float, float, float, float]
    roughness: float = 0.7
    metallic: float = 0.0

    def to_dict(self) -> dict:
        return {"rgba": list(self.rgba), "roughness": self.roughness, "metallic": self.metallic}

    @classmethod
    def from_dict(cls, d: dict) -> "Material":
        return cls(rgba=_floats(d["rgba"], 4), roughness=float(d["roughness"]), metallic=float(d["metallic"]))


@dataclass(frozen=True)
class Part:
    """One rigid primitive of the furniture, placed in the scene frame."""

    name: str
    shape: Shape
    size: tuple[float, ...]
    position: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    material: Material = Material((0.6, 0.6, 0.6, 1.0))
    # Convex hull vertices in the part frame, only for shape == "convex_mesh".
    mesh_vertices: tuple[tuple[float, float, float], ...] | None = None
    # Pieces meant to touch each other share a group: the interpenetration test
    # ignores overlaps inside a group (e.g. the slats of a basket weave).
    group: str = ""

    def __post_init__(self):
        if self.shape not in SHAPES:
            raise ValueError(f"unknown part shape {self.shape!r}; valid: {', '.join(SHAPES)}")
        expected = {"box": 3, "cylinder": 2, "capsule": 2, "convex_mesh": 0}[self.shape]
        if self.shape != "convex_mesh" and len(self.size) != expected:
            raise ValueError(f"part {self.name!r}: a {self.shape} needs {expected} size numbers, got {len(self.size)}")
        if self.shape == "convex_mesh" and not self.mesh_vertices:
            raise ValueError(f"part {self.name!r}: a convex_mesh needs mesh_vertices")
        if any(s <= 0 for s in self.size):
            raise ValueError(f"part {self.name!r}: sizes must be positive, got {self.size}")

    def transform(self) -> np.ndarray:
        """4x4 pose of the part frame in the scene frame."""
        from scipy.spatial.transform import Rotation

        w, x, y, z = self.quat_wxyz
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
        T[:3, 3] = self.position
        return T

    def to_dict(self) -> dict:
        d = {
            "name": self.name,
            "shape": self.shape,
            "size": list(self.size),
            "position": list(self.position),
            "quat_wxyz": list(self.quat_wxyz),
            "material": self.material.to_dict(),
            "group": self.group,
        }
        if self.mesh_vertices is not None:
            d["mesh_vertices"] = [list(v) for v in self.mesh_vertices]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Part":
        verts = d.get("mesh_vertices")
        return cls(
            name=d["name"],
            shape=d["shape"],
            size=_floats(d["size"]),
            position=_floats(d["position"], 3),
            quat_wxyz=_floats(d["quat_wxyz"], 4),
            material=Material.from_dict(d["material"]),
            mesh_vertices=None if verts is None else tuple(_floats(v, 3) for v in verts),
            group=d.get("group", ""),
        )


@dataclass(frozen=True)
class SupportSurface:
    """A horizontal area objects may be placed on.

    ``polygon_xy`` is the usable area (counter-clockwise, scene-frame x/y) at height
    ``height``; ``free_height`` is the clear space above it (to the next board, or to
    the open top). Drawers and baskets have walls along the polygon's edges up to
    ``wall_top`` (scene z); it is None for open surfaces.
    """

    name: str
    label: SupportLabel
    polygon_xy: tuple[tuple[float, float], ...]
    height: float
    free_height: float
    supporting_part: str
    wall_top: float | None = None

    def __post_init__(self):
        if self.label not in SUPPORT_LABELS:
            raise ValueError(f"unknown support label {self.label!r}; valid: {', '.join(SUPPORT_LABELS)}")
        if len(self.polygon_xy) < 3:
            raise ValueError(f"support surface {self.name!r} needs a polygon of >= 3 vertices")

    @property
    def polygon(self):
        """The polygon as a shapely Polygon (for area, erosion and sampling)."""
        from shapely.geometry import Polygon

        return Polygon(self.polygon_xy)

    @property
    def area(self) -> float:
        return float(self.polygon.area)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "label": self.label,
            "polygon_xy": [list(p) for p in self.polygon_xy],
            "height": self.height,
            "free_height": self.free_height,
            "supporting_part": self.supporting_part,
            "wall_top": self.wall_top,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "SupportSurface":
        return cls(
            name=d["name"],
            label=d["label"],
            polygon_xy=tuple(_floats(p, 2) for p in d["polygon_xy"]),
            height=float(d["height"]),
            free_height=float(d["free_height"]),
            supporting_part=d["supporting_part"],
            wall_top=None if d.get("wall_top") is None else float(d["wall_top"]),
        )


@dataclass(frozen=True)
class RobotRegion:
    """Where the robot base may stand: uniform ranges in the scene frame.

    The base faces +x (yaw 0) toward the furniture; ``yaw_range`` allows a small turn.
    ``z_range`` is the height of the base (the robot table's top is just below it).
    """

    x_range: tuple[float, float]
    y_range: tuple[float, float]
    z_range: tuple[float, float]
    yaw_range: tuple[float, float] = (0.0, 0.0)

    def to_dict(self) -> dict:
        return {k: list(v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict) -> "RobotRegion":
        return cls(**{k: _floats(v, 2) for k, v in d.items()})


@dataclass(frozen=True)
class CameraTargetRegion:
    """Axis-aligned box the cameras look at (centre and half extents, scene frame)."""

    center: tuple[float, float, float]
    half_size: tuple[float, float, float]

    def to_dict(self) -> dict:
        return {"center": list(self.center), "half_size": list(self.half_size)}

    @classmethod
    def from_dict(cls, d: dict) -> "CameraTargetRegion":
        return cls(center=_floats(d["center"], 3), half_size=_floats(d["half_size"], 3))


@dataclass(frozen=True)
class SceneSpec:
    """One furniture scene: generated from ``scene_type`` + ``params`` (+ the seed that drew them)."""

    scene_type: str
    seed: int | None
    params: dict[str, float]
    parts: tuple[Part, ...]
    support_surfaces: tuple[SupportSurface, ...]
    robot_region: RobotRegion
    camera_target: CameraTargetRegion
    generator_version: str = "1"

    def part(self, name: str) -> Part:
        for p in self.parts:
            if p.name == name:
                return p
        raise KeyError(f"no part named {name!r} in {self.scene_type}; parts: {', '.join(p.name for p in self.parts)}")

    def surfaces(self, label: str | None = None) -> tuple[SupportSurface, ...]:
        if label is not None and label not in SUPPORT_LABELS:
            raise ValueError(f"unknown support label {label!r}; valid: {', '.join(SUPPORT_LABELS)}")
        return tuple(s for s in self.support_surfaces if label is None or s.label == label)

    @property
    def support_labels(self) -> tuple[str, ...]:
        return tuple(sorted({s.label for s in self.support_surfaces}))

    def to_dict(self) -> dict:
        return {
            "scene_type": self.scene_type,
            "seed": self.seed,
            "generator_version": self.generator_version,
            "params": {k: self.params[k] for k in sorted(self.params)},
            "parts": [p.to_dict() for p in self.parts],
            "support_surfaces": [s.to_dict() for s in self.support_surfaces],
            "robot_region": self.robot_region.to_dict(),
            "camera_target": self.camera_target.to_dict(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "SceneSpec":
        return cls(
            scene_type=d["scene_type"],
            seed=d["seed"],
            params=dict(d["params"]),
            parts=tuple(Part.from_dict(p) for p in d["parts"]),
            support_surfaces=tuple(SupportSurface.from_dict(s) for s in d["support_surfaces"]),
            robot_region=RobotRegion.from_dict(d["robot_region"]),
            camera_target=CameraTargetRegion.from_dict(d["camera_target"]),
            generator_version=d.get("generator_version", "1"),
        )

    def on_grid(self) -> "SceneSpec":
        """This scene with every derived number (part sizes and poses, mesh vertices, support
        polygons and heights, regions) on the grid of ``utils.canonical`` (1 um; radians
        and unit-free numbers to 1e-6 alike). The parameters stay as drawn (they are exact).

        Generators sum and average arrays, and NumPy's SIMD kernels for those differ between
        CPUs in the last bit (an EketShelf's board positions on an Intel AVX-512 SPR machine
        vs an AMD one), which changed the content hash and what the physics is given."""
        d = self.to_dict()
        params = d.pop("params")
        snapped = _snap(d)
        snapped["params"] = params
        return SceneSpec.from_dict(snapped)

    def content_hash(self) -> str:
        """sha256 of the canonical JSON form: equal hashes mean byte-identical scenes."""
        return sha256_bytes(canonical_json(self.to_dict()).encode())


def _snap(value):
    """Every float inside ``value`` (dicts, lists) rounded to ``canonical_length``."""
    if isinstance(value, dict):
        return {k: _snap(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_snap(v) for v in value]
    if isinstance(value, float):
        return canonical_length(value)
    return value
