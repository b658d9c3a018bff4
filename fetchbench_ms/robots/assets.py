"""URDFs of the other hardware setups, generated at run time from files that come inside
installed index packages (nothing is downloaded, nothing large is shipped here).

Sources (licences in docs/robots.md):

- Kinova Gen3 (7-DOF): ``robosuite`` (MIT) ships its MuJoCo model
  (``models/assets/robots/kinova3/robot.xml`` + STL meshes); the body tree is converted
  to URDF joints and links here (positions, quaternions, axes, ranges and inertias taken
  as they are).
- Franka hand: ManiSkill's own ``panda_v2.urdf`` (the hand, finger and TCP links the
  Panda agent uses), copied with absolute mesh paths.
- Robotiq 2F-85: ``airo-models`` (MIT) ships the ROS-Industrial ``robotiq_arg2f_85``
  URDF with meshes; its ``mimic`` tags are read (the coupling of its six joints) and
  dropped (SAPIEN closes the four-bar linkage with a drive instead, as ManiSkill's own
  Robotiq agents do), and two frames are added: ``robotiq_hand``, the grasp frame in the
  Franka hand's convention (approach along +z, closing along y, tool centre point
  ``robotiq_tcp`` 0.1034 m along +z), with the TCP between the finger pads.

The generated file is written to ``$FETCHBENCH_CACHE/robots`` under a name that hashes
its text, so it changes whenever a source file or this generator changes.
"""
from __future__ import annotations

import copy
import importlib.util
import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..utils.io import atomic_write_text, sha256_bytes
from ..utils.mesh_cache import cache_dir

GENERATOR_VERSION = "1"
#: The Franka hand's TCP offset (panda_hand -> panda_hand_tcp), the grasp convention of
#: every hand here (docs/grasps.md).
TCP_OFFSET = 0.1034
#: Kinova Gen3 user guide (UG-014, technical specifications): maximum joint speeds (rad/s)
#: of the large (joints 1-4) and small (5-7) actuators; the MuJoCo model has none. (Torque
#: limits come from the model's actuators, which cite the same guide.)
GEN3_VELOCITY = (1.3963,) * 4 + (1.2218,) * 3
#: Range given to the Gen3's continuous joints (1, 3, 5, 7): one turn either way is all a
#: planner needs, and a bounded box keeps RRT sampling and IK seeding uniform.
CONTINUOUS_RANGE = math.pi
GEN3_LINKS = ("base_link", "shoulder_link", "half_arm_1_link", "half_arm_2_link", "forearm_link",
              "spherical_wrist_1_link", "spherical_wrist_2_link", "bracelet_link")
GEN3_JOINTS = tuple(f"joint_{i}" for i in range(1, 8))
#: The Gen3's tool flange: 0.0615 m below the bracelet link's origin along -z (Kinova's
#: ``end_effector_link``); a tool's +z points away from the arm.
GEN3_FLANGE_XYZ = (0.0, 0.0, -0.0615)
GEN3_FLANGE_RPY = (math.pi, 0.0, 0.0)
ROBOTIQ_PREFIX = "robotiq_"


class MissingRobotAsset(RuntimeError):
    """A package that carries a robot's model is not installed."""


