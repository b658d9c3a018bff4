"""Collision checking of arm configurations against a world, with an optional carried object."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from .robot import FINGER_OPEN, HAND_LINKS, WORLD_LINKS, PandaModel
from .world import CollisionWorld


@dataclass(frozen=True)
class Attachment:
    """A grasped object as spheres in the hand frame (``panda_hand``)."""

    centers_hand: np.ndarray  # (M, 3)
    radii: np.ndarray  # (M,)

    @classmethod
    def from_points(cls, points_hand: np.ndarray, n_spheres: int = 96, seed: int = 0) -> "Attachment":
        """Spheres on object points (surface samples or observed cloud), hand frame.

        Farthest-point picks ``n_spheres`` centres; each radius is the distance to the
        farthest point it is the nearest centre of, so every point is covered.
        """
        points = np.asarray(points_hand, dtype=float).reshape(-1, 3)
        if len(points) == 0:
            raise ValueError("cannot attach an object with no points")
        rng = np.random.default_rng(seed)
        chosen = [int(rng.integers(len(points)))]
        d = np.linalg.norm(points - points[chosen[0]], axis=1)
        for _ in range(min(n_spheres, len(points)) - 1):
            chosen.append(int(np.argmax(d)))
            d = np.minimum(d, np.linalg.norm(points - points[chosen[-1]], axis=1))
        centers = points[chosen]
        owner = np.argmin(np.linalg.norm(points[:, None] - centers[None], axis=2), axis=1)
        radii = np.array([np.linalg.norm(points[owner == i] - centers[i], axis=1).max(initial=0.0)
                          for i in range(len(centers))])
        return cls(centers, np.maximum(radii, 0.005))

    @classmethod
    def from_mesh(cls, mesh_hand: trimesh.Trimesh, n_samples: int = 2000, n_spheres: int = 96,
                  seed: int = 0) -> "Attachment":
        points, _ = trimesh.sample.sample_surface(mesh_hand, n_samples, seed=np.random.default_rng(seed))
        return cls.from_points(np.concatenate([points, mesh_hand.vertices]), n_spheres, seed)


class CollisionChecker:
    """``valid(q)``: joint limits, self-collision and world clearance for a batch of configs.

    ``exclude`` names world groups that are ignored (e.g. the target while approaching
    it). ``margin`` is extra clearance on top of the spheres' own fitting margin.
    """

    def __init__(self, robot: PandaModel, world: CollisionWorld, finger: float = FINGER_OPEN,
                 exclude: tuple[str, ...] = (), attachment: Attachment | None = None, margin: float = 0.0,
                 ignore_links: tuple[str, ...] = (), exact_self_collision: bool = True):
        self.robot, self.world, self.finger = robot, world, finger
        self.exclude, self.attachment, self.margin = tuple(exclude), attachment, margin
        world_links = tuple(l for l in WORLD_LINKS if l not in ignore_links)
        self.world_mask = torch.as_tensor(robot.sphere_mask(world_links))
        self.radii = torch.as_tensor(robot.spheres.radii)
        self.pairs = torch.as_tensor(robot.self_collision_pairs)
        self.n_checked = 0
        # Sphere self-collision is a broad phase: the inflated spheres of the wrist and
        # fingers overlap the forearm's in many valid poses (about a third of IK
        # solutions in a test scene, 1 in 10 of them real), so flagged link pairs are
        # decided on the exact meshes (python-fcl).
        self.exact_self = exact_self_collision
        self._exact = None
        self._pair_links = (torch.as_tensor(robot.spheres.link_index[robot.self_collision_pairs[:, 0]]),
                            torch.as_tensor(robot.spheres.link_index[robot.self_collision_pairs[:, 1]]))
        if attachment is not None:
            self.att_c = torch.as_tensor(attachment.centers_hand, dtype=torch.float64)
            self.att_r = torch.as_tensor(attachment.radii, dtype=torch.float64)
            # The carried object may touch the hand and fingers, not the rest of the arm.
            self.att_arm_mask = torch.as_tensor(robot.sphere_mask(("panda_link0", "panda_link1", "panda_link2",
                                                                   "panda_link3", "panda_link4")))

    def clearance(self, q) -> torch.Tensor:
        """Smallest signed clearance per config (B,): < 0 means collision (ignoring limits)."""
        q = torch.as_tensor(np.asarray(q), dtype=torch.float64).reshape(-1, 7)
        B = len(q)
        self.n_checked += B
        poses = self.robot.link_poses(q, self.finger)
        centers = self.robot.sphere_centers(q, poses=poses)  # (B, S, 3)
        horizon = float(self.radii.max()) + self.margin + 0.02
        c_world = centers[:, self.world_mask].reshape(-1, 3)
        r_world = self.radii[self.world_mask].repeat(B)
        d = self.world.distance(c_world, horizon, self.exclude) - r_world
        clear = d.reshape(B, -1).amin(dim=1)
        a, b = self.pairs[:, 0], self.pairs[:, 1]
        d_self = (centers[:, a] - centers[:, b]).norm(dim=2) - self.radii[a] - self.radii[b]
        self_clear = d_self.amin(dim=1)
        if self.exact_self:
            self_clear = self._exact_self_clearance(poses, d_self, self_clear)
        clear = torch.minimum(clear, self_clear)
        if self.attachment is not None:
            T = poses["panda_hand"]
            att = torch.einsum("bij,mj->bmi", T[:, :3, :3], self.att_c) + T[:, None, :3, 3]  # (B, M, 3)
            d_att = self.world.distance(att.reshape(-1, 3), float(self.att_r.max()) + 0.02, self.exclude)
            d_att = (d_att.reshape(B, -1) - self.att_r).amin(dim=1)
            arm = centers[:, self.att_arm_mask]
            d_arm = (torch.cdist(att, arm) - self.att_r[:, None] - self.radii[self.att_arm_mask][None]).amin(dim=(1, 2))
            clear = torch.minimum(clear, torch.minimum(d_att, d_arm))
        return clear

    def hand_clearance(self, T_base_hand) -> np.ndarray:
        """World clearance (N,) of the hand alone (hand, fingers and the rigidly attached
        link7) placed at each ``T_base_hand`` (N, 4, 4), without IK: a cheap filter for grasp
        candidates before the arm is solved for."""
        T_base_hand = torch.as_tensor(np.asarray(T_base_hand, float)).reshape(-1, 4, 4)
        links = ("panda_link7",) + HAND_LINKS
        poses = self.robot.link_poses(torch.zeros(1, 7, dtype=torch.float64), self.finger)
        T_hand_base = torch.linalg.inv(poses["panda_hand"][0])
        mask = torch.as_tensor(self.robot.sphere_mask(links)) & self.world_mask
        idx = torch.nonzero(mask, as_tuple=True)[0]
        link_of = self.robot.spheres.link_index[idx.numpy()]
        T_hand_link = torch.stack([T_hand_base @ poses[self.robot.spheres.links[l]][0] for l in link_of])  # (M,4,4)
        c_link = torch.as_tensor(self.robot.spheres.centers_link[idx.numpy()])
        c_hand = torch.einsum("mij,mj->mi", T_hand_link[:, :3, :3], c_link) + T_hand_link[:, :3, 3]
        c_base = torch.einsum("nij,mj->nmi", T_base_hand[:, :3, :3], c_hand) + T_base_hand[:, None, :3, 3]
        horizon = float(self.radii.max()) + self.margin + 0.02
        d = self.world.distance(c_base.reshape(-1, 3), horizon, self.exclude).reshape(len(T_base_hand), -1)
        return (d - self.radii[idx][None]).amin(dim=1).numpy()

    def _exact_self_clearance(self, poses, d_self, self_clear) -> torch.Tensor:
        """For configs whose spheres touch: -1 if a flagged link pair's meshes collide, else +inf."""
        flagged = torch.nonzero(self_clear < self.margin, as_tuple=True)[0]
        if len(flagged) == 0:
            return self_clear
        if self._exact is None:
            from .exact import ExactRobot

            self._exact = ExactRobot(self.robot, links=self.robot.spheres.links)
        links = self.robot.spheres.links
        out = self_clear.clone()
        for i in flagged.tolist():
            hit = d_self[i] < self.margin
            pairs = set(zip(self._pair_links[0][hit].tolist(), self._pair_links[1][hit].tolist()))
            for l in {links[k] for pair in pairs for k in pair}:
                self._exact.set_link_pose(l, poses[l][i].numpy())
            collides = any(self._exact.link_pair_collides(links[p], links[q]) for p, q in pairs)
            out[i] = -1.0 if collides else float("inf")
        return out

    def valid(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float).reshape(-1, 7)
        ok = self.robot.within_limits(q)
        if ok.any():
            ok[ok] = (self.clearance(q[ok]) > self.margin).numpy()
        return ok

    def motion_valid(self, q_from, q_to, resolution: float = 0.02) -> bool:
        """Straight joint-space segment checked at ``resolution`` rad (max joint step)."""
        q_from, q_to = np.asarray(q_from, float), np.asarray(q_to, float)
        n = max(2, int(np.ceil(np.abs(q_to - q_from).max() / resolution)) + 1)
        s = np.linspace(0.0, 1.0, n)[:, None]
        return bool(self.valid(q_from + s * (q_to - q_from)).all())
