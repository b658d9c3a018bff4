"""``obs_mode="composed_pointcloud"``: the policies' points composed each step from one render.

Rendering the cameras is nearly all of a point-cloud observation's cost, and between two
steps of a fetch little of what they see changes: the furniture and the other objects stand
still, the target moves rigidly (once grasped, with the hand), and the robot moves by its
joints. So this mode renders the task's two cameras once, when an episode starts, and
composes every observation from that render without rendering again:

- **scene** (1,024 points): furniture and the other objects as the cameras saw them at the
  episode's start, fixed for the episode;
- **target** (512 points): the target's points seen at the start, held in the target's own
  frame and placed by its current pose;
- **robot** (256 points): points sampled once per robot link on its visual meshes, placed by
  the links' current poses (the simulator's forward kinematics).

The blocks, sizes, labels, frame (robot base) and dtypes are ``policy_pointcloud``'s
(``pointcloud.POLICY_CLOUD_SIZES``), so a policy reads either; the points differ: this mode
does not see what the arm occludes or uncovers as it moves, objects the arm pushes stay where
they were, the target keeps the side it showed at the start, and the robot's points cover all
of its surface, seen or not. Within an episode the scene and target draws are seeded by the
episode seed (``compact_seed(seed, 0)``), so an observation is a function of the episode's
first state and the current one: a converter that resets to a recorded episode and sets its
recorded states gets the env's own observations.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .pointcloud import LABEL_NONE, LABEL_ROBOT, POLICY_CLOUD_SIZES, policy_cloud

#: The seed of the robot's point draw: one set of link points for every episode and machine.
ROBOT_POINTS_SEED = 0
#: Surface samples per robot point that the farthest-point draw of the robot's points starts from.
ROBOT_CANDIDATES_PER_POINT = 16


@dataclass
class RobotPoints:
    """Points fixed on the robot's links: ``link_index`` [N] (index into the articulation's
    links) and ``points_link`` [N, 3] (each point in its link's frame)."""

    link_index: torch.Tensor
    points_link: torch.Tensor


def robot_link_points(link_meshes: list, n: int, seed: int = ROBOT_POINTS_SEED) -> RobotPoints:
    """``n`` points spread over the robot's surface, each fixed to its link.

    ``link_meshes``: one trimesh (or None for a link without visual geometry) per link, in the
    link's frame. The surface is sampled by area (``ROBOT_CANDIDATES_PER_POINT`` x n samples,
    trimesh's seeded draw) with every link posed at the identity, and ``n`` of the samples are
    kept by farthest-point sampling *per link*, in proportion to each link's share of the
    samples (largest remainders), so that two links that overlap at the identity pose do not
    take each other's points."""
    import trimesh

    from ..geometry.pointops import farthest_point_sample

    areas = np.array([0.0 if m is None else float(m.area) for m in link_meshes])
    if areas.sum() <= 0:
        raise ValueError("the robot's links have no visual geometry to place points on")
    share = areas / areas.sum() * n
    counts = np.floor(share).astype(int)
    for i in np.argsort(-(share - counts), kind="stable")[: n - counts.sum()]:
        counts[i] += 1
    rng = np.random.default_rng(seed)
    index, points = [], []
    for link, (mesh, count) in enumerate(zip(link_meshes, counts)):
        if count == 0:
            continue
        samples, _ = trimesh.sample.sample_surface(mesh, ROBOT_CANDIDATES_PER_POINT * int(count), seed=rng)
        samples = torch.as_tensor(np.asarray(samples), dtype=torch.float32)
        pick = farthest_point_sample(samples[None], int(count))[0]
        points.append(samples[pick])
        index.append(torch.full((int(count),), link, dtype=torch.int64))
    return RobotPoints(torch.cat(index), torch.cat(points))


def _transform(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Points [..., N, 3] through the transforms T [..., 4, 4] (row vectors)."""
    return points @ T[..., :3, :3].transpose(-1, -2) + T[..., None, :3, 3]


class ComposedCloud:
    """The per-episode part of the composed clouds of a batch of sub-scenes, and the step's cloud.

    ``start`` takes the cameras' points of the sub-scenes whose episode starts (base frame,
    ``LABEL_*`` labels, as ``pointcloud.camera_points_base`` makes them) with the target's
    pose; ``compose`` places the kept points by the current poses of the target and the links."""

    def __init__(self, num_envs: int, robot: RobotPoints, device, sizes: dict | None = None):
        self.sizes = dict(POLICY_CLOUD_SIZES if sizes is None else sizes)
        n_scene, n_target = self.sizes["scene"], self.sizes["target"]
        if len(robot.link_index) != self.sizes["robot"]:
            raise ValueError(f"{len(robot.link_index)} robot points, the cloud keeps {self.sizes['robot']}")
        self.device = device
        self.robot = RobotPoints(robot.link_index.to(device), robot.points_link.to(device))
        self.scene_points = torch.zeros((num_envs, n_scene, 3), device=device)
        self.scene_labels = torch.zeros((num_envs, n_scene), dtype=torch.uint8, device=device)
        self.target_points = torch.zeros((num_envs, n_target, 3), device=device)  # in the target's frame
        self.target_labels = torch.zeros((num_envs, n_target), dtype=torch.uint8, device=device)
        #: Sub-scenes whose episode started since their points were taken (``start`` clears them).
        self.stale = torch.ones(num_envs, dtype=torch.bool, device=device)

    def start(self, env_idx: torch.Tensor, points_base: torch.Tensor, labels: torch.Tensor, seeds: torch.Tensor,
              T_base_target: torch.Tensor) -> None:
        """Keep the scene and target points of sub-scenes ``env_idx`` from their cameras' points
        ``points_base`` [K, P, 3] and ``labels`` [K, P] (rows of ``env_idx``), drawn as
        ``policy_pointcloud`` draws them (``seeds`` [K]); ``T_base_target`` [K, 4, 4]."""
        sizes = {"scene": self.sizes["scene"], "target": self.sizes["target"]}
        points, point_label = policy_cloud(points_base, labels, seeds, sizes)
        points, point_label = points.float().to(self.device), point_label.to(self.device)
        n_scene = sizes["scene"]
        self.scene_points[env_idx] = points[:, :n_scene]
        self.scene_labels[env_idx] = point_label[:, :n_scene]
        T_target_base = torch.linalg.inv(T_base_target.to(self.device))
        self.target_points[env_idx] = _transform(T_target_base, points[:, n_scene:])
        self.target_labels[env_idx] = point_label[:, n_scene:]
        self.stale[env_idx] = False

    def compose(self, T_base_target: torch.Tensor, T_base_links: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(points [B, N, 3] float16, point_label [B, N] uint8) of every sub-scene, the blocks
        scene, target, robot; ``T_base_target`` [B, 4, 4], ``T_base_links`` [B, L, 4, 4]."""
        B = T_base_target.shape[0]
        target = _transform(T_base_target.to(self.device), self.target_points)
        # An unseen target stays the zeros policy_cloud gives it (labelled none), not its pose's origin.
        target = torch.where((self.target_labels == LABEL_NONE)[..., None], torch.zeros_like(target), target)
        T_links = T_base_links.to(self.device)[:, self.robot.link_index]  # [B, R, 4, 4]
        robot = (T_links[..., :3, :3] @ self.robot.points_link[None, :, :, None])[..., 0] + T_links[..., :3, 3]
        robot_labels = torch.full((B, len(self.robot.link_index)), LABEL_ROBOT, dtype=torch.uint8, device=self.device)
        points = torch.cat([self.scene_points, target, robot], 1).to(torch.float16)
        return points, torch.cat([self.scene_labels, self.target_labels, robot_labels], 1)
