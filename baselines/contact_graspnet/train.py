"""Train Contact-GraspNet on FetchBench-MS's own train-split objects and verified grasps.

One readable file in the style of CleanRL / ManiSkill's baselines: the arguments are the
dataclass below (tyro flags), then data, model, losses, loop. The network is the package's
(``fetchbench_ms.grasping.network.ContactGraspNet``); only training lives here.

Data (made once per run folder, cached in ``<run>/data.npz`` with its hash): synthetic
single-view clouds of 1-3 train-split objects on a table. Each view places the objects in
random stable poses and yaws, samples their convex parts' surfaces and a table patch,
and keeps what a pinhole camera (320x240, 70 deg horizontal FOV, 0.6-1.2 m away, 20-70 deg
elevation) sees first along each pixel ray (a z-buffer "render"), in a world frame with z
up. Labels come from the objects' physics-verified grasps (fetchbench_ms.grasps): each
grasp's two finger contacts (TCP +- width/2 along the closing axis); a cloud point within
5 mm of a contact is positive and carries that grasp in CGN's frame (baseline from that
contact to the other finger, approach, width).

Losses (the original's): confidence BCE over the 512 hardest of the 2048 contact points;
ADD-S on gripper control points (min over the two finger-symmetric labels) for positive
points, weighted by the predicted confidence; width L1 for positive points.

    # the H100 run: fine-tunes the pretrained weights; each call stops at --time-limit with a
    # checkpoint and the same command resumes it (the run folder must survive: /tmp while the
    # machine stays warm); the last call validates and exports
    python baselines/contact_graspnet/train.py --run /tmp/cgn-ours --device cuda --workers 16 \
        --views 2000 --steps 1500 --batch-size 16 --init pretrained --time-limit 480 --export
    # a CPU smoke run: tiny network, few points
    python baselines/contact_graspnet/train.py --run /tmp/cgn-smoke --tiny --views 8 --steps 5

``--export`` writes ``assets/checkpoints/cgn_ours.pt`` (fp16 state dict + config) and
``cgn_ours.json`` (command, data hash, steps, final figures) when the last step is done.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from fetchbench_ms.grasping.network import GRIPPER_DEPTH, MAX_WIDTH, CGNConfig, ContactGraspNet
from fetchbench_ms.grasping.pointops import farthest_point_sample, gather


@dataclass
class Args:
    run: str = "runs/cgn/ours"  # run folder: log, data cache, checkpoint (re-running resumes)
    device: str = "cuda" if torch.cuda.is_available() else "cpu"
    seed: int = 0
    views: int = 4000  # synthetic training views
    val_views: int = 64  # views of test-split objects, for the validation figures
    objects_per_view: tuple[int, int] = (1, 3)
    num_points: int = 20000  # points per view fed to the network
    steps: int = 6000
    batch_size: int = 16
    lr: float = 1e-3
    lr_final: float = 1e-5  # cosine decay to this
    init: str = "scratch"  # "scratch" or "pretrained" (fine-tune the cgn-pytorch weights)
    time_limit: float = 0.0  # s; > 0: checkpoint and stop after this long (re-run to resume)
    log_every: int = 50
    ckpt_every: int = 500
    conf_topk: int = 512
    adds_weight: float = 10.0
    width_weight: float = 1.0
    positive_radius: float = 0.005  # m, cloud point to finger contact
    tiny: bool = False  # a small network and 1024 points: for CPU tests
    export: bool = False  # write assets/checkpoints/cgn_ours.{pt,json} when done
    workers: int = 0  # data-generation processes (0: all cores)


TINY = dict(centers=(256, 64, 16))
CAMERA = dict(width=320, height=240, hfov_deg=70.0)
# Control points of the gripper in CGN's frame (fingers along x): base, palm, finger bases, finger tips.
CONTROL_POINTS = np.array([[0, 0, 0], [0, 0, 0.0584], [0.04, 0, 0.0584], [-0.04, 0, 0.0584],
                           [0.04, 0, GRIPPER_DEPTH], [-0.04, 0, GRIPPER_DEPTH]], dtype=np.float32)


# ----------------------------------------------------------------------------- data
def _yaw(angle: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """T_world_camera, OpenCV axes (z forward, y down)."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = eye
    return T


def zbuffer_visible(points: np.ndarray, T_world_camera: np.ndarray) -> np.ndarray:
    """Indices of the points a pinhole camera sees first along each pixel ray."""
    w, h = CAMERA["width"], CAMERA["height"]
    f = (w / 2) / np.tan(np.radians(CAMERA["hfov_deg"]) / 2)
    p = (points - T_world_camera[:3, 3]) @ T_world_camera[:3, :3]
    front = p[:, 2] > 0.1
    u = np.floor(f * p[:, 0] / np.maximum(p[:, 2], 1e-6) + w / 2).astype(np.int64)
    v = np.floor(f * p[:, 1] / np.maximum(p[:, 2], 1e-6) + h / 2).astype(np.int64)
    ok = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    idx = np.flatnonzero(ok)
    pixel = v[idx] * w + u[idx]
    order = np.lexsort((p[idx, 2], pixel))  # by pixel, nearest first
    first = np.ones(len(order), dtype=bool)
    first[1:] = pixel[order][1:] != pixel[order][:-1]
    return idx[order][first]


