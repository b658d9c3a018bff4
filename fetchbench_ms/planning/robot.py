"""A robot as the planner sees it: its URDF, batched forward kinematics
(pytorch_kinematics) and a conservative collision-sphere model with the
self-collision pairs that matter. The Panda (ManiSkill's URDF, ``panda()``) and the
other setups of ``fetchbench_ms.robots`` (their generated URDFs, ``robot_model(uid)``).

Everything is in the robot base frame (``panda_link0`` on the Panda). Joint vectors
``q`` are the 7 arm joints; the gripper's joints are given separately as a finger
opening per finger (0..0.04 m on the Franka hand), because the planner never moves
them: the model turns an opening into the gripper's joint values (the Robotiq's six
coupled joints follow one knuckle angle, looked up from its kinematics).
"""
from __future__ import annotations

import contextlib
import io
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.spatial.transform import Rotation

from ..utils.mesh_cache import cache_dir
from ..robots import SETUPS, RobotSetup, robot_setup
from .spheres import DEFAULT_MARGIN, FIT_VERSION, load_or_fit

ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
# Links whose spheres are checked against the world. panda_link0 stands on the robot
# table, so it only takes part in self-collision.
WORLD_LINKS = ("panda_link1", "panda_link2", "panda_link3", "panda_link4", "panda_link5", "panda_link6",
               "panda_link7", "panda_hand", "panda_leftfinger", "panda_rightfinger")
HAND_LINKS = ("panda_hand", "panda_leftfinger", "panda_rightfinger")
# Franka's published joint acceleration limits (rad/s^2); the URDF carries only velocities.
ACCELERATION_LIMITS = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
# FetchBench's default configuration (arm), fingers open at 0.04.
Q_DEFAULT = np.array([-0.3127, -1.1997, 0.0578, -2.1768, 0.0649, 0.9786, 0.5300])
FINGER_OPEN = 0.04
TCP_OFFSET = 0.1034  # panda_hand -> panda_hand_tcp along hand z


def panda_urdf_path() -> str:
    # find_spec, not import: importing mani_skill registers every env (~2 s).
    import importlib.util

    root = importlib.util.find_spec("mani_skill").submodule_search_locations[0]
    return os.path.join(root, "assets", "robots", "panda", "panda_v2.urdf")


def _origin_matrix(element) -> np.ndarray:
    T = np.eye(4)
    origin = element.find("origin") if element is not None else None
    if origin is not None:
        T[:3, 3] = [float(v) for v in origin.get("xyz", "0 0 0").split()]
        T[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in origin.get("rpy", "0 0 0").split()]).as_matrix()
    return T


def link_collision_meshes(urdf_path: str, convex_links=()) -> dict[str, trimesh.Trimesh]:
    """Each link's collision geometry (meshes and boxes of the URDF) as one mesh in the link
    frame; the meshes of ``convex_links`` as their convex hulls, the shape SAPIEN simulates
    for a mesh of a moving link (a few hundred faces where the Gen3's scans have ten thousand)."""
    root = ET.parse(urdf_path).getroot()
    base = os.path.dirname(urdf_path)
    meshes = {}
    for link in root.findall("link"):
        pieces = []
        for col in link.findall("collision"):
            geom = col.find("geometry")
            T = _origin_matrix(col)
            if geom.find("mesh") is not None:
                mesh = geom.find("mesh")
                piece = trimesh.load(os.path.join(base, mesh.get("filename")), force="mesh")
                if mesh.get("scale") is not None:
                    piece.apply_scale([float(v) for v in mesh.get("scale").split()])
                if link.get("name") in convex_links:
                    piece = piece.convex_hull
            elif geom.find("box") is not None:
                piece = trimesh.creation.box([float(v) for v in geom.find("box").get("size").split()])
            else:
                raise ValueError(f"unsupported collision geometry in link {link.get('name')}")
            pieces.append(piece.apply_transform(T))
        if pieces:
            meshes[link.get("name")] = trimesh.util.concatenate(pieces)
    return meshes