def package_dir(package: str, why: str) -> Path:
    """The installed folder of ``package`` (found without importing it)."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise MissingRobotAsset(f"the package {package!r} is not installed; it carries {why} "
                                f"(install it: pip install --no-deps -r requirements-nodeps.txt)")
    return Path(list(spec.submodule_search_locations)[0])


def gen3_mjcf_path() -> Path:
    return package_dir("robosuite", "the Kinova Gen3 model") / "models" / "assets" / "robots" / "kinova3" / "robot.xml"


def robotiq_urdf_path() -> Path:
    return package_dir("airo_models", "the Robotiq 2F-85 model") / "grippers" / "robotiq_2f_85" / "urdf" / "robotiq_2f_85.urdf"


def panda_urdf_source() -> Path:
    return package_dir("mani_skill", "the Panda and the Franka hand") / "assets" / "robots" / "panda" / "panda_v2.urdf"


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def _quat_wxyz_to_rpy(quat) -> np.ndarray:
    w, x, y, z = (float(v) for v in quat)
    return Rotation.from_quat([x, y, z, w]).as_euler("xyz")


def _sub(parent, tag, **attrs):
    el = ET.SubElement(parent, tag)
    for k, v in attrs.items():
        el.set(k, v)
    return el


def _inertial(link, mass, pos, quat, diag) -> None:
    """An MJCF inertial (principal axes at ``quat``) as a URDF inertia tensor in the link frame."""
    w, x, y, z = quat
    R = Rotation.from_quat([x, y, z, w]).as_matrix()
    I = R @ np.diag(diag) @ R.T
    el = _sub(link, "inertial")
    _sub(el, "origin", xyz=_fmt(pos), rpy="0 0 0")
    _sub(el, "mass", value=repr(float(mass)))
    _sub(el, "inertia", ixx=repr(float(I[0, 0])), ixy=repr(float(I[0, 1])), ixz=repr(float(I[0, 2])), iyy=repr(float(I[1, 1])),
         iyz=repr(float(I[1, 2])), izz=repr(float(I[2, 2])))


def _floats(text, default):
    return [float(v) for v in (text or default).split()]


def gen3_arm(robot: ET.Element) -> str:
    """Add the Gen3's links and joints (from robosuite's MJCF) to ``robot``; returns the
    flange link's name (a frame 0.0615 m beyond the bracelet, +z out of the arm)."""
    path = gen3_mjcf_path()
    root = ET.parse(path).getroot()
    meshes = {m.get("name"): str(path.parent / m.get("file")) for m in root.iter("mesh")}
    effort = {m.get("joint"): max(abs(v) for v in _floats(m.get("ctrlrange"), "0 0")) for m in root.iter("motor")}
    body = root.find("worldbody").find("body").find("body")  # base -> fixed_base_link
    parent_name, k = None, 0
    while body is not None:
        name = GEN3_LINKS[k]
        link = _sub(robot, "link", name=name)
        inertial = body.find("inertial")
        if inertial is not None and float(inertial.get("mass")) > 0:
            _inertial(link, float(inertial.get("mass")), _floats(inertial.get("pos"), "0 0 0"),
                      _floats(inertial.get("quat"), "1 0 0 0"), _floats(inertial.get("diaginertia"), "0 0 0"))
        for geom in body.findall("geom"):
            if geom.get("type") != "mesh":
                continue
            tag = "visual" if geom.get("contype") == "0" else "collision"
            el = _sub(link, tag)
            _sub(el, "origin", xyz="0 0 0", rpy="0 0 0")
            _sub(_sub(el, "geometry"), "mesh", filename=meshes[geom.get("mesh")])
            if tag == "visual":
                _sub(_sub(el, "material", name=f"{name}_grey"), "color", rgba="0.75 0.75 0.75 1")
        if parent_name is not None:
            mj = body.find("joint")
            limited = mj.get("range") is not None
            joint = _sub(robot, "joint", name=GEN3_JOINTS[k - 1], type="revolute")
            _sub(joint, "origin", xyz=_fmt(_floats(body.get("pos"), "0 0 0")),
                 rpy=_fmt(_quat_wxyz_to_rpy(_floats(body.get("quat"), "1 0 0 0"))))
            _sub(joint, "parent", link=parent_name)
            _sub(joint, "child", link=name)
            _sub(joint, "axis", xyz=_fmt(_floats(mj.get("axis"), "0 0 1")))
            lo, hi = _floats(mj.get("range"), "0 0") if limited else (-CONTINUOUS_RANGE, CONTINUOUS_RANGE)
            _sub(joint, "limit", lower=repr(float(lo)), upper=repr(float(hi)), effort=repr(effort[mj.get("name")]),
                 velocity=repr(GEN3_VELOCITY[k - 1]))
            _sub(joint, "dynamics", damping=mj.get("damping", "0.1"), friction="0")
        parent_name = name
        k += 1
        body = next((b for b in body.findall("body") if b.get("name") != "right_hand"), None)
        if k == len(GEN3_LINKS):
            break
    if k != len(GEN3_LINKS):
        raise ValueError(f"{path}: expected the Gen3's {len(GEN3_LINKS)} bodies, found {k}")
    _sub(robot, "link", name="tool_flange")
    joint = _sub(robot, "joint", name="tool_flange_joint", type="fixed")
    _sub(joint, "origin", xyz=_fmt(GEN3_FLANGE_XYZ), rpy=_fmt(GEN3_FLANGE_RPY))
    _sub(joint, "parent", link=GEN3_LINKS[-1])
    _sub(joint, "child", link="tool_flange")
    return "tool_flange"


