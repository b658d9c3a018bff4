"""Grasp labels for the Robotiq 2F-85 (the ``kinova_gen3_robotiq`` setup, docs/robots.md).

Candidates: an object's Franka-hand candidates from the shipped labels (every trial,
successful or not), which are grasp-frame poses in the convention every hand shares
(approach +z, closing along y, TCP 0.1034 m along z): on the Robotiq the same TCP pose,
approach axis and closing direction. Those where the open Robotiq (its own collision
meshes) intersects the object are dropped; the rest are tried in physics as the Franka
hand's are (``physics.GraspLabeller``: close, gravity on, shake, judge), with a floating
Robotiq driven as the env's agent drives it (``robots.agents.KinovaGen3Robotiq``: both
outer knuckles to a PD target past closed, passive inner joints, the four-bar closed by
a drive per side).

Build them with the grasp builder (resumable, sharded, one command on a big machine):
``fetchbench grasps build --hand robotiq_2f_85 --dir assets/grasps_robotiq --workers N``
(``--ids-file`` for a subset, e.g. the test objects).
"""
from __future__ import annotations

import functools
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np
import sapien
import trimesh

from ..robots import assets as robot_assets
from ..robots.agents import ROBOTIQ_CLOSED, ROBOTIQ_DAMPING, ROBOTIQ_FORCE_LIMIT, ROBOTIQ_STIFFNESS
from ..utils.io import atomic_write_text, sha256_bytes
from ..utils.mesh_cache import cache_dir
from . import hand as franka
from . import physics
from .settings import LabelSettings

HAND = "robotiq_2f_85"
DRIVEN_JOINTS = ("left_outer_knuckle_joint", "right_outer_knuckle_joint")
PASSIVE_JOINTS = ("left_inner_knuckle_joint", "right_inner_knuckle_joint", "left_inner_finger_joint",
                  "right_inner_finger_joint")
PAD_LINKS = ("left_inner_finger_pad", "right_inner_finger_pad")
#: The driving knuckle's angle beyond which the fingers count as fully closed (nothing held).
CLOSED_ANGLE = 0.79


@dataclass(frozen=True)
class RobotiqLabelSettings(LabelSettings):
    """The Franka labels' settings, for the Robotiq (recorded in its shards and manifest)."""

    hand: str = HAND
    #: Where the Franka-hand candidates come from (None: the shipped labels).
    franka_grasps_dir: str | None = None

    def as_dict(self) -> dict:
        d = super().as_dict()
        d.pop("franka_grasps_dir", None)  # a location, not a setting
        return d