def hull_links(setup: RobotSetup) -> tuple[str, ...]:
    """Links whose collision meshes the planner takes as convex hulls: none on the Panda,
    and none of the Franka hand on any arm (its meshes as on the Panda, so the hand is the
    same hand everywhere); the Gen3's and the Robotiq's meshes are detailed scans, which
    the simulation turns into their hulls."""
    if setup.uid == "panda":
        return ()
    franka = set(SETUPS["panda"].world_links) | {SETUPS["panda"].base_link}
    return tuple(l for l in (setup.base_link,) + setup.world_links if l not in franka)


def joint_velocity_limits(urdf_path: str, joints: tuple[str, ...] = ARM_JOINTS) -> np.ndarray:
    root = ET.parse(urdf_path).getroot()
    by_name = {j.get("name"): j for j in root.findall("joint")}
    return np.array([float(by_name[n].find("limit").get("velocity")) for n in joints])


@dataclass(frozen=True)
class _Joint:
    name: str
    kind: str  # revolute | prismatic | fixed
    parent: str
    child: str
    T_parent_joint: np.ndarray
    axis: np.ndarray
    q_index: int  # index into the 9-vector (7 arm + 2 fingers), -1 for fixed


class UrdfTreeFK:
    """Batched forward kinematics of the URDF's kinematic tree in torch.

    Why not pytorch_kinematics' forward_kinematics for the planner's inner loop: at the
    batch sizes of collision checking (1-50 configurations) its general code costs
    ~3 ms per call in Python overhead; this fixed-order product of joint transforms costs
    a fraction of that. pytorch_kinematics stays the Jacobian source for IK and the
    reference the tests compare against.
    """

    def __init__(self, urdf_path: str, joint_names: tuple[str, ...]):
        root = ET.parse(urdf_path).getroot()
        joints = []
        for j in root.findall("joint"):
            axis = j.find("axis")
            joints.append(_Joint(
                name=j.get("name"), kind=j.get("type"), parent=j.find("parent").get("link"),
                child=j.find("child").get("link"), T_parent_joint=_origin_matrix(j),
                axis=np.array([float(v) for v in (axis.get("xyz") if axis is not None else "0 0 1").split()]),
                q_index=joint_names.index(j.get("name")) if j.get("name") in joint_names else -1))
        children = {j.parent for j in joints}
        self.root_link = next(iter(children - {j.child for j in joints}))
        order, known = [], {self.root_link}
        while len(order) < len(joints):  # parents before children
            for j in joints:
                if j not in order and j.parent in known:
                    order.append(j)
                    known.add(j.child)
        self.joints = order
        self.links = (self.root_link,) + tuple(j.child for j in order)
        self._T = [torch.as_tensor(j.T_parent_joint) for j in order]
        moving = [j for j in order if j.kind != "fixed"]
        self._slot = {j.name: i for i, j in enumerate(moving)}
        self._q_index = torch.as_tensor([j.q_index for j in moving])
        axes = torch.as_tensor(np.stack([j.axis for j in moving]))  # (M, 3)
        self._prismatic = torch.as_tensor([j.kind == "prismatic" for j in moving])
        self._axes = axes
        x, y, z = axes.T
        zero = torch.zeros_like(x)
        self._K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], 1).reshape(-1, 3, 3)  # cross matrices
        # The transforms' bottom row, made once: a tensor built from a list in ``forward`` is a
        # host-to-device copy, which a CUDA graph cannot capture.
        self._bottom = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
        self.joint_child = {j.name: j.child for j in order}

    def joint_axis(self, names: tuple[str, ...]) -> torch.Tensor:
        """(J, 3) joint axes in their child-link frames (the frame the motion is applied in)."""
        return self._axes[[self._slot[n] for n in names]]

    def to(self, device=None, dtype=torch.float64) -> "UrdfTreeFK":
        """A copy whose constants (and so whose forward) live on ``device`` in ``dtype``."""
        import copy

        out = copy.copy(self)
        out._T = [T.to(device, dtype) for T in self._T]
        out._q_index = self._q_index.to(device)
        out._axes, out._K = self._axes.to(device, dtype), self._K.to(device, dtype)
        out._prismatic = self._prismatic.to(device)
        out._bottom = self._bottom.to(device, dtype)
        return out

    def forward(self, q_full: torch.Tensor) -> dict[str, torch.Tensor]:
        B = q_full.shape[0]
        dd = dict(dtype=self._K.dtype, device=self._K.device)
        v = q_full[:, self._q_index]  # (B, M)
        # All joint motions at once: Rodrigues for revolute, translation for prismatic.
        s, c = torch.sin(v)[..., None, None], torch.cos(v)[..., None, None]
        eye3 = torch.eye(3, **dd)
        R = eye3 + s * self._K + (1 - c) * (self._K @ self._K)
        R = torch.where(self._prismatic[None, :, None, None], eye3, R)
        t = torch.where(self._prismatic[None, :, None], v[..., None] * self._axes, torch.zeros((), **dd))
        bottom = self._bottom.to(**dd).expand(B, len(self._axes), 1, 4)
        motion = torch.cat([torch.cat([R, t[..., None]], dim=3), bottom], dim=2)
        poses = {self.root_link: torch.eye(4, **dd).expand(B, 4, 4)}
        for j, T_origin in zip(self.joints, self._T):
            T = poses[j.parent] @ T_origin
            if j.name in self._slot:
                T = T @ motion[:, self._slot[j.name]]
            poses[j.child] = T
        return poses