def make_view(object_ids: list[str], rng: np.random.Generator, num_points: int, radius: float) -> dict:
    """One labelled view (see the module docstring): points (num_points, 3) float32, z up,
    mean-centred; per point: positive (bool), grasp (4, 4) CGN-frame label, width."""
    from fetchbench_ms.grasps import load_grasps
    from fetchbench_ms.tasks.objects import load_object

    import trimesh

    clouds, owners, contacts, labels, widths = [], [], [], [], []
    placed = []
    for k, object_id in enumerate(object_ids):
        asset = load_object(object_id)
        probs = np.asarray(asset.stable_probs, dtype=np.float64)
        T_support = asset.stable_poses[rng.choice(len(probs), p=probs / probs.sum())]
        for _ in range(20):  # a spot away from the objects already placed
            xy = rng.uniform(-0.15, 0.15, 2)
            if all(np.linalg.norm(xy - q) > 0.5 * (r + np.max(asset.extents)) for q, r in placed):
                break
        placed.append((xy, np.max(asset.extents)))
        T = _yaw(rng.uniform(0, 2 * np.pi)) @ T_support
        T[:2, 3] += xy
        mesh = trimesh.util.concatenate(list(asset.convex_parts))
        surface, _ = trimesh.sample.sample_surface(mesh, 6000, seed=int(rng.integers(2**31)))
        surface = surface @ T[:3, :3].T + T[:3, 3]
        clouds.append(surface)
        owners.append(np.full(len(surface), k))
        grasps = load_grasps(object_id).successful
        T_world_hand = T[None] @ grasps.T_object_hand
        tcp = T_world_hand[:, :3, 3] + GRIPPER_DEPTH * T_world_hand[:, :3, 2]
        y = T_world_hand[:, :3, 1]
        w = np.asarray(grasps.width, dtype=np.float64)
        # contact on the +y finger: baseline -y (hand = cgn @ T_CGN_HAND, hand y = -cgn x);
        # on the -y finger: the same grasp turned half about z (baseline +y).
        flip = _yaw(np.pi)
        to_cgn = np.linalg.inv(np.array([[0.0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]))
        for sign, T_extra in ((1.0, np.eye(4)), (-1.0, flip)):
            contacts.append(tcp + sign * 0.5 * w[:, None] * y)
            labels.append(T_world_hand @ to_cgn @ T_extra)
            widths.append(w)
    table = np.c_[rng.uniform(-0.35, 0.35, (20000, 2)), np.zeros(20000)]
    points = np.concatenate(clouds + [table])
    owner = np.concatenate(owners + [np.full(len(table), -1)])
    azimuth, elevation = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(20, 70))
    distance = rng.uniform(0.6, 1.2)
    eye = distance * np.array([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation), np.sin(elevation)])
    seen = zbuffer_visible(points, _look_at(eye, np.array([0.0, 0.0, 0.05])))
    pick = seen[rng.choice(len(seen), size=num_points, replace=len(seen) < num_points)]
    points, owner = points[pick], owner[pick]
    contacts, labels, widths = np.concatenate(contacts), np.concatenate(labels), np.concatenate(widths)
    from scipy.spatial import cKDTree

    distance_to_contact, nearest = cKDTree(contacts).query(points)
    positive = (distance_to_contact < radius) & (owner >= 0)
    mean = points.mean(0)
    grasp = labels[nearest].astype(np.float32)
    grasp[:, :3, 3] -= mean
    return {"points": (points - mean).astype(np.float32), "positive": positive,
            "grasp": np.where(positive[:, None, None], grasp, 0).astype(np.float32),
            "width": np.where(positive, widths[nearest], 0).astype(np.float32)}


def _view_job(job):
    ids, seed, num_points, radius = job
    return make_view(ids, np.random.default_rng(seed), num_points, radius)