def _absolute_meshes(element: ET.Element, base: Path) -> None:
    for mesh in element.iter("mesh"):
        mesh.set("filename", str((base / mesh.get("filename")).resolve()))


def franka_hand(robot: ET.Element, flange: str) -> None:
    """ManiSkill's Franka hand (panda_hand, fingers, TCP and pad frames) on ``flange``,
    turned as on the Panda's flange (-45 deg about z)."""
    path = panda_urdf_source()
    src = ET.parse(path).getroot()
    keep = {"panda_hand", "panda_hand_tcp", "panda_leftfinger", "panda_rightfinger",
            "panda_leftfinger_pad", "panda_rightfinger_pad"}
    for link in src.findall("link"):
        if link.get("name") in keep:
            link = copy.deepcopy(link)
            _absolute_meshes(link, path.parent)
            robot.append(link)
    for joint in src.findall("joint"):
        if joint.find("child").get("link") in keep:
            joint = copy.deepcopy(joint)
            if joint.get("name") == "panda_hand_joint":
                joint.set("name", "hand_mount_joint")
                joint.find("parent").set("link", flange)
            robot.append(joint)


def _robotiq_root() -> ET.Element:
    """The Robotiq URDF, less its Drake collision-filter tags (an unbound XML prefix)."""
    text = robotiq_urdf_path().read_text()
    text = re.sub(r"<drake:collision_filter_group.*?</drake:collision_filter_group>", "", text, flags=re.S)
    return ET.fromstring(text)


def robotiq_mimic() -> dict[str, tuple[str, float]]:
    """The Robotiq's joint coupling from its URDF: joint -> (driving joint, multiplier),
    with the driving joint renamed as here."""
    root = _robotiq_root()
    out = {}
    for joint in root.findall("joint"):
        mimic = joint.find("mimic")
        if mimic is not None:
            out[_robotiq_joint_name(joint.get("name"))] = (_robotiq_joint_name(mimic.get("joint")),
                                                           float(mimic.get("multiplier", "1")))
    return out


def _robotiq_link_name(name: str) -> str:
    return ROBOTIQ_PREFIX + name if name.startswith("base_link") else name


def _robotiq_joint_name(name: str) -> str:
    # ManiSkill's Robotiq agents (and most ROS descriptions) call the driving joint this.
    return "left_outer_knuckle_joint" if name == "finger_joint" else name


