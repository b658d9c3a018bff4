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
    # The renderer may sit on another device than the simulation (CPU physics, CUDA
    # rendering on a GPU machine): the cloud joins the env's tensors on the env's device.
    for key in ("xyzw", "rgb", "segmentation"):
        if key in pcd:
            pcd[key] = pcd[key].to(lut.device)
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


def fetch_clouds(
    obs: dict,
    env_index: int = 0,
    max_distance: float | None = None,
    num_points: dict[str, int] | None = None,
    rng: np.random.Generator | None = None,
) -> FetchClouds:
    """The fused scene / target / robot clouds of sub-scene ``env_index`` of a point-cloud obs:
    ``obs_mode="pointcloud"`` (every camera point), or ``"compact_pointcloud"`` (the fixed-size
    cloud the imitation policies read: its points as drawn, repeats included where a segment
    had fewer voxels than its size; its zero padding left out).

    ``max_distance``: keep only points within this distance of the base origin (the
    imitation baselines use 1.2 m). ``num_points``: fixed cloud sizes, e.g.
    ``{"scene": 16384, "target": 2048, "robot": 4096}``, drawn uniformly with ``rng``
    (without replacement; with replacement when a cloud has fewer points; an empty cloud
    stays empty).
    """
    pcd = obs.get("pointcloud") if isinstance(obs, dict) else None
    if isinstance(pcd, dict) and "fetch_label" in pcd:
        points = _np(pcd["xyz_base"][env_index]).astype(np.float32)
        labels = _np(pcd["fetch_label"][env_index])
    elif isinstance(pcd, dict) and "seg" in pcd and "xyz" in pcd:  # compact_pointcloud
        points = _np(pcd["xyz"][env_index]).astype(np.float32)
        labels = _np(pcd["seg"][env_index])
    else:
        raise ValueError("fetch_clouds needs an observation of a FetchBench env made with obs_mode='pointcloud' "
                         f"or '{COMPACT_OBS_MODE}'")
    if max_distance is not None:
        labels = np.where(np.linalg.norm(points, axis=1) <= max_distance, labels, LABEL_NONE)
    masks = {
        "scene": (labels == LABEL_FURNITURE) | (labels == LABEL_OBJECT),
        "target": labels == LABEL_TARGET,
        "robot": labels == LABEL_ROBOT,
    }
    if num_points:
        unknown = sorted(set(num_points) - set(masks))
        if unknown:
            raise ValueError(f"unknown clouds {unknown} in num_points; valid: {', '.join(masks)}")
        if rng is None:
            raise ValueError("fetch_clouds with num_points needs an explicit rng (numpy Generator)")
    picks = {}
    for name, mask in masks.items():
        index = np.flatnonzero(mask)
        n = (num_points or {}).get(name)
        if n is not None and len(index) > 0:
            index = np.sort(rng.choice(index, size=n, replace=len(index) < n))
        picks[name] = index
    return FetchClouds(
        scene=points[picks["scene"]],
        target=points[picks["target"]],
        robot=points[picks["robot"]],
        scene_labels=labels[picks["scene"]].astype(np.uint8),
        target_segmentation_id=int(_np(obs["extra"]["target_segmentation_id"][env_index])),
    )


# ---------------------------------------------------------------------- compact clouds
#: ``obs_mode="compact_pointcloud"``: the fixed-size cloud below in place of ManiSkill's raw one.
COMPACT_OBS_MODE = "compact_pointcloud"
#: Points per segment, in this order in the compact cloud (the imitation baselines' sizes).
COMPACT_SIZES = {"scene": 16384, "target": 2048, "robot": 4096}
#: Voxel edge (m) per segment: one point per occupied voxel is kept before the fixed-size draw.
COMPACT_VOXEL = {"scene": 0.01, "target": 0.003, "robot": 0.005}
#: The workspace box in the robot-base frame, ((x0, x1), (y0, y1), (z0, z1)) m: every task
#: object rests at x 0.15-0.86, |y| < 0.73, z 0.01-1.31 (the test suite); the box adds
#: room for the arm carrying the target back (success: x < 0) and leaves out the floor.
WORKSPACE_BOX = ((-0.8, 1.4), (-1.0, 1.0), (-0.2, 1.6))
_SEGMENT_LABELS = {"scene": (LABEL_FURNITURE, LABEL_OBJECT), "target": (LABEL_TARGET,), "robot": (LABEL_ROBOT,)}


