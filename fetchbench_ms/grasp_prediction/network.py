"""Contact-GraspNet (Sundermeyer et al. 2021) in plain PyTorch, batched.

A PointNet++ with multi-scale grouping reads a cloud of N points (20k) and predicts, for
each of M contact points (2048, farthest-point samples of the cloud), a grasp whose one
finger touches that point:

- ``logits``: grasp success confidence (sigmoid -> score),
- ``baseline``: unit vector along which the fingers close (from the contact to the other
  finger),
- ``approach``: unit vector of the approach, orthogonal to the baseline,
- ``width``: the finger opening, m.

The hand pose follows (the original's construction): approach z, baseline x, origin at
``contact + width/2 * baseline - GRIPPER_DEPTH * approach``; the Franka hand's TCP lies
between the fingers, ``GRIPPER_DEPTH`` (0.1034 m) along the approach from that origin.

Layers (the ``cgn-pytorch`` 0.4.3 checkpoint's; parameter names match it so its
state dict loads with ``strict=True``):

- set abstraction, 3 levels of 3 scales each: 2048 / 512 / 128 centres, radii
  (0.02, 0.04, 0.08) / (0.04, 0.08, 0.16) / (0.08, 0.16, 0.32) m, up to 64 neighbours,
  a shared MLP on ``[neighbour features, neighbour - centre]`` (Linear, ReLU, BatchNorm
  per layer) and a max over the neighbours; the scales' features are concatenated
  (320, 640, 640 channels);
- ``set_abstract_final``: the global MLP 640 -> 1024. The checkpoint carries it, but its
  forward pass never uses its output (feature propagation starts from the last
  set-abstraction level), so it is kept for loading only and not evaluated;
- feature propagation 128 -> 128 -> 512 -> 2048 points, inverse-distance interpolation
  from the 3 nearest coarser points, concatenated with the skip features, MLP;
- four heads on ``[contact xyz, 128 features]``: Conv1d 131 -> 128, BatchNorm, Dropout,
  Conv1d -> 1 (confidence), 3 (baseline), 3 (approach), 1 (width).

The cloud goes in mean-centred, z up (the pretrained weights were trained on world-frame
table-top clouds minus their mean: ``predict.py`` does that).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..geometry.pointops import ball_query, farthest_point_sample, gather, knn_interpolate

GRIPPER_DEPTH = 0.1034  # m, hand origin to the TCP along the approach (= fetchbench_ms.grasp_labels.TCP_OFFSET)
MAX_WIDTH = 0.08  # m, the Franka hand's largest opening
NUM_POINTS = 20000  # input points per cloud
NUM_CONTACTS = 2048  # contact points predicted per cloud


@dataclass(frozen=True)
class CGNConfig:
    centers: tuple = (2048, 512, 128)
    radii: tuple = ((0.02, 0.04, 0.08), (0.04, 0.08, 0.16), (0.08, 0.16, 0.32))
    mlps: tuple = (((32, 32, 64), (64, 64, 128), (64, 96, 128)),
                   ((64, 64, 128), (128, 128, 256), (128, 128, 256)),
                   ((64, 64, 128), (128, 128, 256), (128, 128, 256)))
    max_neighbours: int = 64
    global_mlp: tuple = (256, 512, 1024)
    fp_mlps: tuple = ((256, 256), (256, 128), (128, 128, 128))
    head_dropout: tuple = (0.5, 0.7, 0.7, 0.0)
    # The cgn-pytorch checkpoint was trained with PyG's PointNetConv, whose self loops on a
    # bipartite (points -> centres) graph join centre i to the i-th *input* point, not to
    # itself: one extra, usually distant neighbour per centre. Its weights expect it.
    index_self_loop: bool = True


def shared_mlp(channels: list[int]) -> nn.Sequential:
    """Per-point MLP: (Linear, ReLU, BatchNorm1d) per layer, on the last dimension."""
    return nn.Sequential(*[nn.Sequential(nn.Linear(a, b), nn.ReLU(), nn.BatchNorm1d(b))
                           for a, b in zip(channels[:-1], channels[1:])])


def apply_mlp(mlp: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """``mlp`` on features [..., C] (BatchNorm1d wants [rows, C])."""
    shape = x.shape[:-1]
    return mlp(x.reshape(-1, x.shape[-1])).reshape(*shape, -1)


class _PointConv(nn.Module):
    """max over neighbours j of MLP([x_j, p_j - p_i]) (PointNet++'s grouping layer)."""

    def __init__(self, channels: list[int]):
        super().__init__()
        self.local_nn = shared_mlp(channels)

    def forward(self, features, points, centers, neighbours):
        if features is None:
            rel = gather(points, neighbours) - centers[:, :, None, :]  # [B, M, K, 3]
            return apply_mlp(self.local_nn, rel).amax(dim=2)
        # The first layer is linear in [x_j, p_j - p_i]: apply it once per point (W_x x_j + W_p p_j
        # + b) and per centre (W_p p_i), then group. The same numbers as grouping first, with
        # the widest matrix product done on N points instead of M x K neighbours (16x fewer at
        # the second level): a third of the network's time on a CPU.
        linear = self.local_nn[0][0]
        C = features.shape[-1]
        w_features, w_points = linear.weight[:, :C], linear.weight[:, C:]
        per_point = torch.addmm(linear.bias, features.reshape(-1, C), w_features.t()).view(*features.shape[:2], -1)
        per_point = per_point + points @ w_points.t()
        first = gather(per_point, neighbours) - (centers @ w_points.t())[:, :, None, :]
        first = apply_mlp(self.local_nn[0][1:], first)  # the first layer's ReLU and BatchNorm
        return apply_mlp(self.local_nn[1:], first).amax(dim=2)


class SetAbstractionScale(nn.Module):
    """One scale of a multi-scale set-abstraction level (its grouping is done by the level)."""

    def __init__(self, radius: float, channels: list[int]):
        super().__init__()
        self.radius = radius
        self.conv = _PointConv(channels)


def set_abstraction(scales, features, points, centers, max_neighbours: int, index_self_loop: bool):
    """Features [B, M, sum of the scales' channels] of ``centers``: every scale's grouping
    (one distance computation for all radii) and point convolution, concatenated."""
    neighbours = ball_query(points, centers, [s.radius for s in scales], max_neighbours)
    if index_self_loop:  # see CGNConfig.index_self_loop
        B, M = centers.shape[:2]
        loop = torch.arange(M, device=points.device)[None, :, None].expand(B, M, 1)
        neighbours = [torch.cat([n, loop], -1) for n in neighbours]
    return torch.cat([s.conv(features, points, centers, n) for s, n in zip(scales, neighbours)], -1)


class FeaturePropagation(nn.Module):
    def __init__(self, channels: list[int]):
        super().__init__()
        self.nn = shared_mlp(channels)

    def forward(self, features, points, skip_features, skip_points):
        up = knn_interpolate(features, points, skip_points, k=3)
        return apply_mlp(self.nn, torch.cat([up, skip_features], -1))


class ContactGraspNet(nn.Module):
    def __init__(self, config: CGNConfig = CGNConfig()):
        super().__init__()
        self.config = config
        levels, in_channels = [], 0
        for radii, mlps in zip(config.radii, config.mlps):
            levels.append(nn.ModuleList([SetAbstractionScale(r, [in_channels + 3, *mlp])
                                         for r, mlp in zip(radii, mlps)]))
            in_channels = sum(mlp[-1] for mlp in mlps)
        self.set_abstract_msg = nn.ModuleList(levels)
        self.set_abstract_final = shared_mlp([in_channels, *config.global_mlp])  # loaded, unused (see above)
        level_channels = [sum(m[-1] for m in mlps) for mlps in config.mlps]  # 320, 640, 640
        skips = level_channels[::-1]  # the deepest level is its own first skip
        fp, channels = [], level_channels[-1]
        for skip, mlp in zip(skips, config.fp_mlps):
            fp.append(FeaturePropagation([channels + skip, *mlp]))
            channels = mlp[-1]
        self.feat_prop = nn.ModuleList(fp)
        self.multihead = nn.ModuleList([
            nn.Sequential(nn.Conv1d(channels + 3, 128, 1), nn.BatchNorm1d(128), nn.Dropout(p), nn.Conv1d(128, out, 1))
            for out, p in zip((1, 3, 3, 1), config.head_dropout)])

    def forward(self, points: torch.Tensor, contact_index: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """``points`` [B, N, 3] (mean-centred, shuffled); ``contact_index`` [B, M]: which points
        are the contact points (default: M = 2048 farthest points). Returns [B, M, ...]
        tensors: ``contacts``, ``logits``, ``baseline``, ``approach``, ``width``,
        ``raw_width`` (before clamping at 0; the hand pose uses it) and ``T_grasp`` (4x4, CGN's
        gripper frame: baseline x, approach z)."""
        if contact_index is None:
            contact_index = farthest_point_sample(points, self.config.centers[0])
        features, pos = None, points
        skips = []
        for level, scales in enumerate(self.set_abstract_msg):
            index = contact_index if level == 0 else farthest_point_sample(pos, self.config.centers[level])
            centers = gather(pos, index)
            features = set_abstraction(scales, features, pos, centers, self.config.max_neighbours,
                                       self.config.index_self_loop)
            pos = centers
            skips.append((features, pos))
        for module, (skip_features, skip_pos) in zip(self.feat_prop, skips[::-1]):
            features = module(features, pos, skip_features, skip_pos)
            pos = skip_pos
        x = torch.cat([pos, features], -1).transpose(1, 2)  # [B, 131, M]
        logits, z1, z2, w = (head(x).transpose(1, 2) for head in self.multihead)
        baseline = z1 / z1.norm(dim=-1, keepdim=True)
        approach = z2 - (baseline * z2).sum(-1, keepdim=True) * baseline
        approach = approach / approach.norm(dim=-1, keepdim=True)
        raw_width = w[..., 0].clamp(min=-2 * MAX_WIDTH, max=MAX_WIDTH)
        return {
            "contacts": pos,
            "logits": logits[..., 0],
            "baseline": baseline,
            "approach": approach,
            "raw_width": raw_width,
            "width": raw_width.clamp(min=0.0),
            "T_grasp": grasp_frames(pos, baseline, approach, raw_width),
        }


def grasp_frames(contacts, baseline, approach, width, depth: float = GRIPPER_DEPTH) -> torch.Tensor:
    """[..., 4, 4] gripper frames (x baseline, z approach, y = z x x) of contact points [..., 3]."""
    T = torch.zeros(*contacts.shape[:-1], 4, 4, dtype=contacts.dtype, device=contacts.device)
    T[..., :3, 0] = baseline
    T[..., :3, 1] = torch.cross(approach, baseline, dim=-1)
    T[..., :3, 2] = approach
    T[..., :3, 3] = contacts + 0.5 * width[..., None] * baseline - depth * approach
    T[..., 3, 3] = 1.0
    return T
