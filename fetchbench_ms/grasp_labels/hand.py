"""The Franka hand as ManiSkill ships it, read from ``panda_v2_gripper.urdf``.

Frame convention (ManiSkill's ``panda_hand`` link): the fingers close along the hand's
y axis (left finger at +y, right at -y), the hand approaches along +z, and the
tool centre point ``panda_hand_tcp`` sits ``TCP_OFFSET = 0.1034`` m along +z, between
the finger pads. Each finger travels 0..0.04 m, so the opening is at most 0.08 m.

The geometry is read from the URDF that ManiSkill's Panda uses (the gripper-only file
shares the hand and finger links of ``panda_v2.urdf``), so the sampler's collision
check and the physics labeller see exactly the env's hand. The URDF is parsed here
with ``xml.etree`` because no maintained URDF library is installed that returns
collision geometry (pytorch_kinematics keeps visuals only); only boxes and meshes,
the two kinds this file uses, are read.
"""
from __future__ import annotations

import functools
import importlib.util
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from ..utils.io import atomic_write_text, sha256_bytes
from ..utils.mesh_cache import cache_dir

#: ``panda_hand`` -> ``panda_hand_tcp`` along +z, m (the ``panda_hand_tcp_joint`` origin).
TCP_OFFSET = 0.1034
#: Largest finger opening (two fingers x 0.04 m), m.
MAX_OPENING = 0.08
#: Each finger's joint travel, m.
FINGER_TRAVEL = 0.04
FINGER_LINKS = ("panda_leftfinger", "panda_rightfinger")
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
#: The six virtual joints of the floating gripper, root -> hand: x, y, z, then rotations about x, y, z.
VIRTUAL_JOINTS = (
    "root_x_axis_joint",
    "root_y_axis_joint",
    "root_z_axis_joint",
    "root_x_rot_joint",
    "root_y_rot_joint",
    "root_z_rot_joint",
)
HAND_LINKS = ("panda_hand",) + FINGER_LINKS

# Gripper settings of ManiSkill's Panda agent (mani_skill/agents/robots/panda/panda.py),
# copied so that labels hold for the env's hand: finger material, contact patch,
# PD drive and the closed target below the joint limit that keeps force on thin objects.
FINGER_FRICTION = 2.0
FINGER_PATCH_RADIUS = 0.1
GRIPPER_STIFFNESS = 1e3
GRIPPER_DAMPING = 1e2
GRIPPER_FORCE_LIMIT = 100.0
GRIPPER_CLOSED_TARGET = -0.01


def maniskill_asset_dir() -> Path:
    """ManiSkill's Panda asset folder, found without importing mani_skill (which pulls torch/gym).

    ``FETCHBENCH_PANDA_ASSET_DIR`` may point at a copy of that folder, for batch machines
    where only the labeller's few dependencies are installed.
    """
    override = os.environ.get("FETCHBENCH_PANDA_ASSET_DIR")
    if override:
        return Path(override)
    spec = importlib.util.find_spec("mani_skill")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("mani_skill is not installed; its Panda URDF is needed for the Franka hand")
    return Path(list(spec.submodule_search_locations)[0]) / "assets" / "robots" / "panda"


def gripper_urdf_path() -> Path:
    return maniskill_asset_dir() / "panda_v2_gripper.urdf"


def _floats(text: str | None, default: str) -> np.ndarray:
    return np.array([float(v) for v in (text or default).split()])


def _origin(element) -> np.ndarray:
    origin = element.find("origin") if element is not None else None
    xyz = _floats(origin.get("xyz") if origin is not None else None, "0 0 0")
    rpy = _floats(origin.get("rpy") if origin is not None else None, "0 0 0")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF rpy = fixed-axis roll, pitch, yaw
    T[:3, 3] = xyz
    return T


