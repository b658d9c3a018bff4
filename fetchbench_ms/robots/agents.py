"""ManiSkill agents of the other setups (registered with ``@register_agent`` on import).

- ``kinova_gen3_panda_hand``: ManiSkill's Panda agent with the Gen3 arm under the same
  Franka hand: the same controllers, gains, gripper and grasp test; only the arm's
  joints and URDF differ.
- ``kinova_gen3_robotiq``: the Gen3 with a Robotiq 2F-85 as ManiSkill's own Robotiq
  agents drive it: the two outer knuckles follow one PD target (a mimic controller), the
  inner knuckles and fingers are passive and a drive per side closes the four-bar linkage
  (anchor points computed from the URDF, ``robots.assets``). Its gripper action runs
  from -1 (open) to +1 (closed, squeezing), ManiSkill's Robotiq convention; the Panda's
  is the other way round (``gripper_action_sign``).

The URDFs are generated on first use (``robots.assets.urdf_path``), so importing this
module needs none of the asset packages.
"""
from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.agents.base_agent import BaseAgent, Keyframe
from mani_skill.agents.controllers import PassiveControllerConfig, PDJointPosMimicControllerConfig
from mani_skill.agents.registration import register_agent
from mani_skill.agents.robots.panda.panda import Panda
from mani_skill.utils import common, sapien_utils
from mani_skill.utils.structs.actor import Actor

from . import SETUPS, assets

ROBOTIQ_CLOSED = 0.82  # rad of the driving knuckle: past closed (~0.8), so the fingers keep squeezing
ROBOTIQ_STIFFNESS = 1e5
ROBOTIQ_DAMPING = 1e3
ROBOTIQ_FORCE_LIMIT = 5.0  # N m on each outer knuckle


@register_agent()
class KinovaGen3PandaHand(Panda):
    uid = "kinova_gen3_panda_hand"
    arm_joint_names = list(SETUPS["kinova_gen3_panda_hand"].arm_joints)
    keyframes = dict(rest=Keyframe(qpos=np.array(list(SETUPS["kinova_gen3_panda_hand"].q_home) + [0.04, 0.04]),
                                   pose=sapien.Pose()))
    gripper_action_sign = 1.0

    @property
    def urdf_path(self):
        return assets.urdf_path(self.uid)


@register_agent()
class KinovaGen3Robotiq(BaseAgent):
    uid = "kinova_gen3_robotiq"
    setup = SETUPS["kinova_gen3_robotiq"]
    arm_joint_names = list(setup.arm_joints)
    ee_link_name = setup.tcp_link
    # The Panda's arm gains: one hardware change at a time.
    arm_stiffness, arm_damping, arm_force_limit = Panda.arm_stiffness, Panda.arm_damping, Panda.arm_force_limit
    gripper_action_sign = -1.0
    #: ``settle_and_hold``'s drive targets for the gripper: past closed, squeezing.
    squeeze_targets = dict(left_outer_knuckle_joint=ROBOTIQ_CLOSED, right_outer_knuckle_joint=ROBOTIQ_CLOSED)
    urdf_config = dict(
        _materials=dict(gripper=dict(static_friction=2.0, dynamic_friction=2.0, restitution=0.0)),
        link=dict(left_inner_finger_pad=dict(material="gripper", patch_radius=0.1, min_patch_radius=0.1),
                  right_inner_finger_pad=dict(material="gripper", patch_radius=0.1, min_patch_radius=0.1)),
    )
    keyframes = dict(rest=Keyframe(qpos=np.array(list(setup.q_home) + [0.0] * 6), pose=sapien.Pose()))
    passive_joint_names = ["left_inner_knuckle_joint", "right_inner_knuckle_joint",
                           "left_inner_finger_joint", "right_inner_finger_joint"]
    driven_joint_names = ["left_outer_knuckle_joint", "right_outer_knuckle_joint"]
    # Read by the Panda's controller code, whose gripper part is replaced below.
    gripper_joint_names = driven_joint_names
    gripper_stiffness, gripper_damping, gripper_force_limit = ROBOTIQ_STIFFNESS, ROBOTIQ_DAMPING, ROBOTIQ_FORCE_LIMIT

    @property
    def urdf_path(self):
        return assets.urdf_path(self.uid)

    @property
    def _controller_configs(self):
        # The Panda's arm controllers (its gains, delta ranges and EE frames), this robot's joints.
        panda = Panda._controller_configs.fget(self)
        mimic = dict(right_outer_knuckle_joint=dict(joint="left_outer_knuckle_joint", multiplier=1.0, offset=0.0))
        common_kw = dict(stiffness=ROBOTIQ_STIFFNESS, damping=ROBOTIQ_DAMPING, force_limit=ROBOTIQ_FORCE_LIMIT,
                         friction=0.05, mimic=mimic)
        gripper_pos = PDJointPosMimicControllerConfig(self.driven_joint_names, lower=0.0, upper=ROBOTIQ_CLOSED,
                                                      normalize_action=True, **common_kw)
        gripper_delta = PDJointPosMimicControllerConfig(self.driven_joint_names, lower=-0.15, upper=0.15,
                                                        normalize_action=True, use_delta=True, **common_kw)
        passive = PassiveControllerConfig(joint_names=self.passive_joint_names, damping=0, friction=0)
        out = {}
        for mode, parts in panda.items():
            delta = mode.startswith("pd_joint_delta") or mode.startswith("pd_ee_delta") or "target_delta" in mode
            out[mode] = dict(arm=parts["arm"], gripper_active=gripper_delta if delta else gripper_pos,
                             gripper_passive=passive)
        return out

    def _after_loading_articulation(self):
        anchors = assets.urdf_extra(self.uid)["anchors"]
        for side in ("left", "right"):
            finger = self.robot.active_joints_map[f"{side}_inner_finger_joint"].get_child_link()
            knuckle = self.robot.active_joints_map[f"{side}_inner_knuckle_joint"].get_child_link()
            drive = self.scene.create_drive(knuckle, sapien.Pose(anchors[side]["knuckle"]),
                                            finger, sapien.Pose(anchors[side]["finger"]))
            drive.set_limit_x(0, 0)
            drive.set_limit_y(0, 0)
            drive.set_limit_z(0, 0)

    def _after_init(self):
        self.finger1_link = sapien_utils.get_obj_by_name(self.robot.get_links(), self.setup.finger_links[0])
        self.finger2_link = sapien_utils.get_obj_by_name(self.robot.get_links(), self.setup.finger_links[1])
        self.tcp = sapien_utils.get_obj_by_name(self.robot.get_links(), self.ee_link_name)

    def is_grasping(self, object: Actor, min_force=0.5, max_angle=85):
        """Both pads push on ``object`` (>= ``min_force`` N, within ``max_angle`` deg of the
        direction that opens them), as the Panda's test."""
        flags = []
        for link, sign in zip((self.finger1_link, self.finger2_link), self.setup.finger_open_signs):
            force = self.scene.get_pairwise_contact_forces(link, object)
            direction = sign * link.pose.to_transformation_matrix()[..., :3, 1]
            angle = common.compute_angle_between(direction, force)
            flags.append((torch.linalg.norm(force, axis=1) >= min_force) & (torch.rad2deg(angle) <= max_angle))
        return torch.logical_and(*flags)

    def is_static(self, threshold: float = 0.2):
        qvel = self.robot.get_qvel()[..., : len(self.arm_joint_names)]
        return torch.max(torch.abs(qvel), 1)[0] <= threshold

    @property
    def tcp_pose(self):
        return self.tcp.pose
