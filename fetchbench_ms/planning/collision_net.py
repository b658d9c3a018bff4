"""A learned scene-collision checker for partially observed scenes (after CabiNet, Murali
et al. 2023): the observed scene cloud (robot points removed, base frame) in, a
collision probability per query robot configuration out, for many queries against one
encoded scene.

The scene is encoded once per observation:

1. ``scene_grid``: the cloud's truncated distance on a fixed 2 cm grid over the arm's
   workspace (``GRID_BOUNDS``): an EDT of the occupied cells, refined to the exact
   nearest-point distance (5 mm voxel centres, as ``world.PointCloudField``) at the
   vertices within ``EXACT_BAND`` of the cloud. Its trilinear reading is the distance
   field the point-cloud planners use (about a millimetre where the cameras saw a
   surface); what it cannot know is what lies behind the seen surfaces.
2. ``SceneCollisionNet.encode``: a small 3D CNN over that grid (plus coordinates: the
   floor and the robot table sit where they sit) gives a 4 cm feature grid whose
   receptive field (~0.6 m) sees the furniture around a point: where a board seen edge-on
   continues, how thick a wall behind a front face is.

A query is a set of spheres (the Panda's collision spheres at the configuration, and a
carried object's, ``planning.checker.Attachment``): per sphere, an MLP reads the feature
grid and the distance grid at its centre and its radius and predicts its clearance as a
correction of what the cloud alone says (``distance - radius``); the query's clearance is
the smallest over its spheres and its collision probability ``sigmoid(-clearance / TAU)``.
Training (``baselines/mppi_collision/``) regresses every sphere's exact clearance to the
scene's true geometry (the oracle mesh world) and the query's collision label.
"""
from __future__ import annotations

import functools
import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from ..utils.packed import packed_or_plain, torch_load

GRID_RESOLUTION = 0.02  # m between scene-grid vertices
GRID_BOUNDS = ((-1.0, -1.1, -0.4), (1.2, 1.1, 1.4))  # base frame, m: the arm's reach and a carried object's
GRID_SHAPE = tuple(int(round((hi - lo) / GRID_RESOLUTION)) + 1 for lo, hi in zip(*GRID_BOUNDS))
TRUNCATION = 0.20  # m: distances are exact up to here (where seen), this beyond
EXACT_BAND = 0.06  # m: vertices this near the cloud (by the EDT) get the exact nearest-point distance
CLOUD_VOXEL = 0.005  # m: the cloud is reduced to occupied voxel centres first
CLEARANCE_CLIP = (-0.05, 0.10)  # m: the range of clearances the network is trained to predict
TAU = 0.005  # m: the probability's width around zero clearance
CHECKPOINT_NAME = "collision_net"


def checkpoint_path() -> Path:
    from ..utils.paths import assets_root

    return assets_root() / "checkpoints" / f"{CHECKPOINT_NAME}.pt"


def scene_grid(points_base: np.ndarray) -> np.ndarray:
    """(GRID_SHAPE) float32 truncated distance (m) from each grid vertex to the cloud."""
    from scipy.ndimage import distance_transform_edt
    from scipy.spatial import cKDTree

    lo = np.asarray(GRID_BOUNDS[0])
    points = np.asarray(points_base, dtype=float).reshape(-1, 3)
    keys = np.unique(np.floor(points / CLOUD_VOXEL).astype(np.int64), axis=0)
    centers = (keys + 0.5) * CLOUD_VOXEL
    idx = np.round((centers - lo) / GRID_RESOLUTION).astype(int)
    inside = ((idx >= 0) & (idx < GRID_SHAPE)).all(axis=1)
    if not inside.any():
        return np.full(GRID_SHAPE, TRUNCATION, dtype=np.float32)
    occupied = np.zeros(GRID_SHAPE, dtype=bool)
    occupied[tuple(idx[inside].T)] = True
    # Points just outside the grid still count for vertices near its faces.
    near_grid = ((centers >= lo - TRUNCATION) & (centers <= np.asarray(GRID_BOUNDS[1]) + TRUNCATION)).all(axis=1)
    tree = cKDTree(centers[near_grid])
    values = distance_transform_edt(~occupied, sampling=GRID_RESOLUTION)  # to the nearest occupied vertex
    near = np.nonzero(values < EXACT_BAND + GRID_RESOLUTION)
    vertices = lo + np.stack(near, 1) * GRID_RESOLUTION
    d, _ = tree.query(vertices, distance_upper_bound=TRUNCATION)
    values = np.minimum(values, TRUNCATION)
    values[near] = np.minimum(d, TRUNCATION)
    half_diagonal = 0.5 * CLOUD_VOXEL * np.sqrt(3.0)
    return np.clip(values - half_diagonal, 0.0, TRUNCATION).astype(np.float32)


