"""Physics verification of grasp candidates in SAPIEN with ManiSkill's floating Franka hand.

One ``GraspLabeller`` owns one physics-only SAPIEN scene holding ``slots`` floating
grippers (``panda_v2_gripper.urdf``: six virtual joints from a fixed root to the hand),
spaced far apart, each with its own copy of the object. One batch tests ``slots``
candidates at once, so a Python-side step costs the same for one trial or sixteen.

A trial, per candidate (object pose fixed in the world, object z up as in the catalog,
so gravity acts as it will on the shelf):
1. The gripper root is put at the candidate hand pose, fingers open, the object at rest
   with its gravity off.
2. The fingers close for ``close_s`` with the env Panda's gripper drive
   (stiffness 1e3, damping 1e2, force limit 100 N, target -0.01 m) and finger friction 2.0.
3. Object gravity on; the hand shakes for ``shake_s``: +-3 cm vertically and +-0.5 rad
   about the TCP (first half about the hand x axis, second half about the closing y axis)
   at 2 Hz, through the virtual joints' PD drives.
4. Success: both fingers still touch the object, the fingers are not fully closed, and
   the point of the object that was at the TCP after closing is still within 5 cm of it.

Object physics: density ``DENSITY`` (the middle of the benchmark's U(100, 400) kg/m^3)
and a fixed friction ``OBJECT_FRICTION`` = 0.6, the lowest of the benchmark's
U(0.6, 1.2): labels are conservative for every object friction an episode can draw.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import sapien
from scipy.spatial.transform import Rotation

from ..objects.asset import ObjectAsset
from ..utils.mesh_cache import mesh_file
from . import hand as franka
from .sampler import canonical_part

DENSITY = 250.0
OBJECT_FRICTION = 0.6
SIM_FREQ = 100  # Hz, ManiSkill's default
#: PhysX contact offset, m. ManiSkill's default is 0.02; 5 mm generates the same contacts
#: once bodies touch (fingers close at < 2 mm per step) but far fewer speculative pairs on
#: objects of many convex parts, which made those trials 2-3.5x slower.
CONTACT_OFFSET = 0.005


@dataclass(frozen=True)
class TrialConfig:
    close_s: float = 0.5
    shake_s: float = 1.0
    shake_hz: float = 2.0
    shake_translation: float = 0.03  # m
    shake_rotation: float = 0.5  # rad
    max_drift: float = 0.05  # m, TCP point of the object may move this far from the TCP
    min_finger_q: float = 0.0005  # m per finger; below this the fingers count as fully closed
    # Virtual-joint drives: stiff enough that the hand follows the shake closely.
    virtual_stiffness: float = 2e4
    virtual_damping: float = 2e3
    virtual_force_limit: float = 1e4


@dataclass(frozen=True)
class TrialResult:
    success: np.ndarray  # (N,) bool
    width: np.ndarray  # (N,) finger gap after closing, m (both finger joints summed)


def _configure_physx() -> None:
    # The scene settings of ManiSkill's default SimConfig, so contacts behave as in the env.
    sapien.physx.set_shape_config(contact_offset=CONTACT_OFFSET, rest_offset=0.0)
    sapien.physx.set_body_config(solver_position_iterations=15, solver_velocity_iterations=1, sleep_threshold=0.005)
    sapien.physx.set_scene_config(
        gravity=[0, 0, -9.81], bounce_threshold=2.0, enable_pcm=True, enable_tgs=True, enable_ccd=False,
        enable_enhanced_determinism=True, enable_friction_every_iteration=True, cpu_workers=0,
    )
    sapien.physx.set_default_material(0.3, 0.3, 0.0)


class GraspLabeller:
    """Many grasp trials in one SAPIEN scene; reuse one per process."""

    def __init__(
        self, slots: int = 16, config: TrialConfig = TrialConfig(), object_friction: float = OBJECT_FRICTION, spacing: float = 2.0
    ):
        _configure_physx()
        self.config = config
        self.scene = sapien.Scene([sapien.physx.PhysxCpuSystem()])
        self.scene.set_timestep(1.0 / SIM_FREQ)
        side = int(np.ceil(np.sqrt(slots)))
        self.slot_origins = np.array([[spacing * (i % side), spacing * (i // side), 1.0] for i in range(slots)])
        self._load_grippers(slots, config)
        self.objects: list = []
        self._object_id = None
        self.object_material = sapien.physx.PhysxMaterial(object_friction, object_friction, 0.0)

    # The floating hand: its pad links, driven finger joints and hand link, its URDF and the
    # set-up of its finger joints (the Franka hand's here; grasp_labels.robotiq.RobotiqLabeller's
    # Robotiq overrides them).
    PAD_LINKS = franka.FINGER_LINKS
    DRIVEN_FINGER_JOINTS = franka.FINGER_JOINTS
    HAND_LINK = "panda_hand"

    def _hand_urdf(self) -> str:
        return franka.physics_urdf_path()

    def _set_up_fingers(self, joints: dict) -> None:
        """Drives of one floating hand's finger joints, by joint name."""
        for name in franka.FINGER_JOINTS:
            joints[name].set_drive_properties(franka.GRIPPER_STIFFNESS, franka.GRIPPER_DAMPING, franka.GRIPPER_FORCE_LIMIT)

    def _load_grippers(self, slots: int, config: TrialConfig) -> None:
        """One floating hand per slot, moved by its virtual joints."""
        loader = self.scene.create_urdf_loader()
        loader.fix_root_link = True
        for link in self.PAD_LINKS:
            loader.set_link_material(link, franka.FINGER_FRICTION, franka.FINGER_FRICTION, 0.0)
            loader.set_link_patch_radius(link, franka.FINGER_PATCH_RADIUS)
            loader.set_link_min_patch_radius(link, franka.FINGER_PATCH_RADIUS)
        urdf = self._hand_urdf()
        self.grippers = []
        for origin in self.slot_origins:
            gripper = loader.load(urdf)
            gripper.set_root_pose(sapien.Pose(p=origin))
            for link in gripper.links:
                link.disable_gravity = True
            joints = {j.name: j for j in gripper.active_joints}
            for name in franka.VIRTUAL_JOINTS:
                joints[name].set_drive_properties(config.virtual_stiffness, config.virtual_damping, config.virtual_force_limit)
                joints[name].set_friction(0.0)
            self._set_up_fingers(joints)
            self.grippers.append(gripper)
        names = [j.name for j in self.grippers[0].active_joints]
        self._virtual_idx = [names.index(n) for n in franka.VIRTUAL_JOINTS]
        self._finger_idx = [names.index(n) for n in self.DRIVEN_FINGER_JOINTS]
        self._joints = [[g.active_joints[i] for i in range(len(names))] for g in self.grippers]
        self._hand_links = [next(link for link in g.links if link.name == self.HAND_LINK) for g in self.grippers]
        # Contacts name their bodies by component; per-scene entity ids identify them.
        self._finger_owner = {
            link.entity.per_scene_id: i for i, g in enumerate(self.grippers) for link in g.links if link.name in self.PAD_LINKS
        }

    # The hand's gripper, in four hooks (the Franka hand's here).
    def _open_gripper(self, i: int, qpos: np.ndarray) -> None:
        """Set slot ``i``'s fingers open in ``qpos`` and their drive targets open."""
        qpos[self._finger_idx] = franka.FINGER_TRAVEL

    def _open_targets(self, i: int) -> None:
        for k in self._finger_idx:
            self._joints[i][k].set_drive_target(franka.FINGER_TRAVEL)

    def _close(self, i: int) -> None:
        for k in self._finger_idx:
            self._joints[i][k].set_drive_target(franka.GRIPPER_CLOSED_TARGET)

    def _width(self, qpos: np.ndarray) -> float:
        """Finger gap (m) from the gripper's joint positions."""
        return qpos[self._finger_idx].sum()

    def _open_enough(self, qpos: np.ndarray) -> bool:
        return bool(np.all(qpos[self._finger_idx] > self.config.min_finger_q))

    @property
    def slots(self) -> int:
        return len(self.grippers)

    def set_object(self, asset: ObjectAsset, density: float = DENSITY) -> None:
        """Put a copy of ``asset`` into every slot (replacing the previous object)."""
        for entity in self.objects:
            self.scene.remove_entity(entity)
        self.objects = []
        # Canonical parts: the same shapes, listed the same way however the catalog's hull
        # routine ordered them, so PhysX cooks identical meshes and labels reproduce.
        part_files = [mesh_file(canonical_part(part)) for part in asset.convex_parts]
        for i, origin in enumerate(self.slot_origins):
            builder = self.scene.create_actor_builder()
            for path in part_files:
                builder.add_convex_collision_from_file(path, material=self.object_material, density=density)
            builder.set_initial_pose(sapien.Pose(p=origin + [0, 0, 10.0]))
            entity = builder.build(name=f"object_{i}")
            self.objects.append(entity)
        self._object_id = asset.object_id

    def _reset_slot(self, i: int, T_object_hand: np.ndarray) -> None:
        gripper, entity = self.grippers[i], self.objects[i]
        T_world_hand = np.eye(4)
        T_world_hand[:3, :3] = T_object_hand[:3, :3]
        T_world_hand[:3, 3] = T_object_hand[:3, 3] + self.slot_origins[i]
        gripper.set_root_pose(sapien.Pose(T_world_hand))
        qpos = np.zeros(gripper.dof)
        self._open_gripper(i, qpos)
        gripper.set_qpos(qpos)
        gripper.set_qvel(np.zeros(gripper.dof))
        for joint in self._joints[i]:
            joint.set_drive_target(0.0)
            joint.set_drive_velocity_target(0.0)
        self._open_targets(i)
        body = entity.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
        entity.set_pose(sapien.Pose(p=self.slot_origins[i]))
        body.set_linear_velocity([0, 0, 0])
        body.set_angular_velocity([0, 0, 0])
        body.disable_gravity = True
        body.wake_up()

    def _shake_trajectory(self) -> tuple[np.ndarray, np.ndarray]:
        """The shake as virtual-joint targets: ``rotation_part`` (steps, 6) is the same for every
        slot (rotation about the TCP, in the gripper root = initial hand frame); the vertical
        sine is ``vertical`` (steps,) times each slot's world-up direction in its root frame."""
        c = self.config
        t = np.arange(1, int(round(c.shake_s * SIM_FREQ)) + 1) / SIM_FREQ
        s = np.sin(2 * np.pi * c.shake_hz * t)
        axis = np.where(t <= c.shake_s / 2, 0, 1)  # first about hand x, then about the closing y
        rotvec = np.zeros((len(t), 3))
        rotvec[np.arange(len(t)), axis] = c.shake_rotation * s
        tcp = np.array([0.0, 0.0, franka.TCP_OFFSET])
        rotation_part = np.zeros((len(t), 6))
        # Hand = Trans(xyz) * R (the virtual joints' order); xyz = tcp - R tcp keeps the TCP in place.
        rotation_part[:, :3] = tcp - Rotation.from_rotvec(rotvec).apply(tcp)
        rotation_part[:, 3:] = rotvec  # one axis at a time, so the joint angles are the rotvec
        return rotation_part, c.shake_translation * s

    def run_batch(self, T_object_hand: np.ndarray) -> TrialResult:
        """Test up to ``slots`` hand poses (N, 4, 4) on the current object."""
        n = len(T_object_hand)
        if n > self.slots:
            raise ValueError(f"batch of {n} poses exceeds the labeller's {self.slots} slots")
        if self._object_id is None:
            raise ValueError("set_object() first")
        c = self.config
        active = range(n)
        for i in active:
            self._reset_slot(i, T_object_hand[i])
        # Park unused slots' objects out of the way so they cost nothing.
        for i in range(n, self.slots):
            self.objects[i].set_pose(sapien.Pose(p=self.slot_origins[i] + [0, 0, 10.0]))
            self.objects[i].find_component_by_type(sapien.physx.PhysxRigidDynamicComponent).disable_gravity = True
        for i in active:
            self._close(i)
        for _ in range(int(round(c.close_s * SIM_FREQ))):
            self.scene.step()
        width = np.zeros(n)
        p_object_tcp = np.zeros((n, 3))
        for i in active:
            qpos = self.grippers[i].get_qpos()
            width[i] = self._width(qpos)
            T_world_object = self.objects[i].get_pose().to_transformation_matrix()
            p_world_tcp = self._tcp_world(i)
            p_object_tcp[i] = np.linalg.solve(T_world_object, np.append(p_world_tcp, 1.0))[:3]
            self.objects[i].find_component_by_type(sapien.physx.PhysxRigidDynamicComponent).disable_gravity = False
        # World up seen from each gripper root, for the vertical part of the shake.
        up_root = np.array([self.grippers[i].get_root_pose().to_transformation_matrix()[2, :3] for i in active])
        rotation_part, vertical = self._shake_trajectory()
        for step in range(len(vertical)):
            targets = np.tile(rotation_part[step], (n, 1))
            targets[:, :3] += vertical[step] * up_root
            for i in active:
                joints = self._joints[i]
                for k, joint_index in enumerate(self._virtual_idx):
                    joints[joint_index].set_drive_target(float(targets[i, k]))
            self.scene.step()
        touching = self._finger_contacts(n)
        success = np.zeros(n, dtype=bool)
        for i in active:
            qpos = self.grippers[i].get_qpos()
            open_enough = self._open_enough(qpos)
            T_world_object = self.objects[i].get_pose().to_transformation_matrix()
            drift = np.linalg.norm(T_world_object[:3, :3] @ p_object_tcp[i] + T_world_object[:3, 3] - self._tcp_world(i))
            success[i] = open_enough and touching[i] and drift < c.max_drift
        return TrialResult(success=success, width=width)

    def _tcp_world(self, i: int) -> np.ndarray:
        T_world_hand = self._hand_links[i].entity_pose.to_transformation_matrix()
        return T_world_hand[:3, 3] + franka.TCP_OFFSET * T_world_hand[:3, 2]

    def _finger_contacts(self, n: int) -> np.ndarray:
        """(n,) True where both fingers of slot i press on object i."""
        slot_of_object = {self.objects[i].per_scene_id: i for i in range(n)}
        touched = [set() for _ in range(n)]
        for contact in self.scene.get_contacts():
            a, b = (body.entity.per_scene_id for body in contact.bodies)
            for obj, finger in ((a, b), (b, a)):
                i = slot_of_object.get(obj)
                if i is not None and self._finger_owner.get(finger) == i:
                    if any(np.linalg.norm(point.impulse) > 0 for point in contact.points):
                        touched[i].add(finger)
        return np.array([len(t) == 2 for t in touched])

    def label(self, asset: ObjectAsset, T_object_hand: np.ndarray) -> TrialResult:
        """Label every pose in ``T_object_hand`` (N, 4, 4) on ``asset``, in batches of ``slots``."""
        if self._object_id != asset.object_id:
            self.set_object(asset)
        results = [self.run_batch(T_object_hand[s : s + self.slots]) for s in range(0, len(T_object_hand), self.slots)]
        if not results:
            return TrialResult(success=np.zeros(0, dtype=bool), width=np.zeros(0))
        return TrialResult(
            success=np.concatenate([r.success for r in results]), width=np.concatenate([r.width for r in results])
        )