def robotiq_hand(robot: ET.Element, flange: str) -> dict:
    """The Robotiq 2F-85 on ``flange`` (its base z along the flange's z), plus the
    ``robotiq_hand`` grasp frame and the ``robotiq_tcp``. Returns the geometry the
    simulation needs (the four-bar anchor points)."""
    path = robotiq_urdf_path()
    src = _robotiq_root()
    for link in src.findall("link"):
        link = copy.deepcopy(link)
        link.set("name", _robotiq_link_name(link.get("name")))
        for origin in link.findall("origin"):  # a stray origin directly under <link>
            link.remove(origin)
        for col in link.findall("collision"):  # collision materials confuse some parsers
            for mat in col.findall("material"):
                col.remove(mat)
        _absolute_meshes(link, path.parent)
        robot.append(link)
    joints = {}
    for joint in src.findall("joint"):
        joint = copy.deepcopy(joint)
        joint.set("name", _robotiq_joint_name(joint.get("name")))
        for mimic in joint.findall("mimic"):
            joint.remove(mimic)
        for tag in ("parent", "child"):
            joint.find(tag).set("link", _robotiq_link_name(joint.find(tag).get("link")))
        joints[joint.get("name")] = joint
        robot.append(joint)
    mount = _sub(robot, "joint", name="hand_mount_joint", type="fixed")
    _sub(mount, "origin", xyz="0 0 0", rpy="0 0 0")
    _sub(mount, "parent", link=flange)
    _sub(mount, "child", link=ROBOTIQ_PREFIX + "base_link")

    def xyz(name):
        return np.array(_floats(joints[name].find("origin").get("xyz"), "0 0 0"))

    def rpy(name):
        return Rotation.from_euler("xyz", _floats(joints[name].find("origin").get("rpy"), "0 0 0")).as_matrix()

    # The pads' centre at the open pose, in the frame the fingers close in (base_link_inertia):
    # outer knuckle -> outer finger -> inner finger -> pad, all unrotated at zero.
    side = "right"
    pad = (xyz(f"{side}_outer_knuckle_joint") + rpy(f"{side}_outer_knuckle_joint") @ (
        xyz(f"{side}_outer_finger_joint") + xyz(f"{side}_inner_finger_joint") + xyz(f"{side}_inner_finger_pad_joint")))
    tcp_z = float(pad[2])
    _sub(robot, "link", name="robotiq_hand")
    joint = _sub(robot, "joint", name="robotiq_hand_joint", type="fixed")
    _sub(joint, "origin", xyz=_fmt((0.0, 0.0, tcp_z - TCP_OFFSET)), rpy="0 0 0")
    _sub(joint, "parent", link=ROBOTIQ_PREFIX + "base_link_inertia")
    _sub(joint, "child", link="robotiq_hand")
    _sub(robot, "link", name="robotiq_tcp")
    joint = _sub(robot, "joint", name="robotiq_tcp_joint", type="fixed")
    _sub(joint, "origin", xyz=_fmt((0.0, 0.0, TCP_OFFSET)), rpy="0 0 0")
    _sub(joint, "parent", link="robotiq_hand")
    _sub(joint, "child", link="robotiq_tcp")
    # Four-bar closure: the inner knuckle's far pivot is the point of the inner finger
    # where it meets the outer finger's (a parallelogram): in the inner knuckle's frame the
    # same vector as that joint in the outer knuckle's frame; in the inner finger's frame,
    # the offset between the two knuckles' base pivots.
    anchors = {}
    for side in ("left", "right"):
        R_outer = rpy(f"{side}_outer_knuckle_joint")
        anchors[side] = dict(
            knuckle=(xyz(f"{side}_outer_finger_joint") + xyz(f"{side}_inner_finger_joint")).tolist(),
            finger=(R_outer.T @ (xyz(f"{side}_inner_knuckle_joint") - xyz(f"{side}_outer_knuckle_joint"))).tolist())
    return dict(tcp_z=tcp_z, anchors=anchors)


_BUILT: dict = {}  # uid -> (URDF path, extra geometry), per process


def build_urdf(uid: str) -> tuple[str, dict]:
    """(URDF text, extra geometry) of a setup: ``kinova_gen3_panda_hand`` or ``kinova_gen3_robotiq``."""
    robot = ET.Element("robot", name=uid)
    flange = gen3_arm(robot)
    extra = {}
    if uid == "kinova_gen3_panda_hand":
        franka_hand(robot, flange)
    elif uid == "kinova_gen3_robotiq":
        extra = robotiq_hand(robot, flange)
    else:
        raise ValueError(f"no generated URDF for robot {uid!r}; valid: kinova_gen3_panda_hand, kinova_gen3_robotiq")
    ET.indent(robot)
    text = f"<?xml version=\"1.0\"?>\n<!-- generated by fetchbench_ms.robots.assets v{GENERATOR_VERSION} -->\n" \
        + ET.tostring(robot, encoding="unicode") + "\n"
    return text, extra


def urdf_path(uid: str) -> str:
    """The generated URDF of ``uid``, written once per content to ``$FETCHBENCH_CACHE/robots``."""
    if uid not in _BUILT:
        text, extra = build_urdf(uid)
        path = cache_dir() / "robots" / f"{uid}_{sha256_bytes(text.encode())[:16]}.urdf"
        if not path.exists():
            atomic_write_text(path, text)
        _BUILT[uid] = (str(path), extra)
    return _BUILT[uid][0]


def urdf_extra(uid: str) -> dict:
    urdf_path(uid)
    return _BUILT[uid][1]