def grid_to_uint8(grid: np.ndarray) -> np.ndarray:
    """A compact copy for datasets: 0.8 mm steps (a 2 cm grid is the coarser error)."""
    return np.round(np.clip(grid, 0, TRUNCATION) / TRUNCATION * 255).astype(np.uint8)


def grid_from_uint8(grid_u8) -> torch.Tensor:
    return torch.as_tensor(grid_u8).float() * (TRUNCATION / 255)


@dataclass(frozen=True)
class NetConfig:
    channels: tuple[int, int, int] = (16, 32, 64)  # 2 cm, 4 cm, 8 cm stages
    hidden: int = 64  # per-sphere MLP width


def _conv(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv3d(cin, cout, 3, stride=stride, padding=dilation, dilation=dilation),
                         nn.GroupNorm(4, cout), nn.GELU())


def _trilinear(table: torch.Tensor, shape_zyx: tuple[int, int, int], s: torch.Tensor) -> torch.Tensor:
    """Trilinear reading of a vertex grid stored as rows ``table`` (N, Z*Y*X, C) at points
    ``s`` (N, M, 3) (x, y, z in [0, 1] over the grid, clamped to its border): (N, M, C)."""
    Z, Y, X = shape_zyx
    size = torch.tensor([X - 1, Y - 1, Z - 1], device=s.device, dtype=s.dtype)
    g = s.clamp(0, 1) * size
    i0 = torch.minimum(g.floor(), size - 1).long()
    w = g - i0  # (N, M, 3)
    base = (i0[..., 2] * Y + i0[..., 1]) * X + i0[..., 0]  # (N, M)
    n, m = base.shape
    offsets = torch.tensor([(dz * Y + dy) * X + dx for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)],
                           device=s.device)
    idx = (base[..., None] + offsets).reshape(n, -1)  # (N, M*8)
    rows = torch.gather(table, 1, idx[..., None].expand(n, idx.shape[1], table.shape[2])).reshape(n, m, 8, -1)
    wx, wy, wz = w[..., 0:1], w[..., 1:2], w[..., 2:3]
    weights = torch.cat([(1 - wz if dz == 0 else wz) * (1 - wy if dy == 0 else wy) * (1 - wx if dx == 0 else wx)
                         for dz in (0, 1) for dy in (0, 1) for dx in (0, 1)], dim=-1)  # (N, M, 8)
    return (rows * weights[..., None]).sum(dim=2)


