"""``TaskSpec``: one FetchBench fetching task as plain numbers.

A task is a furniture scene (type + seed + the parameter values the seed drew), the
objects resting on it (catalog id, settled pose, physics material), which object is the
target, the robot's base pose and its box "robot table", and the two camera poses.
Everything the env builds comes from here, so the same spec always gives the same
episode, and a spec round-trips through JSON (``to_dict`` / ``from_dict``) unchanged.

Frames: the scene frame is z-up with the floor at z = 0 (see ``scenes/spec.py``).
Object poses are the pose of the object frame (``ObjectAsset``'s mesh frame) in the
scene frame; camera poses follow SAPIEN's camera convention (x forward, y left, z up).
Quaternions are wxyz.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ..scenes.spec import SUPPORT_LABELS, _floats
from ..utils.canonical import canonical_lengths, canonical_quat
from ..utils.io import canonical_json, sha256_bytes

#: Bump when the meaning of a field changes; loading another version fails loudly.
TASK_SPEC_VERSION = "1"

#: Env category name -> support label the target stands on.
CATEGORY_LABELS = {
    "Table": "on_table",
    "Shelf": "on_shelf",
    "Drawer": "in_drawer",
    "Basket": "in_basket",
}


def category_name(category: str | None) -> str | None:
    """The category's name (``Shelf``) for either vocabulary: the env ids' names (``Table``,
    ``Shelf``, ``Drawer``, ``Basket``) or the target labels that suites, records and results
    use (``on_table``, ``on_shelf``, ``in_drawer``, ``in_basket``); ValueError naming both."""
    if category is None or category in CATEGORY_LABELS:
        return category
    by_label = {label: name for name, label in CATEGORY_LABELS.items()}
    if category in by_label:
        return by_label[category]
    raise ValueError(f"unknown category {category!r}; valid: {', '.join(CATEGORY_LABELS)} "
                     f"(or the target labels {', '.join(by_label)})")

#: The Franka arm's default joint configuration in the original (7 arm joints + 2 fingers).
DEFAULT_QPOS = (-0.3127, -1.1997, 0.0578, -2.1768, 0.0649, 0.9786, 0.5300, 0.04, 0.04)


def _require(d: dict, keys: tuple[str, ...], what: str) -> None:
    if not isinstance(d, dict):
        raise ValueError(f"{what} must be a dict, got {type(d).__name__}")
    missing = [k for k in keys if k not in d]
    if missing:
        raise ValueError(f"{what} is missing {', '.join(missing)}; required keys: {', '.join(keys)}")
    unknown = sorted(set(d) - set(keys))
    if unknown:
        raise ValueError(f"{what} has unknown keys {', '.join(unknown)}; valid keys: {', '.join(keys)}")


def _unit_quat(q, what: str) -> tuple[float, float, float, float]:
    q = _floats(q, 4)
    norm = math.sqrt(sum(v * v for v in q))
    if not 0.99 < norm < 1.01:
        raise ValueError(f"{what}: quaternion {q} is not unit length")
    return q


@dataclass(frozen=True)
class ObjectPlacement:
    """One object of a task: what it is, where it rests, its physics material."""

    object_id: str
    position: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float]
    density: float  # kg/m^3
    static_friction: float
    dynamic_friction: float
    restitution: float
    support_surface: str  # name of the SupportSurface it was placed on
    support_label: str  # that surface's label (on_table, on_shelf, in_drawer, in_basket)

    KEYS = (
        "object_id", "position", "quat_wxyz", "density", "static_friction",
        "dynamic_friction", "restitution", "support_surface", "support_label",
    )

    def __post_init__(self):
        if self.support_label not in SUPPORT_LABELS:
            raise ValueError(f"object {self.object_id!r}: unknown support label {self.support_label!r}; valid: {', '.join(SUPPORT_LABELS)}")
        if self.density <= 0:
            raise ValueError(f"object {self.object_id!r}: density must be positive, got {self.density}")

    def canonical(self) -> "ObjectPlacement":
        """This placement with its pose on the grids of ``utils.canonical``."""
        return replace(self, position=canonical_lengths(self.position), quat_wxyz=canonical_quat(self.quat_wxyz))

    def transform(self) -> np.ndarray:
        """4x4 pose of the object frame in the scene frame."""
        return pose_matrix(self.position, self.quat_wxyz)

    def to_dict(self) -> dict:
        return {
            "object_id": self.object_id,
            "position": list(self.position),
            "quat_wxyz": list(self.quat_wxyz),
            "density": self.density,
            "static_friction": self.static_friction,
            "dynamic_friction": self.dynamic_friction,
            "restitution": self.restitution,
            "support_surface": self.support_surface,
            "support_label": self.support_label,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "ObjectPlacement":
        _require(d, cls.KEYS, "task object")
        return cls(
            object_id=str(d["object_id"]),
            position=_floats(d["position"], 3),
            quat_wxyz=_unit_quat(d["quat_wxyz"], f"object {d['object_id']!r}"),
            density=float(d["density"]),
            static_friction=float(d["static_friction"]),
            dynamic_friction=float(d["dynamic_friction"]),
            restitution=float(d["restitution"]),
            support_surface=str(d["support_surface"]),
            support_label=str(d["support_label"]),
        )


@dataclass(frozen=True)
class CameraPose:
    """A camera: pose in the scene frame (SAPIEN convention: x forward, z up) and horizontal FOV."""

    position: tuple[float, float, float]
    quat_wxyz: tuple[float, float, float, float]
    fov_x: float = math.radians(70.0)

    def to_dict(self) -> dict:
        return {"position": list(self.position), "quat_wxyz": list(self.quat_wxyz), "fov_x": self.fov_x}

    @classmethod
    def from_dict(cls, d: dict) -> "CameraPose":
        _require(d, ("position", "quat_wxyz", "fov_x"), "task camera")
        return cls(_floats(d["position"], 3), _unit_quat(d["quat_wxyz"], "camera"), float(d["fov_x"]))


@dataclass(frozen=True)
class TaskSpec:
    """One fetching task. ``objects[target_index]`` is the object to fetch."""

    scene_type: str
    scene_seed: int
    scene_params: dict  # every parameter value of the scene (generate(..., overrides=scene_params))
    scene_hash: str  # SceneSpec.content_hash() when sampled: a changed generator fails loudly
    objects: tuple[ObjectPlacement, ...]
    target_index: int
    robot_base_position: tuple[float, float, float]
    robot_base_quat_wxyz: tuple[float, float, float, float]
    robot_table_center: tuple[float, float, float]
    robot_table_size: tuple[float, float, float]  # full extents, m
    camera_left: CameraPose
    camera_right: CameraPose
    robot_init_qpos: tuple[float, ...] = DEFAULT_QPOS
    object_source: str = ""  # objects.loading.object_source() when sampled; checked on load
    seed: int | None = None  # the sampler seed that produced this task (None if hand-made)
    version: str = TASK_SPEC_VERSION
    extra: dict = field(default_factory=dict)  # free-form, JSON-safe (e.g. sampler statistics)

    KEYS = (
        "version", "seed", "scene_type", "scene_seed", "scene_params", "scene_hash", "objects",
        "target_index", "robot_base_position", "robot_base_quat_wxyz", "robot_table_center",
        "robot_table_size", "camera_left", "camera_right", "robot_init_qpos", "object_source", "extra",
    )

    def __post_init__(self):
        if not self.objects:
            raise ValueError("a task needs at least one object")
        if not 0 <= self.target_index < len(self.objects):
            raise ValueError(f"target_index {self.target_index} out of range; valid: 0..{len(self.objects) - 1}")
        if len(self.robot_init_qpos) != 9:
            raise ValueError(f"robot_init_qpos needs 9 values (7 arm + 2 fingers), got {len(self.robot_init_qpos)}")
        if any(s <= 0 for s in self.robot_table_size):
            raise ValueError(f"robot_table_size must be positive, got {self.robot_table_size}")

    @property
    def target(self) -> ObjectPlacement:
        return self.objects[self.target_index]

    @property
    def target_label(self) -> str:
        """Support label (category) of the target: on_table, on_shelf, in_drawer or in_basket."""
        return self.target.support_label

    def scene(self):
        """Regenerate the furniture; raises if the generator no longer gives the sampled scene."""
        from ..scenes import generate

        spec = generate(self.scene_type, self.scene_seed, overrides=self.scene_params)
        if spec.content_hash() != self.scene_hash:
            raise ValueError(
                f"task's {self.scene_type} scene (seed {self.scene_seed}) regenerates differently than when the "
                f"task was sampled (hash {spec.content_hash()[:12]} != {self.scene_hash[:12]}): the scene "
                "generator changed; resample the task"
            )
        return spec

    def T_world_base(self) -> np.ndarray:
        return pose_matrix(self.robot_base_position, self.robot_base_quat_wxyz)

    def to_dict(self) -> dict:
        return {
            "version": self.version,
            "seed": self.seed,
            "scene_type": self.scene_type,
            "scene_seed": self.scene_seed,
            "scene_params": {k: self.scene_params[k] for k in sorted(self.scene_params)},
            "scene_hash": self.scene_hash,
            "objects": [o.to_dict() for o in self.objects],
            "target_index": self.target_index,
            "robot_base_position": list(self.robot_base_position),
            "robot_base_quat_wxyz": list(self.robot_base_quat_wxyz),
            "robot_table_center": list(self.robot_table_center),
            "robot_table_size": list(self.robot_table_size),
            "camera_left": self.camera_left.to_dict(),
            "camera_right": self.camera_right.to_dict(),
            "robot_init_qpos": list(self.robot_init_qpos),
            "object_source": self.object_source,
            "extra": self.extra,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "TaskSpec":
        """Parse and validate a task dict; malformed input raises ValueError naming what is valid."""
        _require(d, cls.KEYS, "task")
        if d["version"] != TASK_SPEC_VERSION:
            raise ValueError(f"task spec version {d['version']!r} is not supported; valid: {TASK_SPEC_VERSION!r}")
        from ..scenes import SCENE_TYPES

        if d["scene_type"] not in SCENE_TYPES:
            raise ValueError(f"unknown scene type {d['scene_type']!r}; valid: {', '.join(SCENE_TYPES)}")
        if not isinstance(d["objects"], list):
            raise ValueError("task 'objects' must be a list of object dicts")
        try:
            return cls(
                scene_type=d["scene_type"],
                scene_seed=int(d["scene_seed"]),
                scene_params=_scene_params(d["scene_params"]),
                scene_hash=str(d["scene_hash"]),
                objects=tuple(ObjectPlacement.from_dict(o) for o in d["objects"]),
                target_index=int(d["target_index"]),
                robot_base_position=_floats(d["robot_base_position"], 3),
                robot_base_quat_wxyz=_unit_quat(d["robot_base_quat_wxyz"], "robot base"),
                robot_table_center=_floats(d["robot_table_center"], 3),
                robot_table_size=_floats(d["robot_table_size"], 3),
                camera_left=CameraPose.from_dict(d["camera_left"]),
                camera_right=CameraPose.from_dict(d["camera_right"]),
                robot_init_qpos=_floats(d["robot_init_qpos"], 9),
                object_source=str(d["object_source"]),
                seed=None if d["seed"] is None else int(d["seed"]),
                version=d["version"],
                extra=dict(d["extra"]),
            )
        except (TypeError, AttributeError) as error:  # wrong container types inside the dict
            raise ValueError(f"malformed task dict: {error}") from None

    def to_json(self) -> str:
        return canonical_json(self.to_dict())

    def content_hash(self) -> str:
        return sha256_bytes(self.to_json().encode())


def _scene_params(params) -> dict:
    """Parameter values as given (ints stay ints: the scene hash is over their JSON form)."""
    if not isinstance(params, dict):
        raise ValueError("task 'scene_params' must be a dict of parameter name -> number")
    for name, value in params.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"task scene parameter {name!r} = {value!r} is not a number")
    return dict(params)


def pose_matrix(position, quat_wxyz) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    w, x, y, z = quat_wxyz
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix()
    T[:3, 3] = position
    return T


def matrix_to_pose(T: np.ndarray) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """(position, quat_wxyz) of a 4x4 transform, with w >= 0 (one canonical sign)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    q = np.array([w, x, y, z])
    if q[0] < 0:
        q = -q
    return tuple(float(v) for v in T[:3, 3]), tuple(float(v) for v in q)
