"""The segmented fetch input of point-cloud observations, in the robot-base frame.

In ``obs_mode="pointcloud"`` the env adds to ``obs["pointcloud"]``:

- ``xyz_base`` [B, N, 3] float32: every camera point in the robot-base frame,
- ``fetch_label`` [B, N] uint8: ``LABEL_ROBOT``, ``LABEL_TARGET``, ``LABEL_OBJECT`` (the
  other objects), ``LABEL_FURNITURE`` (furniture, robot table, floor), or ``LABEL_NONE``
  for background and points outside the 0.15-2.5 m depth range of their camera,

and to ``obs["extra"]`` the target's segmentation id and, per camera, its pose in the
base frame (``cam_pose_base_<side>``, OpenCV axes) and intrinsics (``cam_intrinsic_<side>``).

``fetch_clouds(obs)`` turns one sub-scene of such an observation into the three
clouds the sense-plan-act and imitation baselines use (``FetchClouds``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

LABEL_NONE, LABEL_ROBOT, LABEL_TARGET, LABEL_OBJECT, LABEL_FURNITURE = 0, 1, 2, 3, 4
LABEL_NAMES = {LABEL_NONE: "none", LABEL_ROBOT: "robot", LABEL_TARGET: "target", LABEL_OBJECT: "object",
               LABEL_FURNITURE: "furniture"}
DEPTH_RANGE = (0.15, 2.5)  # m, the original's depth crop


def segmentation_lut(num_ids: int, robot_ids, target_ids, object_ids, furniture_ids, num_envs: int, device) -> torch.Tensor:
    """[B, num_ids] uint8 table: per-scene segmentation id -> fetch label, for each sub-scene.

    ``robot_ids`` / ``furniture_ids``: lists of [B] id tensors; ``object_ids``: [B, S]
    ids of the task objects (placeholders left out: -1); ``target_ids``: [B].
    """
    lut = torch.zeros((num_envs, num_ids), dtype=torch.uint8, device=device)
    rows = torch.arange(num_envs, device=device)
    for ids in furniture_ids:
        lut[rows, ids.long()] = LABEL_FURNITURE
    for ids in robot_ids:
        lut[rows, ids.long()] = LABEL_ROBOT
    for k in range(object_ids.shape[1]):
        ids = object_ids[:, k].long()
        ok = ids >= 0
        lut[rows[ok], ids[ok]] = LABEL_OBJECT
    lut[rows, target_ids.long()] = LABEL_TARGET
    lut[:, 0] = LABEL_NONE  # 0 is the background
    return lut


def world_to_base(points_world: torch.Tensor, base_pose_raw: torch.Tensor) -> torch.Tensor:
    """[B, N, 3] world points into the frame of the base pose [B, 7] (p, q wxyz)."""
    from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

    return world_to_frame(points_world, base_pose_raw[:, :3], quaternion_to_matrix(base_pose_raw[:, 3:]))


def world_to_frame(points_world: torch.Tensor, p_world_frame: torch.Tensor, R_world_frame: torch.Tensor) -> torch.Tensor:
    """[B, N, 3] world points into a frame given by its origin [B, 3] and rotation [B, 3, 3]."""
    # p_frame = R^T (p_world - t); as row vectors: (p_world - t) @ R
    return (points_world - p_world_frame[:, None, :]) @ R_world_frame


def add_fetch_pointcloud(obs: dict, lut: torch.Tensor, p_world_base: torch.Tensor, R_world_base: torch.Tensor,
                         camera_pixels: dict) -> None:
    """Add ``xyz_base`` and ``fetch_label`` to ``obs["pointcloud"]`` (in place).

    ``camera_pixels``: camera uid -> pixel count, in sensor order (ManiSkill concatenates
    the cameras' pixels in that order)."""
    pcd = obs["pointcloud"]
    xyzw = pcd["xyzw"]
    seg = pcd["segmentation"][..., 0].long().clamp(min=0, max=lut.shape[1] - 1)
    labels = torch.gather(lut, 1, seg)
    # Depth of each point in its own camera: cameras' pixels are concatenated in sensor order.
    depth = torch.zeros(xyzw.shape[:2], device=xyzw.device)
    start = 0
    for uid, n in camera_pixels.items():
        extrinsic = obs["sensor_param"][uid]["extrinsic_cv"].to(xyzw.device)  # [B, 3, 4] world -> camera
        pts = xyzw[:, start:start + n, :3]
        depth[:, start:start + n] = (pts @ extrinsic[:, 2:3, :3].transpose(1, 2))[..., 0] + extrinsic[:, 2, 3][:, None]
        start += n
    in_range = (depth >= DEPTH_RANGE[0]) & (depth <= DEPTH_RANGE[1]) & (xyzw[..., 3] > 0)
    labels = torch.where(in_range, labels, torch.zeros_like(labels))
    pcd["xyz_base"] = world_to_frame(xyzw[..., :3], p_world_base, R_world_base).float()
    pcd["fetch_label"] = labels


@dataclass
class FetchClouds:
    """One sub-scene's segmented clouds in the robot-base frame (numpy, float32, (N, 3))."""

    scene: np.ndarray  # furniture, robot table, floor and the other objects: the obstacles
    target: np.ndarray
    robot: np.ndarray
    scene_labels: np.ndarray  # (N,) LABEL_FURNITURE or LABEL_OBJECT per scene point
    target_segmentation_id: int


def _np(x):
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


def fetch_clouds(obs: dict, env_index: int = 0) -> FetchClouds:
    """The fused scene / target / robot clouds of sub-scene ``env_index`` of a point-cloud obs."""
    if not isinstance(obs, dict) or "pointcloud" not in obs or "fetch_label" not in obs["pointcloud"]:
        raise ValueError("fetch_clouds needs an observation of a FetchBench env made with obs_mode='pointcloud'")
    points = _np(obs["pointcloud"]["xyz_base"][env_index]).astype(np.float32)
    labels = _np(obs["pointcloud"]["fetch_label"][env_index])
    scene_mask = (labels == LABEL_FURNITURE) | (labels == LABEL_OBJECT)
    return FetchClouds(
        scene=points[scene_mask],
        target=points[labels == LABEL_TARGET],
        robot=points[labels == LABEL_ROBOT],
        scene_labels=labels[scene_mask].astype(np.uint8),
        target_segmentation_id=int(_np(obs["extra"]["target_segmentation_id"][env_index])),
    )