@functools.lru_cache(maxsize=None)
def _link_collision_meshes() -> dict[str, trimesh.Trimesh]:
    """Collision geometry of each hand link in its own link frame, as one mesh per link.

    A mesh collision is replaced by its convex hull: PhysX builds dynamic links from
    convex hulls, so the hull is what the fingers actually bump into.
    """
    urdf = gripper_urdf_path()
    root = ET.parse(urdf).getroot()
    meshes = {}
    for link in root.findall("link"):
        name = link.get("name")
        if name not in HAND_LINKS:
            continue
        pieces = []
        for collision in link.findall("collision"):
            geometry = collision.find("geometry")
            T_link_shape = _origin(collision)
            if geometry.find("box") is not None:
                piece = trimesh.creation.box(extents=_floats(geometry.find("box").get("size"), ""))
            elif geometry.find("mesh") is not None:
                piece = trimesh.load(urdf.parent / geometry.find("mesh").get("filename"), force="mesh").convex_hull
            else:
                raise ValueError(f"{urdf}: link {name} has a collision shape other than box/mesh")
            piece.apply_transform(T_link_shape)
            pieces.append(piece)
        meshes[name] = trimesh.util.concatenate(pieces)
    missing = set(HAND_LINKS) - set(meshes)
    if missing:
        raise ValueError(f"{urdf} lacks links {sorted(missing)}")
    return meshes


@functools.lru_cache(maxsize=None)
def _finger_joint_origins() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    root = ET.parse(gripper_urdf_path()).getroot()
    out = {}
    for joint in root.findall("joint"):
        if joint.get("name") in FINGER_JOINTS:
            out[joint.find("child").get("link")] = (_origin(joint), _floats(joint.find("axis").get("xyz"), ""))
    return out


def hand_collision_meshes(finger_q: float = FINGER_TRAVEL) -> dict[str, trimesh.Trimesh]:
    """Collision meshes of hand and fingers in the ``panda_hand`` frame, fingers at ``finger_q`` each."""
    link_meshes = _link_collision_meshes()
    out = {"panda_hand": link_meshes["panda_hand"].copy()}
    for link, (T_hand_joint, axis) in _finger_joint_origins().items():
        T = T_hand_joint.copy()
        T[:3, 3] += T_hand_joint[:3, :3] @ (axis * finger_q)
        out[link] = link_meshes[link].copy().apply_transform(T)
    return out


def open_hand_mesh() -> trimesh.Trimesh:
    """The open hand (fingers at 0.04 m) as one mesh in the ``panda_hand`` frame."""
    return trimesh.util.concatenate(list(hand_collision_meshes(FINGER_TRAVEL).values()))


def physics_urdf_path() -> str:
    """The gripper URDF without visual elements and with absolute mesh paths.

    The labeller runs a physics-only SAPIEN scene (no renderer, so no GPU/Vulkan), and
    SAPIEN's URDF loader would otherwise build render bodies for the visuals.
    """
    source = gripper_urdf_path()
    tree = ET.parse(source)
    for link in tree.getroot().findall("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
        for mesh in link.iter("mesh"):
            mesh.set("filename", str((source.parent / mesh.get("filename")).resolve()))
    text = ET.tostring(tree.getroot(), encoding="unicode")
    path = cache_dir() / "urdf" / f"panda_gripper_physics_{sha256_bytes(text.encode())[:16]}.urdf"
    if not path.exists():
        atomic_write_text(path, text)
    return os.fspath(path)


def gripper_outline_hand(width: float = MAX_OPENING) -> np.ndarray:
    """Line segments (K, 2, 3) drawing the hand in the ``panda_hand`` frame: a stem along
    z from the wrist, a palm bar along y, two fingers ending at the TCP depth plus the pads."""
    half = width / 2
    palm_z, tip_z = 0.0584, TCP_OFFSET + 0.01
    return np.array(
        [
            [[0, 0, 0], [0, 0, palm_z]],
            [[0, -half, palm_z], [0, half, palm_z]],
            [[0, half, palm_z], [0, half, tip_z]],
            [[0, -half, palm_z], [0, -half, tip_z]],
        ],
        dtype=float,
    )
