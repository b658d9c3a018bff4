"""The hardware setups a task can be run with (``robot_uids`` of the envs, ``--robot`` of
``fetchbench eval``): the Panda (default), the Kinova Gen3 with the Franka hand, and the
Kinova Gen3 with a Robotiq 2F-85 (docs/robots.md).

A ``RobotSetup`` is plain data: the names the planner, the env and the grasp code read
(joints, links, frames), so the code never spells a robot's link names itself. The
Panda's values are the constants the planner always had, so its behaviour is unchanged.

Frames shared by every setup: the grasp frame ``hand_link`` follows the Franka hand's
convention (approach along +z, fingers closing along y, the TCP ``tcp_link`` 0.1034 m
along +z between the finger pads), so one grasp pose ``T_object_hand`` means the same
TCP pose on every hand: a Franka-hand grasp carries over to the Robotiq with the same
approach axis and width, offset by the Robotiq's own tool frame (``robots.assets``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

DEFAULT_ROBOT = "panda"


@dataclass(frozen=True)
class RobotSetup:
    uid: str
    arm: str  # "franka" | "kinova_gen3"
    hand: str  # "franka_hand" | "robotiq_2f_85"
    arm_joints: tuple[str, ...]
    #: The gripper's joints in the planner's joint vector, after the arm's; their values
    #: follow from one finger opening (m per finger) through ``gripper_coupling``.
    gripper_joints: tuple[str, ...]
    base_link: str  # the root, standing on the robot table
    hand_link: str  # the grasp frame (Franka-hand convention)
    tcp_link: str
    finger_links: tuple[str, str]  # the links that touch a grasped object (left, right)
    #: +1 / -1: the sign of each finger link's y axis that points away from the object
    #: (the direction that opens it), for the env's grasp test.
    finger_open_signs: tuple[float, float]
    hand_links: tuple[str, ...]  # every link of the hand (rigid with the grasp frame or moving fingers)
    wrist_link: str  # the last arm link, rigid with the hand
    #: Links near the base that a carried object is checked against (it may touch the hand).
    proximal_links: tuple[str, ...]
    #: Links whose spheres are checked against the world (the base stands on its table).
    world_links: tuple[str, ...]
    #: Per-finger opening (m) of the open hand, and the largest.
    finger_open: float
    #: Joint acceleration limits (rad/s^2): URDFs carry velocities only.
    acceleration_limits: tuple[float, ...]
    #: The arm's start configuration (and the fingers open).
    q_home: tuple[float, ...]
    #: Sphere fit overrides per link: (spheres, margin).
    link_fit: dict = field(default_factory=dict)
    #: What the generated URDF is made from (docs/robots.md has the licences).
    sources: tuple[str, ...] = ()

    @property
    def n_arm(self) -> int:
        return len(self.arm_joints)


_PANDA_ARM = tuple(f"panda_joint{i}" for i in range(1, 8))
_FRANKA_HAND_LINKS = ("panda_hand", "panda_leftfinger", "panda_rightfinger")
_FRANKA_HAND_FIT = {"panda_leftfinger": (10, 0.002), "panda_rightfinger": (10, 0.002), "panda_hand": (12, 0.003)}
_GEN3_ARM = tuple(f"joint_{i}" for i in range(1, 8))
_GEN3_LINKS = ("shoulder_link", "half_arm_1_link", "half_arm_2_link", "forearm_link", "spherical_wrist_1_link",
               "spherical_wrist_2_link", "bracelet_link")
#: The Gen3's models carry no acceleration limits; 5.2 rad/s^2 for every joint is an
#: assumption (the order of what Kinova's ROS driver configures), below the Panda's
#: 7.5-20: the executor's time parametrisation is the only reader.
_GEN3_ACCELERATION = (5.2,) * 7
#: The Gen3's start configurations, printed by ``scripts/maint/robot_home.py``: the IK solution
#: that puts the TCP where the Panda's start configuration puts the Panda's (with the
#: longer Robotiq, 3 cm lower: the highest it reaches), farthest from the joint limits;
#: ``tests/test_robots.py`` checks they still do.
_GEN3_HOME_FRANKA_HAND = (0.2708, -0.3683, -0.1712, 1.2869, -0.0768, 2.2167, 2.4207)
_GEN3_HOME_ROBOTIQ = (2.9388, 0.3716, 0.1483, -1.3015, 0.0668, -2.2069, -1.5949)
_ROBOTIQ_LINKS = ("robotiq_base_link_inertia", "left_outer_knuckle", "left_outer_finger", "left_inner_finger",
                  "left_inner_finger_pad", "left_inner_knuckle", "right_outer_knuckle", "right_outer_finger",
                  "right_inner_finger", "right_inner_finger_pad", "right_inner_knuckle")
_ROBOTIQ_JOINTS = ("left_outer_knuckle_joint", "left_inner_finger_joint", "left_inner_knuckle_joint",
                   "right_outer_knuckle_joint", "right_inner_finger_joint", "right_inner_knuckle_joint")

SETUPS: dict[str, RobotSetup] = {
    "panda": RobotSetup(
        uid="panda", arm="franka", hand="franka_hand", arm_joints=_PANDA_ARM,
        gripper_joints=("panda_finger_joint1", "panda_finger_joint2"),
        base_link="panda_link0", hand_link="panda_hand", tcp_link="panda_hand_tcp",
        finger_links=("panda_leftfinger", "panda_rightfinger"), finger_open_signs=(1.0, -1.0),
        hand_links=_FRANKA_HAND_LINKS, wrist_link="panda_link7",
        proximal_links=("panda_link0", "panda_link1", "panda_link2", "panda_link3", "panda_link4"),
        world_links=tuple(f"panda_link{i}" for i in range(1, 8)) + _FRANKA_HAND_LINKS,
        finger_open=0.04, acceleration_limits=(15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
        q_home=(-0.3127, -1.1997, 0.0578, -2.1768, 0.0649, 0.9786, 0.5300),
        link_fit=_FRANKA_HAND_FIT, sources=("mani_skill: panda_v2.urdf",)),
    "kinova_gen3_panda_hand": RobotSetup(
        uid="kinova_gen3_panda_hand", arm="kinova_gen3", hand="franka_hand", arm_joints=_GEN3_ARM,
        gripper_joints=("panda_finger_joint1", "panda_finger_joint2"),
        base_link="base_link", hand_link="panda_hand", tcp_link="panda_hand_tcp",
        finger_links=("panda_leftfinger", "panda_rightfinger"), finger_open_signs=(1.0, -1.0),
        hand_links=_FRANKA_HAND_LINKS, wrist_link="bracelet_link",
        proximal_links=("base_link",) + _GEN3_LINKS[:4],
        world_links=_GEN3_LINKS + _FRANKA_HAND_LINKS,
        finger_open=0.04, acceleration_limits=_GEN3_ACCELERATION, q_home=_GEN3_HOME_FRANKA_HAND,
        link_fit=_FRANKA_HAND_FIT,
        sources=("robosuite: models/assets/robots/kinova3", "mani_skill: panda_v2.urdf (hand)")),
    "kinova_gen3_robotiq": RobotSetup(
        uid="kinova_gen3_robotiq", arm="kinova_gen3", hand="robotiq_2f_85", arm_joints=_GEN3_ARM,
        gripper_joints=_ROBOTIQ_JOINTS,
        base_link="base_link", hand_link="robotiq_hand", tcp_link="robotiq_tcp",
        finger_links=("left_inner_finger_pad", "right_inner_finger_pad"), finger_open_signs=(1.0, 1.0),
        hand_links=_ROBOTIQ_LINKS, wrist_link="bracelet_link",
        proximal_links=("base_link",) + _GEN3_LINKS[:4],
        world_links=_GEN3_LINKS + _ROBOTIQ_LINKS,
        finger_open=0.0425, acceleration_limits=_GEN3_ACCELERATION, q_home=_GEN3_HOME_ROBOTIQ,
        link_fit={"left_inner_finger_pad": (4, 0.002), "right_inner_finger_pad": (4, 0.002),
                  "left_inner_finger": (6, 0.002), "right_inner_finger": (6, 0.002),
                  "robotiq_base_link_inertia": (10, 0.003)},
        sources=("robosuite: models/assets/robots/kinova3", "airo-models: grippers/robotiq_2f_85")),
}
ROBOT_UIDS = tuple(SETUPS)


def robot_setup(uid: str | None) -> RobotSetup:
    """The setup of ``uid`` (None: the Panda); ValueError naming the valid uids."""
    uid = DEFAULT_ROBOT if uid is None else uid
    if uid not in SETUPS:
        raise ValueError(f"unknown robot {uid!r}; valid: {', '.join(ROBOT_UIDS)}")
    return SETUPS[uid]


def check_robot_uid(uid) -> str:
    if not isinstance(uid, str):
        raise ValueError(f"robot_uids must be one robot uid (a string), got {uid!r}; valid: {', '.join(ROBOT_UIDS)}")
    return robot_setup(uid).uid


__all__ = ["DEFAULT_ROBOT", "ROBOT_UIDS", "SETUPS", "RobotSetup", "check_robot_uid", "robot_setup"]