class SceneCollisionNet(nn.Module):
    """See the module docstring. ``encode(grid)`` once per scene, then ``clearance`` /
    ``probability`` for any number of sphere sets."""

    def __init__(self, config: NetConfig = NetConfig()):
        super().__init__()
        self.config = config
        c1, c2, c3 = config.channels
        self.stem = _conv(5, c1)  # distance, nearness, x, y, z
        self.down1 = nn.Sequential(_conv(c1, c2, stride=2), _conv(c2, c2))  # 4 cm
        self.down2 = nn.Sequential(_conv(c2, c3, stride=2), _conv(c3, c3, dilation=2))  # 8 cm
        self.fuse = nn.Sequential(nn.Conv3d(c2 + c3, c2, 1), nn.GELU())  # back at 4 cm
        h = config.hidden
        self.head = nn.Sequential(nn.Linear(c2 + 2 + 1 + 3, h), nn.GELU(), nn.Linear(h, h), nn.GELU(), nn.Linear(h, 1))
        lo, hi = torch.tensor(GRID_BOUNDS[0]), torch.tensor(GRID_BOUNDS[1])
        self.register_buffer("lo", lo, persistent=False)
        self.register_buffer("span", hi - lo, persistent=False)
        # Clearance below which a query is called colliding: chosen on the validation tasks
        # (train.py) so that few colliding queries are called free; saved with the weights.
        self.decision_margin = 0.0

    # -- scene ------------------------------------------------------------------------------
    def encode(self, grid: torch.Tensor) -> dict:
        """``grid`` (X, Y, Z) or (N, X, Y, Z) distances (m) from ``scene_grid`` -> the encoded
        scene(s): a feature grid and the distance grid, both as (N, C, Z, Y, X) for grid_sample."""
        grid = grid.to(self.lo.device, torch.float32)
        if grid.dim() == 3:
            grid = grid[None]
        n = grid.shape[0]
        g = grid.permute(0, 3, 2, 1)[:, None]  # (N, 1, Z, Y, X): grid_sample reads coordinates as (x, y, z)
        axes = [torch.linspace(-1, 1, s, device=g.device) for s in g.shape[2:]]
        zz, yy, xx = torch.meshgrid(*axes, indexing="ij")
        coords = torch.stack([xx, yy, zz])[None].expand(n, 3, *g.shape[2:])
        x = torch.cat([g / TRUNCATION, torch.exp(-g / 0.02), coords], dim=1)
        f1 = self.stem(x)
        f2 = self.down1(f1)
        f3 = self.down2(f2)
        up = F.interpolate(f3, size=f2.shape[2:], mode="trilinear", align_corners=True)
        features = self.fuse(torch.cat([f2, up], dim=1))
        # Channels last, one row per vertex: a trilinear read is then 8 row gathers
        # (grid_sample over 32 channels was 3x slower on a CPU).
        return {"features": features.permute(0, 2, 3, 4, 1).reshape(n, -1, features.shape[1]),
                "features_shape": tuple(features.shape[2:]), "distance": g.reshape(n, -1, 1),
                "distance_shape": tuple(g.shape[2:])}

    # -- queries ----------------------------------------------------------------------------
    def sphere_clearance(self, scene: dict, centers: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """Predicted clearance (m) of spheres ``centers`` (..., S, 3), ``radii`` (S,) or
        (..., S), base frame. One encoded scene: any leading shape; N scenes: ``centers``
        (N, ..., S, 3), scene n for row n."""
        feats = scene["features"]
        n = feats.shape[0]
        shape = centers.shape[:-1]
        # Positions, distances and radii in float32 whatever the features' dtype (under bf16
        # autocast a position would be rounded to ~4 mm); the MLP may run in bf16.
        s = (centers.reshape(n, -1, 3).float() - self.lo) / self.span  # (N, M, 3) in [0, 1] inside
        f = _trilinear(feats, scene["features_shape"], s).float()
        d = _trilinear(scene["distance"], scene["distance_shape"], s).float()
        u = 2 * s - 1
        r = torch.broadcast_to(radii.float(), shape).reshape(n, -1, 1)
        outside = (u.abs() > 1).any(dim=-1, keepdim=True).float()  # beyond the grid: nothing known
        x = torch.cat([f, d / TRUNCATION, torch.exp(-d / 0.02), r / 0.05, u], dim=-1)
        correction = 0.05 * self.head(x).float()
        clearance = d - r + correction * (1 - outside) + outside * TRUNCATION
        return clearance.reshape(shape)

    def clearance(self, scene: dict, centers: torch.Tensor, radii: torch.Tensor,
                  mask: torch.Tensor | None = None) -> torch.Tensor:
        """(...,) predicted clearance of each query (the smallest of its spheres'); ``mask``
        (S,) or (..., S) leaves spheres out (padding, links the caller does not check)."""
        c = self.sphere_clearance(scene, centers, radii)
        if mask is not None:
            c = torch.where(torch.broadcast_to(mask, c.shape), c, torch.full_like(c, TRUNCATION))
        return c.amin(dim=-1)

    def probability(self, scene: dict, centers: torch.Tensor, radii: torch.Tensor,
                    mask: torch.Tensor | None = None) -> torch.Tensor:
        """(...,) collision probability of each query (> 0.5: clearance below the decision margin)."""
        return torch.sigmoid((self.decision_margin - self.clearance(scene, centers, radii, mask)) / TAU)


class RobotSpheres:
    """The Panda's world-checked spheres (``robot.WORLD_LINKS``, 77) and a carried object's
    at batches of configurations, on any device: the network's queries."""

    def __init__(self, device="cpu", dtype=torch.float32):
        from .robot import WORLD_LINKS, panda

        robot = panda()
        sp = robot.spheres
        self.device, self.dtype = torch.device(device), dtype
        self.fk = robot.fk.to(self.device, dtype)
        self.links = sp.links
        world = np.flatnonzero(robot.sphere_mask(WORLD_LINKS))
        self.link_of = torch.as_tensor(sp.link_index[world], device=self.device)
        self.centers_link = torch.as_tensor(sp.centers_link[world], device=self.device, dtype=dtype)
        self.radii = torch.as_tensor(sp.radii[world], device=self.device, dtype=dtype)  # (77,)
        fingers = robot.sphere_mask(("panda_leftfinger", "panda_rightfinger"))[world]
        self.finger_mask = torch.as_tensor(fingers, device=self.device)  # spheres a carrying checker ignores

    def centers(self, q: torch.Tensor, finger: float = 0.04, att_centers_hand: torch.Tensor | None = None
                ) -> torch.Tensor:
        """Sphere centres (..., 77 [+ M], 3) of configurations ``q`` (..., 7); a carried
        object's ``att_centers_hand`` (M, 3), or (N, M, 3) with ``q`` (N, ..., 7), follow the hand."""
        shape = q.shape[:-1]
        q = q.reshape(-1, 7).to(self.device, self.dtype)
        f = torch.full((len(q), 2), float(finger), device=self.device, dtype=self.dtype)
        poses = self.fk.forward(torch.cat([q, f], 1))
        T = torch.stack([poses[l] for l in self.links], 1)[:, self.link_of]
        arm = torch.einsum("bsij,sj->bsi", T[..., :3, :3], self.centers_link) + T[..., :3, 3]
        if att_centers_hand is None:
            return arm.reshape(*shape, -1, 3)
        H = poses["panda_hand"].reshape(*shape, 4, 4)
        a = att_centers_hand.to(self.device, self.dtype)
        if a.dim() == 2:
            att = torch.einsum("...ij,mj->...mi", H[..., :3, :3], a) + H[..., None, :3, 3]
        else:  # one object per leading row
            Hf = H.reshape(a.shape[0], -1, 4, 4)
            att = (torch.einsum("nbij,nmj->nbmi", Hf[..., :3, :3], a) + Hf[..., None, :3, 3]).reshape(*shape, -1, 3)
        return torch.cat([arm.reshape(*shape, -1, 3), att], dim=-2)


def file_sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_checkpoint(model: SceneCollisionNet, path, extra: dict | None = None) -> None:
    """fp16 weights + config, written atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().half() if v.is_floating_point() else v.cpu() for k, v in model.state_dict().items()}
    tmp = path.with_name(path.name + ".tmp")
    torch.save({"state_dict": state, "config": asdict(model.config), "decision_margin": float(model.decision_margin),
                **(extra or {})}, tmp)
    tmp.replace(path)


@functools.lru_cache(maxsize=4)
def load_collision_net(path: str | None = None, device: str = "cpu") -> SceneCollisionNet:
    """The trained network (strict load, eval mode), cached per process. A missing
    checkpoint is an error that says how to make one."""
    p = packed_or_plain(Path(path) if path else checkpoint_path())
    if not p.is_file():
        raise FileNotFoundError(
            f"no scene-collision network checkpoint at {p}: make one with baselines/mppi_collision/labels.py and "
            "baselines/mppi_collision/train.py --export (docs/planning.md, 'MPPI'), or plan with the distance "
            "fields instead: method ga-mesh-mppi, SolveConfig(mppi_cost='distance') or MppiConfig(cost='distance')")
    saved = torch_load(p, map_location="cpu", weights_only=True)
    cfg = dict(saved.get("config", {}))
    model = SceneCollisionNet(NetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()}))
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in saved["state_dict"].items()},
                          strict=True)
    model.decision_margin = float(saved.get("decision_margin", 0.0))
    return model.eval().to(device)


__all__ = ["RobotSpheres", "GRID_BOUNDS", "GRID_RESOLUTION", "GRID_SHAPE", "NetConfig", "SceneCollisionNet", "TAU", "checkpoint_path",
           "load_collision_net", "save_checkpoint", "scene_grid"]