@functools.lru_cache(maxsize=None)
def floating_robotiq_urdf() -> str:
    """A floating Robotiq: ManiSkill's six virtual joints (as in ``panda_v2_gripper.urdf``)
    ending in ``float_hand``, the grasp frame, and the Robotiq mounted so that its own
    ``robotiq_hand`` frame coincides with it; no visuals (a physics-only scene)."""
    source = ET.parse(franka.gripper_urdf_path()).getroot()
    robot = ET.Element("robot", name="floating_robotiq_2f_85")
    virtual_links = {"root"} | {j.find("child").get("link") for j in source.findall("joint")
                                if j.get("name") in franka.VIRTUAL_JOINTS}
    for link in source.findall("link"):
        if link.get("name") in virtual_links and link.get("name") != "panda_hand":
            robot.append(link)
    for joint in source.findall("joint"):
        if joint.get("name") in franka.VIRTUAL_JOINTS:
            if joint.find("child").get("link") == "panda_hand":
                joint.find("child").set("link", "float_hand")
            robot.append(joint)
    hand = ET.SubElement(robot, "link", name="float_hand")
    inertial = ET.SubElement(hand, "inertial")
    ET.SubElement(inertial, "mass", value="0.01")
    ET.SubElement(inertial, "inertia", ixx="1e-6", ixy="0", ixz="0", iyy="1e-6", iyz="0", izz="1e-6")
    extra = robot_assets.robotiq_hand(ET.Element("scratch"), "none")  # the grasp frame's offset
    # float_hand = base_link * Rz(yaw) * Tz(tcp_z - 0.1034); the mount is its inverse.
    yaw = _robotiq_inertia_yaw()
    ET.SubElement(robot, "link", name="tool_flange")
    joint = ET.SubElement(robot, "joint", name="float_mount_joint", type="fixed")
    ET.SubElement(joint, "origin", xyz=f"0 0 {-(extra['tcp_z'] - robot_assets.TCP_OFFSET)!r}", rpy=f"0 0 {-yaw!r}")
    ET.SubElement(joint, "parent", link="float_hand")
    ET.SubElement(joint, "child", link="tool_flange")
    robot_assets.robotiq_hand(robot, "tool_flange")
    for link in robot.findall("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
    text = ET.tostring(robot, encoding="unicode")
    path = cache_dir() / "urdf" / f"floating_robotiq_physics_{sha256_bytes(text.encode())[:16]}.urdf"
    if not path.exists():
        atomic_write_text(path, text)
    return os.fspath(path)


def _robotiq_inertia_yaw() -> float:
    root = robot_assets._robotiq_root()
    joint = next(j for j in root.findall("joint") if j.get("name") == "base_link_to_base_link_inertia")
    roll, pitch, yaw = (float(v) for v in joint.find("origin").get("rpy").split())
    if roll or pitch:
        raise ValueError("the Robotiq's base_link_inertia is expected to turn about z only")
    return yaw


@functools.lru_cache(maxsize=1)
def open_hand_mesh() -> trimesh.Trimesh:
    """The open Robotiq's collision geometry as one mesh in the grasp frame."""
    from ..planning.robot import robot_model

    model = robot_model("kinova_gen3_robotiq")
    poses = model.link_poses(np.asarray(model.q_home), model.finger_open)
    T_hand_base = np.linalg.inv(poses[model.hand_link][0].numpy())
    pieces = [model.collision_meshes[link].copy().apply_transform(T_hand_base @ poses[link][0].numpy())
              for link in model.hand_links]
    return trimesh.util.concatenate(pieces)


def collision_free(asset, T_object_hand: np.ndarray) -> np.ndarray:
    """(N,) whether the open Robotiq at each grasp pose stays clear of the object's convex parts."""
    manager = trimesh.collision.CollisionManager()
    for k, part in enumerate(asset.convex_parts):
        manager.add_object(f"part{k}", part)
    hand = open_hand_mesh()
    return np.array([not manager.in_collision_single(hand, transform=T) for T in T_object_hand], dtype=bool)


class RobotiqLabeller(physics.GraspLabeller):
    """``physics.GraspLabeller`` with floating Robotiqs instead of Franka hands."""

    PAD_LINKS = PAD_LINKS
    DRIVEN_FINGER_JOINTS = DRIVEN_JOINTS
    HAND_LINK = "float_hand"

    def _hand_urdf(self) -> str:
        return floating_robotiq_urdf()

    def _set_up_fingers(self, joints: dict) -> None:
        """The outer knuckles driven, the rest of the linkage passive, each inner finger tied
        to its inner knuckle by a drive (the closed loop a URDF cannot state)."""
        anchors = robot_assets.urdf_extra("kinova_gen3_robotiq")["anchors"]
        for name in DRIVEN_JOINTS:
            joints[name].set_drive_properties(ROBOTIQ_STIFFNESS, ROBOTIQ_DAMPING, ROBOTIQ_FORCE_LIMIT)
            joints[name].set_friction(0.05)
        for name in PASSIVE_JOINTS:
            joints[name].set_drive_properties(0.0, 0.0, 0.0)
            joints[name].set_friction(0.0)
        for side in ("left", "right"):
            finger = joints[f"{side}_inner_finger_joint"].get_child_link()
            knuckle = joints[f"{side}_inner_knuckle_joint"].get_child_link()
            drive = self.scene.create_drive(knuckle, sapien.Pose(anchors[side]["knuckle"]),
                                            finger, sapien.Pose(anchors[side]["finger"]))
            drive.set_limit_x(0, 0)
            drive.set_limit_y(0, 0)
            drive.set_limit_z(0, 0)

    def _open_gripper(self, i: int, qpos: np.ndarray) -> None:
        pass  # every joint at 0: open

    def _open_targets(self, i: int) -> None:
        pass  # drive targets 0: open

    def _close(self, i: int) -> None:
        for k in self._finger_idx:
            self._joints[i][k].set_drive_target(ROBOTIQ_CLOSED)

    def _width(self, qpos: np.ndarray) -> float:
        from ..planning.robot import robot_model

        return 2 * robot_model("kinova_gen3_robotiq").finger_from_gripper_q(qpos[self._finger_idx[:1]])

    def _open_enough(self, qpos: np.ndarray) -> bool:
        return bool(np.all(qpos[self._finger_idx] < CLOSED_ANGLE))


def franka_candidates(object_id: str, directory: str | None = None) -> np.ndarray:
    """Every Franka-hand trial pose of the object in the labels (N, 4, 4)."""
    from .store import _store, default_dir

    trials = _store(os.fspath(directory or default_dir())).load(object_id)
    return np.asarray(trials.T_object_hand, dtype=float)


def label_object_robotiq(asset, settings: RobotiqLabelSettings):
    """The Robotiq's trials on one object (``build.label_object`` for ``hand="robotiq_2f_85"``)."""
    from .store import ObjectTrials

    candidates = franka_candidates(asset.object_id, getattr(settings, "franka_grasps_dir", None))
    candidates = candidates[collision_free(asset, candidates)] if len(candidates) else candidates
    labeller = RobotiqLabeller(slots=settings.slots, config=settings.trial, object_friction=settings.object_friction)
    labeller.set_object(asset, density=settings.density)
    result = labeller.label(asset, candidates)
    return ObjectTrials(object_id=asset.object_id, T_object_hand=candidates, success=result.success,
                        width=result.width)


__all__ = ["HAND", "RobotiqLabelSettings", "RobotiqLabeller", "collision_free", "floating_robotiq_urdf",
           "label_object_robotiq"]