def compact_seed(episode_seed: int, step: int) -> int:
    """The seed of the compact cloud of step ``step`` of an episode: the same episode and
    step give the same points whoever computes them (the env, a replay, a conversion)."""
    return int(np.random.SeedSequence([int(episode_seed) % 2**63, int(step)]).generate_state(1)[0])


def _voxel_draw(points: np.ndarray, voxel: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``n`` points: one random point per occupied voxel, then ``n`` of those
    (all, plus random repeats, when fewer voxels are occupied)."""
    perm = rng.permutation(len(points))
    cells = np.floor(points[perm] / voxel).astype(np.int64)
    cells -= cells.min(axis=0)
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]
    _, first = np.unique(key, return_index=True)
    reps = perm[first]  # one point per voxel (voxels in key order)
    if len(reps) >= n:
        return reps[rng.permutation(len(reps))[:n]]
    return np.concatenate([reps, reps[rng.integers(len(reps), size=n - len(reps))]])


def _segment_table() -> np.ndarray:
    table = np.full(256, -1, dtype=np.int8)
    for k, labels in enumerate(_SEGMENT_LABELS.values()):
        table[list(labels)] = k
    return table


def compact_cloud(xyz_base, labels, seed: int, sizes: dict | None = None, box=WORKSPACE_BOX,
                  voxel: dict | None = None) -> dict:
    """A fixed-size, segment-aware cloud from one camera cloud (``xyz_base`` (N, 3) in the
    robot-base frame, ``labels`` (N,) ``LABEL_*``, numpy or torch).

    Points outside ``box`` (base frame) are dropped; each segment (scene = furniture and
    other objects, target, robot) is voxel-downsampled (``voxel`` m) and drawn to its size
    (``sizes``, default ``COMPACT_SIZES``) with a generator seeded by ``seed``. Returns
    ``{"xyz": (M, 3) float16, "seg": (M,) uint8}`` (numpy), M = sum of the sizes, the
    segments one after the other in ``sizes`` order; ``seg`` is each point's label
    (furniture or object within the scene block). A segment with no point is filled with
    zeros labelled ``LABEL_NONE``. (``seg``: ManiSkill's recorder gzips datasets of that name.)"""
    sizes = COMPACT_SIZES if sizes is None else sizes
    voxel = COMPACT_VOXEL if voxel is None else voxel
    unknown = sorted(set(sizes) - set(_SEGMENT_LABELS))
    if unknown:
        raise ValueError(f"unknown segments {unknown}; valid: {', '.join(_SEGMENT_LABELS)}")
    points = _np(xyz_base).reshape(-1, 3).astype(np.float32, copy=False)
    labels = _np(labels).reshape(-1).astype(np.uint8, copy=False)
    low, high = np.array([b[0] for b in box]), np.array([b[1] for b in box])
    segment = _segment_table()[labels]
    segment[~((points >= low) & (points <= high)).all(axis=1)] = -1
    rng = np.random.default_rng(int(seed))
    xyz_out, seg_out = [], []
    for k, (name, n) in enumerate((name, sizes[name]) for name in _SEGMENT_LABELS if name in sizes):
        index = np.flatnonzero(segment == k)
        if len(index) == 0:
            xyz_out.append(np.zeros((n, 3), dtype=np.float32))
            seg_out.append(np.full(n, LABEL_NONE, dtype=np.uint8))
            continue
        pick = index[_voxel_draw(points[index], voxel.get(name, COMPACT_VOXEL[name]), n, rng)]
        xyz_out.append(points[pick])
        seg_out.append(labels[pick])
    return {"xyz": np.concatenate(xyz_out).astype(np.float16), "seg": np.concatenate(seg_out)}


def compact_pointcloud_obs(obs: dict, seeds) -> dict:
    """``obs`` with ``obs["pointcloud"]`` (a FetchBench point-cloud observation with
    ``xyz_base`` and ``fetch_label``, batched [B, N, ...], torch or numpy) replaced by the
    compact cloud of each sub-scene (``compact_cloud``; ``seeds``: one per sub-scene),
    batched: ``xyz`` [B, M, 3] float16, ``seg`` [B, M] uint8. Everything else is kept."""
    pcd = obs["pointcloud"]
    if "xyz_base" not in pcd or "fetch_label" not in pcd:
        raise ValueError("compact_pointcloud_obs needs a FetchBench point-cloud observation (obs_mode='pointcloud': "
                         "pointcloud/xyz_base and pointcloud/fetch_label)")
    clouds = [compact_cloud(pcd["xyz_base"][i], pcd["fetch_label"][i], int(s)) for i, s in enumerate(seeds)]
    batched = {k: np.stack([c[k] for c in clouds]) for k in ("xyz", "seg")}
    out = dict(obs)
    if isinstance(pcd["xyz_base"], torch.Tensor):
        device = pcd["xyz_base"].device
        batched = {k: torch.from_numpy(v).to(device) for k, v in batched.items()}
    out["pointcloud"] = batched
    return out


# ---------------------------------------------------------------------- policy clouds
#: ``obs_mode="policy_pointcloud"``: the imitation policies' own points, made in the env from
#: cameras at ``POLICY_CAMERA_SIZE`` with no camera cloud or compact cloud in between.
POLICY_OBS_MODE = "policy_pointcloud"
#: The policy mode's cameras (the task's views, a quarter of the pixels of 320x240): the
#: 1,792 points the policies keep need ~40k camera points, not 153,600.
POLICY_CAMERA_SIZE = (160, 120)
#: Points per segment in the policy cloud (scene, target, robot; the imitation policies' sizes).
POLICY_CLOUD_SIZES = {"scene": 1024, "target": 512, "robot": 256}
#: ``obs_mode="composed_pointcloud"`` (``envs.composed``): the same points composed every step
#: from one render at the episode's start, the target and robot placed by their poses.
COMPOSED_OBS_MODE = "composed_pointcloud"
#: Obs modes whose ``obs["pointcloud"]`` is the policies' points themselves (``points``,
#: ``point_label``; ``POLICY_CLOUD_SIZES``), not a cloud a policy subsamples.
POINTS_OBS_MODES = (POLICY_OBS_MODE, COMPOSED_OBS_MODE)
#: Farthest-point sampling of a segment starts from this many candidates per point kept:
#: the segment's pixels with the smallest keys (a seeded hash of the pixel's index).
POLICY_CANDIDATES_PER_POINT = 4
_MASK32 = 0xFFFFFFFF
_PIXEL_BITS = 20  # pixel index bits of a sort key (two 160x120 cameras: 38,400 pixels)


def _mul32(x: torch.Tensor, c: int) -> torch.Tensor:
    """(x * c) mod 2^32 for int64 ``x`` in [0, 2^32), without an int64 overflow (same bits on any device)."""
    lo, hi = c & 0xFFFF, c >> 16
    return (x * lo + ((x * hi) & 0xFFFF) * 65536) & _MASK32


def hash32(x: torch.Tensor) -> torch.Tensor:
    """A 32-bit integer mix (lowbias32) of int64 values in [0, 2^32): a counter-based random draw."""
    x = x ^ (x >> 16)
    x = _mul32(x, 0x7FEB352D)
    x = x ^ (x >> 15)
    x = _mul32(x, 0x846CA68B)
    return x ^ (x >> 16)


def pixel_keys(seeds: torch.Tensor, num_pixels: int) -> torch.Tensor:
    """[B, P] int64 sort keys, all distinct within a row: a hash of (seed, pixel index) above the
    index. Pixel i's key depends on i and the seed only, so a pixel that changes (an edge moving
    onto another surface) changes its own candidacy and no other pixel's."""
    if num_pixels > 1 << _PIXEL_BITS:
        raise ValueError(f"{num_pixels} pixels: the policy cloud's keys hold at most {1 << _PIXEL_BITS}")
    index = torch.arange(num_pixels, dtype=torch.int64, device=seeds.device)
    mixed = hash32(seeds.long()[:, None] & _MASK32)
    key = hash32(_mul32(index[None, :], 0x9E3779B1) ^ mixed)
    return (key << _PIXEL_BITS) | index[None, :]


def policy_cloud(points_base: torch.Tensor, labels: torch.Tensor, seeds: torch.Tensor,
                 sizes: dict | None = None, box=WORKSPACE_BOX) -> tuple[torch.Tensor, torch.Tensor]:
    """The policies' points of a batch of camera clouds: (points [B, N, 3] float16, point_label
    [B, N] uint8), the segments scene, target, robot one after the other (``sizes``).

    ``points_base`` [B, P, 3] (robot-base frame) and ``labels`` [B, P] (``LABEL_*``, 0 for a
    pixel not seen) are the cameras' pixels in a fixed order; ``seeds`` [B] (``compact_seed``).
    Per segment, points outside ``box`` are dropped; the candidates are the segment's
    ``POLICY_CANDIDATES_PER_POINT`` x n pixels of smallest key (``pixel_keys``: a seeded uniform
    draw), repeated cyclically when fewer; then n of them by farthest-point sampling from the
    smallest key. A segment with no point is zeros labelled ``LABEL_NONE``. Runs on the tensors'
    device (the render device on a GPU machine), batched over the sub-scenes."""
    from ..geometry.pointops import farthest_point_sample

    sizes = POLICY_CLOUD_SIZES if sizes is None else sizes
    unknown = sorted(set(sizes) - set(_SEGMENT_LABELS))
    if unknown:
        raise ValueError(f"unknown segments {unknown}; valid: {', '.join(_SEGMENT_LABELS)}")
    points_base = points_base.float()
    B, P, _ = points_base.shape
    device = points_base.device
    low = torch.tensor([b[0] for b in box], device=device)
    high = torch.tensor([b[1] for b in box], device=device)
    in_box = ((points_base >= low) & (points_base <= high)).all(-1)
    segment = torch.from_numpy(_segment_table()).to(device)[labels.long()]
    segment = torch.where(in_box, segment, torch.full_like(segment, -1))
    keys = pixel_keys(seeds.to(device), P)
    never = torch.iinfo(torch.int64).max
    rows = torch.arange(B, device=device)[:, None]
    points_out, labels_out = [], []
    for k, name in enumerate(_SEGMENT_LABELS):
        if name not in sizes:
            continue
        n = sizes[name]
        m = min(POLICY_CANDIDATES_PER_POINT * n, P)
        in_segment = segment == k
        count = in_segment.sum(1)
        _, order = torch.topk(torch.where(in_segment, keys, torch.full_like(keys, never)), m, dim=1,
                              largest=False, sorted=True)
        # Fewer than m pixels in the segment: its pixels, in key order, over and over.
        slot = torch.arange(m, device=device)[None, :] % count.clamp(min=1, max=m)[:, None]
        candidates = torch.gather(order, 1, slot)
        xyz = points_base[rows, candidates]
        pick = farthest_point_sample(xyz, n)
        chosen = torch.gather(candidates, 1, pick.to(device))
        seen = (count > 0)[:, None]
        points_out.append(torch.where(seen[..., None], points_base[rows, chosen], torch.zeros(1, device=device)))
        labels_out.append(torch.where(seen, labels[rows, chosen].to(torch.uint8),
                                      torch.full((1,), LABEL_NONE, dtype=torch.uint8, device=device)))
    return torch.cat(points_out, 1).to(torch.float16), torch.cat(labels_out, 1)


def camera_points_base(obs: dict, lut: torch.Tensor, T_base_world: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(points_base [B, P, 3], labels [B, P] uint8) of the cameras' ``position`` and
    ``segmentation`` textures (ManiSkill's, in sensor order, on the render device), with
    ``LABEL_NONE`` outside the ``DEPTH_RANGE`` crop and for the background. The labels and the
    depth crop are those of ``add_fetch_pointcloud``; the points go from each camera's OpenGL
    frame to the base frame in one transform."""
    points, labels = [], []
    for uid, images in obs["sensor_data"].items():
        position = images["position"]
        device = position.device
        xyz_gl = position[..., :3].reshape(position.shape[0], -1, 3).float() / 1000.0  # mm -> m
        seg = images["segmentation"].reshape(position.shape[0], -1).long().clamp(min=0, max=lut.shape[1] - 1)
        T = T_base_world.to(device) @ obs["sensor_param"][uid]["cam2world_gl"].to(device)  # [B, 4, 4]
        points.append(xyz_gl @ T[:, :3, :3].transpose(1, 2) + T[:, None, :3, 3])
        depth = -xyz_gl[..., 2]
        seen = (seg != 0) & (depth >= DEPTH_RANGE[0]) & (depth <= DEPTH_RANGE[1])
        label = torch.gather(lut.to(device), 1, seg)
        labels.append(torch.where(seen, label, torch.zeros_like(label)))
    return torch.cat(points, 1), torch.cat(labels, 1)