def build_views(split: str, count: int, args: Args, seed: int) -> dict:
    from fetchbench_ms.grasps import objects_with_grasps
    from fetchbench_ms.tasks.objects import object_ids

    kept = set(objects_with_grasps())
    ids = [i for i in object_ids(split) if i in kept]
    rng = np.random.default_rng(seed)
    lo, hi = args.objects_per_view
    jobs = [(list(rng.choice(ids, size=int(rng.integers(lo, hi + 1)), replace=False)), int(rng.integers(2**31)),
             args.num_points, args.positive_radius) for _ in range(count)]
    workers = args.workers or os.cpu_count() or 1
    if workers > 1 and count > 1:
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(workers) as pool:
            views = pool.map(_view_job, jobs, chunksize=max(1, count // (4 * workers)))
    else:
        views = [_view_job(j) for j in jobs]
    data = {k: np.stack([v[k] for v in views]) for k in views[0]}
    # compact storage (20k points x thousands of views): the label frames' top 3 rows and the widths in float16
    data["grasp"] = data["grasp"][:, :, :3, :].astype(np.float16)
    data["width"] = data["width"].astype(np.float16)
    return data


def load_or_build_data(args: Args, run: Path, log) -> tuple[dict, dict, str]:
    """(train, val, data hash), cached in the run folder."""
    path = run / "data.npz"
    key = json.dumps({k: getattr(args, k) for k in ("seed", "views", "val_views", "objects_per_view", "num_points",
                                                     "positive_radius")}, sort_keys=True)
    if path.is_file():
        data = dict(np.load(path))
        if str(data.pop("key")) == key:
            log(f"data: {path} (cached)")
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            return ({k[6:]: v for k, v in data.items() if k.startswith("train_")},
                    {k[4:]: v for k, v in data.items() if k.startswith("val_")}, digest)
    t = time.perf_counter()
    train = build_views("train", args.views, args, args.seed)
    val = build_views("test", args.val_views, args, args.seed + 1)
    np.savez(path, key=key, **{f"train_{k}": v for k, v in train.items()}, **{f"val_{k}": v for k, v in val.items()})
    log(f"data: {args.views} train / {args.val_views} val views in {time.perf_counter() - t:.0f} s, "
        f"{train['positive'].mean():.3f} of points positive")
    return train, val, hashlib.sha256(path.read_bytes()).hexdigest()


# ----------------------------------------------------------------------------- losses
def control_points(T: torch.Tensor, width: torch.Tensor | None = None) -> torch.Tensor:
    """[..., 6, 3] gripper control points of frames [..., 4, 4] (fingers at +-width/2 if given)."""
    cp = torch.as_tensor(CONTROL_POINTS, device=T.device).expand(*T.shape[:-2], -1, -1).clone()
    if width is not None:
        half = (0.5 * width.clamp(0, MAX_WIDTH))[..., None]
        cp[..., 2:, 0] = torch.sign(cp[..., 2:, 0]) * half
    return cp @ T[..., :3, :3].transpose(-1, -2) + T[..., None, :3, 3]


def losses(out: dict, batch: dict, index: torch.Tensor, args: Args) -> dict:
    positive = gather(batch["positive"][..., None].float(), index)[..., 0] > 0.5  # [B, M]
    label_T = gather(batch["grasp"].flatten(2), index).unflatten(-1, (4, 4))
    label_w = gather(batch["width"][..., None], index)[..., 0]
    bce = torch.nn.functional.binary_cross_entropy_with_logits(out["logits"], positive.float(), reduction="none")
    conf = bce.topk(min(args.conf_topk, bce.shape[1]), dim=1).values.mean()
    pred_cp = control_points(out["T_grasp"], out["width"])
    label_cp = control_points(label_T, label_w)
    flipped = control_points(label_T @ torch.diag(torch.tensor([-1.0, -1, 1, 1], device=label_T.device)), label_w)
    adds = torch.minimum((pred_cp - label_cp).norm(dim=-1).mean(-1), (pred_cp - flipped).norm(dim=-1).mean(-1))
    score = torch.sigmoid(out["logits"]).detach()
    n_pos = positive.sum().clamp(min=1)
    adds = (adds * score * positive).sum() / n_pos
    width = ((out["raw_width"] - label_w).abs() * positive).sum() / n_pos
    total = conf + args.adds_weight * adds + args.width_weight * width
    # precision of the 10 best-scored contacts: how often they are labelled positive
    top = out["logits"].topk(min(10, positive.shape[1]), dim=1).indices
    precision = positive.gather(1, top).float().mean()
    return {"loss": total, "conf": conf, "adds": adds, "width": width, "top10_positive": precision}


# ----------------------------------------------------------------------------- training
def main(args: Args) -> dict:
    run = Path(args.run)
    run.mkdir(parents=True, exist_ok=True)
    log_file = open(run / "log.txt", "a")

    def log(message: str) -> None:
        line = f"[{time.strftime('%H:%M:%S')}] {message}"
        print(line, flush=True)
        log_file.write(line + "\n")
        log_file.flush()

    t_start = time.perf_counter()
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    if args.tiny:
        args = dataclasses.replace(args, num_points=min(args.num_points, 1024))
    train, val, data_hash = load_or_build_data(args, run, log)
    config = CGNConfig(**TINY) if args.tiny else CGNConfig()
    model = ContactGraspNet(config).to(args.device)
    if args.init == "pretrained" and not args.tiny:
        from fetchbench_ms.grasping.predict import load_model

        model.load_state_dict(load_model("pretrained").state_dict())
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=args.steps, eta_min=args.lr_final)
    step, ckpt = 0, run / "checkpoint.pt"
    if ckpt.is_file():
        saved = torch.load(ckpt, map_location=args.device, weights_only=False)
        model.load_state_dict(saved["model"])
        optimizer.load_state_dict(saved["optimizer"])
        schedule.load_state_dict(saved["schedule"])
        step = saved["step"]
        rng = saved["rng"]
        log(f"resumed at step {step}")

    def to_device(data: dict, rows) -> dict:
        out = {k: torch.as_tensor(v[rows], device=args.device) for k, v in data.items()}
        grasp = out["grasp"].float()  # [B, N, 3, 4] -> [B, N, 4, 4]
        bottom = torch.tensor([0.0, 0, 0, 1], device=args.device).expand(*grasp.shape[:2], 1, 4)
        out["grasp"], out["width"] = torch.cat([grasp, bottom], -2), out["width"].float()
        return out

    def save() -> None:
        torch.save({"model": model.state_dict(), "optimizer": optimizer.state_dict(), "schedule": schedule.state_dict(),
                    "step": step, "rng": rng, "args": dataclasses.asdict(args), "data_sha256": data_hash}, ckpt)

    @torch.no_grad()
    def validate() -> dict:
        model.eval()
        sums: dict = {}
        for s in range(0, len(val["points"]), args.batch_size):
            batch = to_device(val, slice(s, s + args.batch_size))
            index = farthest_point_sample(batch["points"], config.centers[0])
            for k, v in losses(model(batch["points"], index), batch, index, args).items():
                sums[k] = sums.get(k, 0.0) + float(v) * len(batch["points"])
        model.train()
        return {k: round(v / len(val["points"]), 5) for k, v in sums.items()}

    model.train()
    log(f"training from step {step} to {args.steps} on {args.device} ({sum(p.numel() for p in model.parameters())} "
        f"parameters, {len(train['points'])} views, data {data_hash[:12]})")
    history = []
    while step < args.steps:
        rows = rng.choice(len(train["points"]), size=min(args.batch_size, len(train["points"])), replace=False)
        batch = to_device(train, rows)
        # augmentation: a random yaw about z (the clouds are z up, as at inference)
        angle = torch.as_tensor(rng.uniform(0, 2 * np.pi, len(rows)), device=args.device, dtype=torch.float32)
        R = torch.zeros(len(rows), 4, 4, device=args.device)
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = angle.cos(), -angle.sin(), angle.sin(), angle.cos()
        R[:, 2, 2] = R[:, 3, 3] = 1.0
        batch["points"] = batch["points"] @ R[:, :3, :3].transpose(1, 2)
        batch["grasp"] = R[:, None] @ batch["grasp"]
        index = farthest_point_sample(batch["points"], config.centers[0])
        parts = losses(model(batch["points"], index), batch, index, args)
        optimizer.zero_grad(set_to_none=True)
        parts["loss"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        schedule.step()
        step += 1
        history.append(float(parts["loss"].detach()))
        if step % args.log_every == 0 or step == args.steps:
            log(f"step {step} " + " ".join(f"{k} {float(v.detach()):.4f}" for k, v in parts.items())
                + f" lr {schedule.get_last_lr()[0]:.2e}")
        if step % args.ckpt_every == 0:
            save()
        if args.time_limit and time.perf_counter() - t_start > args.time_limit and step < args.steps:
            save()
            log(f"time limit: checkpoint at step {step}; run again to resume")
            return {"step": step, "done": False, "losses": history}
    save()
    figures = validate()
    log(f"validation (test-split objects): {figures}")
    if args.export:
        export(model, config, args, data_hash, step, figures, log)
    return {"step": step, "done": True, "losses": history, "val": figures}


def export(model, config, args, data_hash, step, figures, log) -> None:
    from fetchbench_ms.grasping.predict import ours_checkpoint

    path = ours_checkpoint()
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: (v.half() if v.is_floating_point() else v) for k, v in model.state_dict().items()}
    torch.save({"state_dict": state, "config": dataclasses.asdict(config)}, path)
    meta = {"command": " ".join(["python", *sys.argv]), "data_sha256": data_hash, "steps": step,
            "args": dataclasses.asdict(args), "val": figures,
            "checkpoint_sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    path.with_suffix(".json").write_text(json.dumps(meta, indent=1) + "\n")
    log(f"exported {path} ({path.stat().st_size / 1e6:.1f} MB)")


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))