def disabled_collision_pairs(srdf_path: str) -> set[frozenset[str]]:
    root = ET.parse(srdf_path).getroot()
    return {frozenset((d.get("link1"), d.get("link2"))) for d in root.findall("disable_collisions")}


@dataclass(frozen=True)
class SphereModel:
    """All spheres of the robot, flattened: sphere i belongs to ``links[link_index[i]]``."""

    links: tuple[str, ...]
    link_index: np.ndarray  # (S,)
    centers_link: np.ndarray  # (S, 3) in each sphere's link frame
    radii: np.ndarray  # (S,)
    margin: float
    version: str


class RobotModel:
    """Batched FK and collision spheres of a robot setup (float64, CPU torch); the
    Panda's by default (ManiSkill's URDF and SRDF)."""

    def __init__(self, margin: float = DEFAULT_MARGIN, seed: int = 0, setup: RobotSetup | str = "panda"):
        import pytorch_kinematics as pk

        self.setup = setup = robot_setup(setup) if isinstance(setup, str) else setup
        self.uid = setup.uid
        self.arm_joints, self.gripper_joints = setup.arm_joints, setup.gripper_joints
        self.n_arm = setup.n_arm
        self.hand_link, self.tcp_link = setup.hand_link, setup.tcp_link
        self.world_links, self.hand_links = setup.world_links, setup.hand_links
        self.finger_links, self.proximal_links = setup.finger_links, setup.proximal_links
        self.wrist_link = setup.wrist_link
        self.finger_open = setup.finger_open
        self.q_home = np.asarray(setup.q_home, dtype=float)
        if setup.uid == "panda":
            self.urdf_path = panda_urdf_path()
        else:
            from ..robots.assets import urdf_path

            self.urdf_path = urdf_path(setup.uid)
        with open(self.urdf_path, "rb") as f:
            urdf = f.read()
        # The URDF parser prints a warning per unknown dynamics attribute; they are noise here.
        with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
            self.chain = pk.build_chain_from_urdf(urdf).to(dtype=torch.float64)
            self.arm_chain = pk.build_serial_chain_from_urdf(urdf, self.tcp_link).to(dtype=torch.float64)
        names = self.chain.get_joint_parameter_names()
        if sorted(names) != sorted(self.arm_joints + self.gripper_joints) \
                or tuple(names[: self.n_arm]) != self.arm_joints:
            raise ValueError(f"unexpected {self.uid} joint order {names}")
        self.fk = UrdfTreeFK(self.urdf_path, self.arm_joints + self.gripper_joints)
        low, high = self.chain.get_joint_limits()
        self.q_min = np.asarray(low[: self.n_arm], dtype=float)
        self.q_max = np.asarray(high[: self.n_arm], dtype=float)
        self.velocity_limits = joint_velocity_limits(self.urdf_path, self.arm_joints)
        self.acceleration_limits = np.asarray(setup.acceleration_limits, dtype=float)
        self.collision_meshes = link_collision_meshes(self.urdf_path, hull_links(setup))
        self._init_gripper()
        self.spheres = self._fit(margin, seed)
        if setup.uid == "panda":
            self.self_collision_pairs = self._self_pairs(self.urdf_path.replace(".urdf", ".srdf"))
        else:
            self.self_collision_pairs = self._self_pairs_generated(seed)

    # -- gripper ------------------------------------------------------------------------
    def _init_gripper(self) -> None:
        """How a finger opening (m per finger) sets the gripper's joints: the Franka hand's
        two prismatic joints take it as it is; a revolute linkage (the Robotiq) is coupled
        to its driving joint as its URDF's mimic tags say, and the driving angle for an
        opening is read off a table of its own kinematics (the pads' distance from the
        grasp plane, less half a pad, over the joint's range)."""
        self._coupling = None
        if self.setup.hand == "franka_hand":
            return
        from ..robots.assets import robotiq_mimic

        mimic = robotiq_mimic()
        driver = self.gripper_joints[0]
        self._coupling = torch.as_tensor([1.0 if j == driver else mimic[j][1] for j in self.gripper_joints],
                                         dtype=torch.float64)
        root = ET.parse(self.urdf_path).getroot()
        limit = next(j for j in root.findall("joint") if j.get("name") == driver).find("limit")
        angles = torch.linspace(float(limit.get("lower")), float(limit.get("upper")), 161, dtype=torch.float64)
        q = torch.cat([torch.as_tensor(self.q_home).expand(len(angles), self.n_arm),
                       angles[:, None] * self._coupling], dim=1)
        poses = self.fk.forward(q)
        pad = self.finger_links[1]
        T_hand_pad = torch.linalg.inv(poses[self.hand_link]) @ poses[pad]
        half_pad = float(self.collision_meshes[pad].extents[1]) / 2
        opening = T_hand_pad[:, :3, 3].abs()[:, 1] - half_pad
        if not bool((opening[1:] < opening[:-1]).all()):
            raise ValueError(f"{self.uid}: finger opening is not monotonic in {driver}")
        # Increasing openings for interpolation.
        self._open_table = opening.flip(0)
        self._angle_table = angles.flip(0)

    def gripper_q(self, finger) -> torch.Tensor:
        """Gripper joint values (N, G) for per-finger openings ``finger`` (scalar or (N,) / (N, 1))."""
        f = torch.as_tensor(finger, dtype=torch.float64).reshape(-1, 1)
        if self._coupling is None:
            return f.expand(len(f), len(self.gripper_joints))
        table_f, table_a = self._open_table.to(f), self._angle_table.to(f)
        x = f[:, 0].clamp(float(table_f[0]), float(table_f[-1]))
        i = torch.searchsorted(table_f, x.contiguous()).clamp(1, len(table_f) - 1)
        w = (x - table_f[i - 1]) / (table_f[i] - table_f[i - 1])
        angle = table_a[i - 1] + w * (table_a[i] - table_a[i - 1])
        return angle[:, None] * self._coupling.to(f)

    def finger_from_gripper_q(self, gripper_q) -> float:
        """Per-finger opening (m) of the gripper joint values (in ``gripper_joints`` order)."""
        gripper_q = np.asarray(gripper_q, dtype=float).reshape(-1)
        if self._coupling is None:
            return float(gripper_q[0])
        return float(np.interp(gripper_q[0], self._angle_table.flip(0).numpy(), self._open_table.flip(0).numpy()))

    def full_q(self, q, finger) -> torch.Tensor:
        """(B, n_arm + G) joint vectors of the FK from arm configurations and finger openings
        (one, or one per configuration)."""
        q = torch.as_tensor(q).reshape(-1, self.n_arm)
        g = self.gripper_q(torch.as_tensor(finger, dtype=torch.float64)).to(q)
        return torch.cat([q, g.expand(q.shape[0], g.shape[1])], dim=1)

    # -- spheres ------------------------------------------------------------------------
    def _fit(self, margin: float, seed: int) -> SphereModel:
        links = tuple(sorted(self.collision_meshes))
        name = "panda" if self.uid == "panda" else self.uid
        fitted = load_or_fit(self.collision_meshes, self._input_bytes(), cache_dir(), margin, seed,
                             link_fit=self.setup.link_fit, name=name)
        return SphereModel(
            links=links,
            link_index=np.concatenate([np.full(len(s.radii), i) for i, s in enumerate(fitted)]),
            centers_link=np.concatenate([s.centers_link for s in fitted]),
            radii=np.concatenate([s.radii for s in fitted]),
            margin=margin,
            version=FIT_VERSION,
        )

    def _input_bytes(self) -> bytes:
        """URDF + collision mesh bytes: what the fitted spheres depend on."""
        root = ET.parse(self.urdf_path).getroot()
        if self.uid == "panda":
            files = sorted({m.get("filename") for m in root.iter("mesh") if "collision" in m.get("filename")})
        else:
            files = sorted({m.get("filename") for c in root.iter("collision") for m in c.iter("mesh")})
        base = os.path.dirname(self.urdf_path)
        data = [Path(self.urdf_path).read_bytes()] + [Path(base, f).read_bytes() for f in files]
        if self.uid != "panda":  # meshes read with their URDF scale (the Panda's have none), as hulls
            data.insert(0, b"mesh-scale|convex-hull:" + ",".join(hull_links(self.setup)).encode())
        return b"|".join(data)

    def _self_pairs(self, srdf_path: str) -> np.ndarray:
        """Sphere index pairs (P, 2) of link pairs that can touch (the SRDF's complement)."""
        disabled = disabled_collision_pairs(srdf_path)
        links = self.spheres.links
        pairs = []
        for a in range(len(links)):
            for b in range(a + 1, len(links)):
                if frozenset((links[a], links[b])) in disabled:
                    continue
                ia = np.flatnonzero(self.spheres.link_index == a)
                ib = np.flatnonzero(self.spheres.link_index == b)
                pairs.append(np.stack(np.meshgrid(ia, ib, indexing="ij"), -1).reshape(-1, 2))
        return np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=int)

    def _self_pairs_generated(self, seed: int, samples: int = 256) -> np.ndarray:
        """Sphere index pairs (P, 2) of link pairs that can touch, for a URDF without an
        SRDF, by MoveIt's setup-assistant rules: skip links adjacent in the tree or one
        link apart (counting links with geometry only), pairs within the hand (they move
        together or by the linkage) and pairs whose spheres overlap in every one of
        ``samples`` random configurations (always touching: spheres are conservative)."""
        root = ET.parse(self.urdf_path).getroot()
        parent = {j.find("child").get("link"): j.find("parent").get("link") for j in root.findall("joint")}
        links = self.spheres.links

        def geometric_ancestors(link):
            out, cur = [], parent.get(link)
            while cur is not None:
                if cur in self.collision_meshes:
                    out.append(cur)
                cur = parent.get(cur)
            return out

        near = set()
        for l in links:
            up = geometric_ancestors(l)
            for k, a in enumerate(up[:2]):
                near.add(frozenset((l, a)))
        hand = set(self.hand_links) | {self.wrist_link}
        rng = np.random.default_rng(seed)
        q = rng.uniform(self.q_min, self.q_max, size=(samples, self.n_arm))
        centers = self.sphere_centers(q, self.finger_open)
        always = set()
        for a in range(len(links)):
            for b in range(a + 1, len(links)):
                ia = np.flatnonzero(self.spheres.link_index == a)
                ib = np.flatnonzero(self.spheres.link_index == b)
                d = (torch.cdist(centers[:, ia], centers[:, ib]) - torch.as_tensor(self.spheres.radii[ia])[:, None]
                     - torch.as_tensor(self.spheres.radii[ib])[None]).amin(dim=(1, 2))
                if bool((d < 0).all()):
                    always.add(frozenset((links[a], links[b])))
        pairs = []
        for a in range(len(links)):
            for b in range(a + 1, len(links)):
                key = frozenset((links[a], links[b]))
                if key in near or key in always or (links[a] in hand and links[b] in hand):
                    continue
                ia = np.flatnonzero(self.spheres.link_index == a)
                ib = np.flatnonzero(self.spheres.link_index == b)
                pairs.append(np.stack(np.meshgrid(ia, ib, indexing="ij"), -1).reshape(-1, 2))
        return np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=int)

    def sphere_mask(self, links: tuple[str, ...]) -> np.ndarray:
        idx = [self.spheres.links.index(l) for l in links]
        return np.isin(self.spheres.link_index, idx)

    # -- kinematics ---------------------------------------------------------------------
    def _full_q(self, q: torch.Tensor, finger: float | torch.Tensor) -> torch.Tensor:
        q = torch.as_tensor(q, dtype=torch.float64).reshape(-1, self.n_arm)
        if self._coupling is None:
            f = torch.as_tensor(finger, dtype=torch.float64).reshape(-1, 1).expand(q.shape[0], 1)
            return torch.cat([q, f, f], dim=1)
        return self.full_q(q, finger)

    def link_poses(self, q, finger=FINGER_OPEN) -> dict[str, torch.Tensor]:
        """T_base_link for every link, each (B, 4, 4)."""
        return self.fk.forward(self._full_q(q, finger))

    def sphere_centers(self, q, finger=FINGER_OPEN, poses: dict | None = None) -> torch.Tensor:
        """Sphere centres in the base frame, (B, S, 3)."""
        poses = poses if poses is not None else self.link_poses(q, finger)
        T = torch.stack([poses[l] for l in self.spheres.links], dim=1)  # (B, L, 4, 4)
        T_s = T[:, torch.as_tensor(self.spheres.link_index)]  # (B, S, 4, 4)
        c = torch.as_tensor(self.spheres.centers_link)
        return torch.einsum("bsij,sj->bsi", T_s[..., :3, :3], c) + T_s[..., :3, 3]

    def tcp_pose(self, q) -> torch.Tensor:
        """T_base_tcp (B, 4, 4): the point between the finger pads (ManiSkill's panda_hand_tcp)."""
        q = torch.as_tensor(q, dtype=torch.float64).reshape(-1, self.n_arm)
        return self.arm_chain.forward_kinematics(q).get_matrix()

    def tcp_jacobian(self, q, poses: dict | None = None) -> torch.Tensor:
        """Geometric Jacobian of the TCP in the base frame, (B, 6, 7): linear rows first.

        Built from the FK's joint frames (axis z_i and origin p_i of each arm joint:
        J_i = [z_i x (p_tcp - p_i); z_i]); pytorch_kinematics' ``jacobian`` gives the same
        (a test checks) but recomputes its own FK at several times the cost.
        """
        poses = poses if poses is not None else self.link_poses(q)
        frames = torch.stack([poses[self.fk.joint_child[j]] for j in self.arm_joints], dim=1)  # (B, 7, 4, 4)
        axes = torch.einsum("bjik,jk->bji", frames[..., :3, :3], self.fk.joint_axis(self.arm_joints))
        p_tcp = poses[self.tcp_link][:, None, :3, 3]
        linear = torch.cross(axes, p_tcp - frames[..., :3, 3], dim=2)
        return torch.cat([linear, axes], dim=2).transpose(1, 2)

    def within_limits(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        q = np.asarray(q).reshape(-1, self.n_arm)
        return np.all((q >= self.q_min - tol) & (q <= self.q_max + tol), axis=1)


#: The Panda's model class under its old name (``RobotModel()`` is the Panda).
PandaModel = RobotModel


@lru_cache(maxsize=4)
def panda(margin: float = DEFAULT_MARGIN, seed: int = 0) -> RobotModel:
    """The shared Panda model (fitting spheres once per process)."""
    return RobotModel(margin, seed)


def robot_for_env(env) -> RobotModel:
    """The model of the robot a FetchBench env runs (``robot_uids``)."""
    setup = getattr(env.unwrapped, "robot_setup", None)
    return robot_model(None if setup is None else setup.uid)


@lru_cache(maxsize=8)
def robot_model(uid: str | None = None, margin: float = DEFAULT_MARGIN, seed: int = 0) -> RobotModel:
    """The shared model of a robot setup (``fetchbench_ms.robots``; None: the Panda)."""
    uid = robot_setup(uid).uid
    return panda(margin, seed) if uid == "panda" else RobotModel(margin, seed, setup=uid)
