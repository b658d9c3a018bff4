"""Train Contact-GraspNet on FetchBench-MS's own train-split objects and verified grasps.

One readable file in the style of CleanRL / ManiSkill's baselines: the arguments are the
dataclass below (tyro flags), then data, model, losses, loop. The network is the package's
(``fetchbench_ms.grasp_prediction.network.ContactGraspNet``); only training lives here.

Objects. Only train-split objects with verified grasps are used. A fixed, hash-based 5 %
of them (``holdout``: sha256 of the object id) is held out: the training views never show
them, and the validation views show only them. The validation figures (losses and the
top-10 precision on those views) are what a run reports and what hyper-parameters may be
chosen by. Test-split objects are never read here; their grasp quality is reported
separately by ``scripts/bench/bench_cgn.py quality`` (docs/grasping.md), and not used to choose
anything.

Data (made once per run folder, cached in ``<run>/data.npz``; the hash of its arrays goes
into the checkpoint): synthetic clouds of 1-3 objects on a table, made the way the network's
input is made at inference. Each scene places the objects in random stable poses and yaws
and samples their convex parts' surfaces and a table patch densely (1.5 mm); each of its
``--views-per-scene`` views fuses what two pinhole cameras (320x240, 70 deg horizontal FOV,
0.6-1.2 m away, 20-70 deg elevation, random azimuths) see first along each pixel ray (a
z-buffer "render"), world frame, z up, then crops the cube about one seen object and draws
20k points from it with ``predict.region_index`` (inference's own crop), and mean-centres
them. (The first run's views, a whole 0.7 m table seen by one camera, 3x sparser, 5 % object
points, were far from what the network sees at inference: the pretrained logits reached
+-1e4 on them and the first steps were spent on that.) Labels come from the objects'
physics-verified grasps (fetchbench_ms.grasp_labels) that are collision-free in the scene
(``collision_free``: the open hand above the table and out of the other objects; verified on
the object alone, most of them put the palm through the table): each grasp's two finger
contacts (TCP +- width/2 along the closing axis); a cloud point within 5 mm of a contact is
positive and carries that grasp in CGN's frame (baseline from that contact to the other
finger, approach into the object, width the finger gap: the original's convention,
docs/grasping.md "Labels"). Only the positive points' labels are stored.

Losses (the original's): confidence BCE over the 512 hardest of the 2048 contact points;
ADD-S on gripper control points (min over the two finger-symmetric labels) for positive
points, weighted by the predicted confidence; width L1 for positive points.

    # the H100 run (docs/grasping-training.md): fine-tunes the pretrained
    # weights; --train-seconds fixes --steps from the measured step time at the start, each
    # call stops at --time-limit with a checkpoint and the same command resumes it (the run
    # folder must survive between calls); the last call validates and exports
    python baselines/contact_graspnet/train.py --run /tmp/cgn-ours-v3 --workers 14 --train-seconds 900 \
        --time-limit 540 --export --export-dir runs/cgn/export
    # views of train tasks through their own cameras (task_views.py) mixed in, checkpoints
    # chosen on views of val tasks, data-parallel over 4 GPUs (torch DDP; --batch-size per
    # process; the run folder spelled --run-dir under torchrun)
    torchrun --standalone --nproc-per-node 4 baselines/contact_graspnet/train.py --run-dir /tmp/cgn-ours-v4 \
        --task-views /data/cgn/train --val-task-views /data/cgn/val --val-every 250 --export --export-dir runs/cgn/export
    # a CPU smoke run: tiny network, few points
    python baselines/contact_graspnet/train.py --run /tmp/cgn-smoke --tiny --views 8 --val-views 2 --steps 5

``--export`` writes ``cgn_ours.pt`` (fp16 state dict + config, what ``--grasp-model ours``
loads from ``assets/checkpoints/``), ``cgn_ours.json`` (the one command that retrains it,
data hash, steps, wall times, validation figures) and ``cgn_ours.log`` (the training log)
into ``--export-dir`` once the last step is done; a call stopped by ``--time-limit`` copies
the log there too.
"""
from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import math
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import numpy as np
import torch
import tyro

from fetchbench_ms.grasp_prediction.network import GRIPPER_DEPTH, MAX_WIDTH, CGNConfig, ContactGraspNet
from fetchbench_ms.geometry.pointops import farthest_point_sample, fps_backend, gather
from fetchbench_ms.utils.workers import one_thread_per_spawned_worker

DATA_VERSION = 3  # bump when make_scene / render_view change what a seed produces


RUN_HELP = ("run folder: log, data cache, checkpoint (re-running resumes); spelled --run-dir under torchrun, whose "
            "parser takes --run for its --run-path")


@dataclass
class Args:
    run: Annotated[str, tyro.conf.arg(aliases=("--run-dir",), help=RUN_HELP)] = "runs/cgn/ours"
    device: str = "cuda" if torch.cuda.is_available() else "cpu"
    seed: int = 0
    views: int = 6000  # synthetic training views (of held-in train-split objects)
    views_per_scene: int = 2  # camera views rendered of each random arrangement
    val_views: int = 128  # views of the held-out train-split objects, for the validation figures
    val_fraction: float = 0.05  # of the train-split objects held out for validation (by id hash)
    objects_per_view: tuple[int, int] = (1, 3)
    num_points: int = 20000  # points per view fed to the network
    steps: int = 1500
    train_seconds: float = 0.0  # > 0: set --steps from the step time measured over the first steps
    batch_size: int = 16
    lr: float = 1e-4
    lr_final: float = 1e-6  # cosine decay to this after a linear warm-up
    warmup_steps: int = 50
    # "scratch", "pretrained" (fine-tune the cgn-pytorch weights), "ours" (go on from the shipped
    # assets/checkpoints/cgn_ours.pt) or the path of an exported cgn_ours.pt (packed or plain)
    init: str = "pretrained"
    # fine-tuning keeps the pretrained BatchNorm running statistics (those layers stay in eval
    # mode; their scales and shifts still learn): statistics re-estimated on our views halve
    # the pretrained model's pose agreement with no weight changed (docs/grasping.md)
    freeze_bn: bool = True
    time_limit: float = 0.0  # s; > 0: checkpoint and stop after this long (re-run to resume)
    log_every: int = 50
    ckpt_every: int = 200
    conf_topk: int = 512
    adds_weight: float = 10.0
    width_weight: float = 1.0
    positive_radius: float = 0.005  # m, cloud point to finger contact
    tiny: bool = False  # a small network (no pretrained init) and 1024 points: for CPU tests
    export: bool = False  # write cgn_ours.{pt,json,log} into --export-dir when done
    export_dir: str = "assets/checkpoints"  # where --export writes (the repo's, or a folder to copy from)
    workers: int = 0  # data-generation processes (0: all cores)
    # views of train-suite tasks through their own cameras (task_views.py folders, each with
    # its manifest.json), trained on alongside the --views table-top ones (--views 0: alone)
    task_views: tuple[str, ...] = ()
    # views of val-suite tasks (task_views.py --suite val): every --val-every steps the
    # checkpoint is judged on them, and the best one is what --export ships
    val_task_views: str = ""
    val_every: int = 0  # steps between validations (0: only at the end)


# Flags that change what is trained (the retraining command names them all); the others
# (run folder, device, workers, time limits, export) change only where and how fast.
TRAINING_FLAGS = ("seed", "views", "views_per_scene", "val_views", "val_fraction", "objects_per_view", "num_points",
                  "steps", "batch_size", "lr", "lr_final", "warmup_steps", "init", "freeze_bn", "conf_topk",
                  "adds_weight", "width_weight", "positive_radius", "tiny", "task_views", "val_task_views",
                  "val_every")
DATA_FLAGS = ("seed", "views", "views_per_scene", "val_views", "val_fraction", "objects_per_view", "num_points",
              "positive_radius")
# --tiny: fewer centres and narrow layers, for CPU tests (seconds per step, not minutes)
TINY = dict(centers=(128, 32, 8), mlps=(((8, 16),) * 3, ((16, 16),) * 3, ((16, 16),) * 3), global_mlp=(16,),
            fp_mlps=((16,), (16,), (16,)))
CAMERA = dict(width=320, height=240, hfov_deg=70.0)
CAMERAS = 2  # fused per view, as the benchmark's two cameras
SURFACE_SPACING = 0.0015  # m, mean spacing of the surface samples that the cameras see
TABLE_HALF = 0.4  # m, half side of the table patch (a 0.6 m region about an object at 0.15 m fits)
# Control points of the gripper in CGN's frame (fingers along x): base, palm, finger bases, finger tips.
CONTROL_POINTS = np.array([[0, 0, 0], [0, 0, 0.0584], [0.04, 0, 0.0584], [-0.04, 0, 0.0584],
                           [0.04, 0, GRIPPER_DEPTH], [-0.04, 0, GRIPPER_DEPTH]], dtype=np.float32)
# panda_hand = cgn @ T_CGN_HAND (fetchbench_ms.grasp_prediction.predict), so cgn = hand @ inv(T_CGN_HAND)
T_HAND_CGN = np.array([[0.0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])


# ----------------------------------------------------------------------------- objects
def holdout(object_id: str, fraction: float) -> bool:
    """Whether a train-split object is held out for validation: a fixed hash of its id, so the
    split is the same on every machine and for every seed."""
    return int(hashlib.sha256(object_id.encode()).hexdigest()[:8], 16) < fraction * 16**8


@functools.lru_cache(maxsize=None)
def train_val_objects(fraction: float) -> tuple[list[str], list[str]]:
    """(training, validation) ids: train-split objects with verified grasps, split by ``holdout``.
    A test-split object among them is refused (``tasks.splits.TestSplitRefused``)."""
    from fetchbench_ms.grasp_labels import objects_with_grasps
    from fetchbench_ms.objects.loading import object_ids
    from fetchbench_ms.tasks.splits import refuse_test_objects

    kept = set(objects_with_grasps())
    ids = [i for i in object_ids("train") if i in kept]
    refuse_test_objects(ids, "Contact-GraspNet training data")
    val = [i for i in ids if holdout(i, fraction)]
    train = [i for i in ids if not holdout(i, fraction)]
    if not train or not val:
        raise ValueError(f"--val-fraction {fraction} leaves {len(train)} training and {len(val)} validation objects")
    return train, val


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


@functools.lru_cache(maxsize=1)
def hand_points() -> np.ndarray:
    """Points on the open hand's collision meshes in the ``panda_hand`` frame: their corners and
    surface samples (about 2 mm apart on the fingers), what the scene-collision test checks."""
    import trimesh

    from fetchbench_ms.grasp_labels.hand import open_hand_mesh

    mesh = open_hand_mesh()
    surface, _ = trimesh.sample.sample_surface(mesh, 2000, seed=0)
    return np.concatenate([np.asarray(mesh.vertices), surface])


def collision_free(T_world_hand: np.ndarray, obstacles: list) -> np.ndarray:
    """(N,) whether the open hand at each pose ((N, 4, 4), world frame, table top at z = 0)
    stays above the table and out of every obstacle (``ConvexUnion`` of another object's
    convex parts, world frame). The annotations were verified on the object alone; once it
    rests on a table beside others, most of them put the palm through the table (over 80 %
    for flat objects): the pretrained network was trained on scene-consistent labels (the
    original's ACRONYM scenes drop grasps that collide), so ours must be too."""
    local = hand_points()
    points = np.einsum("nij,kj->nki", T_world_hand[:, :3, :3], local) + T_world_hand[:, None, :3, 3]
    free = points[..., 2].min(axis=1) > 0.0
    flat = points.reshape(-1, 3)
    for union, (lo, hi) in obstacles:
        near = np.flatnonzero(np.all((flat > lo) & (flat < hi), axis=1))  # only points in its box
        if len(near):
            inside = union.signed_distance_to_planes(flat[near]).min(axis=1) < -0.001
            hit = np.zeros(len(flat), dtype=bool)
            hit[near[inside]] = True
            free &= ~hit.reshape(points.shape[:2]).any(axis=1)
    return free


def finger_contacts(T_world_hand: np.ndarray, width: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The two finger contacts of each grasp ((N, 4, 4) panda_hand poses, (N,) widths) and the
    label each carries: (2N, 3) contacts, (2N, 4, 4) grasps in CGN's frame, (2N,) widths, the
    +y finger's contacts first. On the +y finger the baseline is -y (hand y = -cgn x); on the
    -y finger the label is the same grasp turned half about z (baseline +y)."""
    tcp = T_world_hand[:, :3, 3] + GRIPPER_DEPTH * T_world_hand[:, :3, 2]
    y = T_world_hand[:, :3, 1]
    contacts, labels = [], []
    for sign, T_extra in ((1.0, np.eye(4)), (-1.0, _yaw(np.pi))):
        contacts.append(tcp + sign * 0.5 * width[:, None] * y)
        labels.append(T_world_hand @ T_HAND_CGN @ T_extra)
    return np.concatenate(contacts).reshape(-1, 3), np.concatenate(labels).reshape(-1, 4, 4), np.concatenate([width, width])


def make_scene(object_ids: list[str], rng: np.random.Generator) -> dict:
    """1-3 objects on a table: surface points with their owner (-1: table), and the two finger
    contacts of every verified grasp that is collision-free in this scene (``collision_free``)
    with the grasp (in CGN's frame) that each contact carries."""
    import trimesh

    from fetchbench_ms.grasp_labels import load_grasps
    from fetchbench_ms.grasp_labels.sampler import ConvexUnion
    from fetchbench_ms.objects.loading import load_object

    clouds, owners, contacts, labels, widths, hands = [], [], [], [], [], []
    placed, poses, parts = [], [], []
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
        # dense enough that the camera's pixels, not the samples, set the spacing (as a render)
        count = int(np.clip(mesh.area / SURFACE_SPACING**2, 4000, 40000))
        surface, _ = trimesh.sample.sample_surface(mesh, count, seed=int(rng.integers(2**31)))
        clouds.append(surface @ T[:3, :3].T + T[:3, 3])
        owners.append(np.full(len(surface), k))
        poses.append(T)
        parts.append([p.copy().apply_transform(T) for p in asset.convex_parts])
    for k, object_id in enumerate(object_ids):
        others = [(ConvexUnion(tuple(parts[j])), (clouds[j].min(0) - 0.002, clouds[j].max(0) + 0.002))
                  for j in range(len(object_ids)) if j != k]
        grasps = load_grasps(object_id).successful
        T_world_hand = poses[k][None] @ grasps.T_object_hand
        keep = collision_free(T_world_hand, others)
        T_world_hand = T_world_hand[keep]
        w = np.asarray(grasps.width, dtype=np.float64)[keep]
        c, lab, wid = finger_contacts(T_world_hand, w)
        contacts.append(c)
        labels.append(lab)
        widths.append(wid)
        hands.append(np.concatenate([T_world_hand, T_world_hand]))
    count = int((2 * TABLE_HALF) ** 2 / SURFACE_SPACING**2)
    table = np.c_[rng.uniform(-TABLE_HALF, TABLE_HALF, (count, 2)), np.zeros(count)]
    contacts = np.concatenate(contacts)
    if len(contacts) == 0:  # no grasp survives the scene: nothing positive (a point far away)
        contacts, labels, widths, hands = np.full((1, 3), 1e3), [np.eye(4)[None]], [np.zeros(1)], [np.eye(4)[None]]
    # hands: the annotated panda_hand pose (world) each contact's label was made from
    return {"points": np.concatenate(clouds + [table]), "owner": np.concatenate(owners + [np.full(len(table), -1)]),
            "contacts": contacts, "labels": np.concatenate(labels), "widths": np.concatenate(widths),
            "hands": np.concatenate(hands), "T_world_object": np.stack(poses), "object_ids": list(object_ids)}


def render_view(scene: dict, rng: np.random.Generator, num_points: int, radius: float) -> dict:
    """One labelled view of a scene, made as the network's input is made at inference
    (fetchbench_ms.grasp_prediction.predict): what two cameras at random poses see (``CAMERAS``),
    fused, cropped to the cube about one object (``predict.region_index``: the same region
    size and the same draw of ``num_points``), mean-centred. Returns points (num_points, 3)
    float32, z up, and ``mean`` (taken out, scene frame); per point: positive (bool), grasp
    (4, 4) CGN-frame label, width, owner (object index in the scene, -1: table)."""
    from scipy.spatial import cKDTree

    from fetchbench_ms.grasp_prediction.predict import region_index

    seen = []
    for _ in range(CAMERAS):
        azimuth, elevation = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(20, 70))
        distance = rng.uniform(0.6, 1.2)
        eye = distance * np.array([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation),
                                   np.sin(elevation)])
        seen.append(zbuffer_visible(scene["points"], _look_at(eye, np.array([0.0, 0.0, 0.05]))))
    seen = np.unique(np.concatenate(seen))
    owner_seen = scene["owner"][seen]
    visible = np.unique(owner_seen[owner_seen >= 0])
    target = rng.choice(visible)  # the object whose region this view is (each scene has one seen)
    pick = seen[region_index(scene["points"][seen], owner_seen == target, num_points, rng)]
    points, owner = scene["points"][pick], scene["owner"][pick]
    distance_to_contact, nearest = cKDTree(scene["contacts"]).query(points)
    positive = (distance_to_contact < radius) & (owner >= 0)
    mean = points.mean(0)
    grasp = scene["labels"][nearest].astype(np.float32)
    grasp[:, :3, 3] -= mean
    return {"points": (points - mean).astype(np.float32), "positive": positive,
            "grasp": np.where(positive[:, None, None], grasp, 0).astype(np.float32),
            "width": np.where(positive, scene["widths"][nearest], 0).astype(np.float32), "owner": owner, "mean": mean}


def make_view(object_ids: list[str], rng: np.random.Generator, num_points: int, radius: float) -> dict:
    """One labelled view of a new scene of ``object_ids``."""
    return render_view(make_scene(object_ids, rng), rng, num_points, radius)


def _scene_job(job) -> list[dict]:
    """The views of one scene, their labels kept for the positive points only (about 2 %)."""
    ids, seed, cameras, num_points, radius = job
    rng = np.random.default_rng(seed)
    scene = make_scene(ids, rng)
    views = []
    for _ in range(cameras):
        view = render_view(scene, rng, num_points, radius)
        index = np.flatnonzero(view["positive"])
        views.append({"points": view["points"], "pos_index": index.astype(np.int32),
                      "pos_grasp": view["grasp"][index, :3, :].astype(np.float16),
                      "pos_width": view["width"][index].astype(np.float16)})
    return views


def build_views(ids: list[str], count: int, args: Args, seed: int, pool=None) -> dict:
    """``count`` views of random scenes of ``ids`` (made in ``pool`` if given): points
    [count, N, 3], and the positive points' labels concatenated (``pos_*``) with
    ``pos_offset`` [count + 1] marking each view's run."""
    if count == 0:
        return empty_views(args.num_points)
    rng = np.random.default_rng(seed)
    lo, hi = args.objects_per_view
    cameras = max(1, args.views_per_scene)
    jobs = [(list(rng.choice(ids, size=int(rng.integers(lo, hi + 1)), replace=False)), int(rng.integers(2**31)),
             min(cameras, count - s), args.num_points, args.positive_radius) for s in range(0, count, cameras)]
    if pool is not None:
        scenes = pool.map(_scene_job, jobs, chunksize=max(1, len(jobs) // 64))  # order kept: same data for any pool
    else:
        scenes = [_scene_job(j) for j in jobs]
    views = [v for scene in scenes for v in scene]
    counts = np.array([len(v["pos_index"]) for v in views])
    return {"points": np.stack([v["points"] for v in views]),
            "pos_offset": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            **{k: np.concatenate([v[k] for v in views]) for k in ("pos_index", "pos_grasp", "pos_width")}}


def empty_views(num_points: int) -> dict:
    return {"points": np.zeros((0, num_points, 3), np.float32), "pos_offset": np.zeros(1, np.int64),
            "pos_index": np.zeros(0, np.int32), "pos_grasp": np.zeros((0, 3, 4), np.float16),
            "pos_width": np.zeros(0, np.float16)}


def concat_views(parts: list[dict]) -> dict:
    """One set of views from several (``build_views``'s arrays), their label runs re-based."""
    offsets, base = [], 0
    for part in parts:
        offsets.append(part["pos_offset"][1:] + base)
        base += int(part["pos_offset"][-1])
    return {"points": np.concatenate([p["points"] for p in parts]),
            "pos_offset": np.concatenate([np.zeros(1, np.int64), *offsets]).astype(np.int64),
            **{k: np.concatenate([p[k] for p in parts]) for k in ("pos_index", "pos_grasp", "pos_width")}}


def load_task_views(folder: str, suite: str, num_points: int) -> tuple[dict, str]:
    """The views of a finished ``task_views.py`` folder of ``suite`` (every shard its manifest
    lists, each checked against its sha256) and the manifest's sha256."""
    from fetchbench_ms.tasks.splits import refuse_test_task_ids
    from fetchbench_ms.utils.io import sha256_file

    path = Path(folder)
    if not (path / "manifest.json").is_file():
        raise ValueError(f"{folder}: no manifest.json (task views unfinished or missing): run task_views.py into it")
    manifest = json.loads((path / "manifest.json").read_text())
    config = manifest["config"]
    if config["suite"] != suite or config["num_points"] != num_points:
        raise ValueError(f"{folder} holds views of suite {config['suite']!r} with {config['num_points']} points; "
                         f"expected suite {suite!r} with {num_points} points (--num-points)")
    parts, task_ids = [], set()
    for entry in manifest["shards"]:
        shard = path / entry["file"]
        if sha256_file(shard) != entry["sha256"]:
            raise ValueError(f"{shard}: its sha256 is not the manifest's: remake it (delete it, rerun task_views.py)")
        with np.load(shard) as z:
            parts.append({k: z[k] for k in ("points", "pos_offset", "pos_index", "pos_grasp", "pos_width")})
            task_ids.update(str(t) for t in z["task_id"])
    refuse_test_task_ids(sorted(task_ids), "Contact-GraspNet training")
    return concat_views(parts), manifest["sha256"]


@contextlib.contextmanager
def view_pool(workers: int):
    """A pool of ``workers`` processes of one thread each (BLAS / OpenMP would otherwise take
    every core in each), or None for ``workers`` <= 1 (views made in this process)."""
    if workers <= 1:
        yield None
        return
    import multiprocessing

    with one_thread_per_spawned_worker(), multiprocessing.get_context("spawn").Pool(workers) as pool:
        yield pool


def data_digest(arrays: dict) -> str:
    """sha256 of named arrays (names, dtypes, shapes, bytes): the same data gives the same hash,
    unlike the bytes of an .npz (its zip entries carry the time of writing)."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}:{a.dtype.str}:{a.shape};".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


def load_or_build_data(args: Args, run: Path, log) -> tuple[dict, dict, str]:
    """(train, val, data hash), cached in the run folder."""
    path = run / "data.npz"
    key = json.dumps({"version": DATA_VERSION, **{k: getattr(args, k) for k in DATA_FLAGS}}, sort_keys=True)
    if path.is_file():
        data = dict(np.load(path))
        if str(data.pop("key")) == key:
            log(f"data: {path} (cached)")
            return ({k[6:]: v for k, v in data.items() if k.startswith("train_")},
                    {k[4:]: v for k, v in data.items() if k.startswith("val_")}, data_digest(data))
    t = time.perf_counter()
    train_ids, val_ids = train_val_objects(args.val_fraction)
    workers = args.workers or os.cpu_count() or 1
    with view_pool(workers) as pool:
        train = build_views(train_ids, args.views, args, args.seed, pool)
        val = build_views(val_ids, args.val_views, args, args.seed + 1, pool)
    arrays = {**{f"train_{k}": v for k, v in train.items()}, **{f"val_{k}": v for k, v in val.items()}}
    tmp = path.with_name("data.tmp.npz")
    np.savez(tmp, key=key, **arrays)
    os.replace(tmp, path)
    seconds = time.perf_counter() - t
    log(f"data: {args.views} train views of {len(train_ids)} objects, {args.val_views} val views of {len(val_ids)} "
        f"held-out train-split objects, in {seconds:.0f} s ({seconds / (args.views + args.val_views):.3f} s per view "
        f"with {workers} workers); "
        f"{len(train['pos_index']) / max(1, np.prod(train['points'].shape[:2])):.3f} of training points positive")
    return train, val, data_digest(arrays)


def batch_to_device(data: dict, rows: np.ndarray, device: str) -> dict:
    """Views ``rows`` of ``data`` as dense tensors: points [B, N, 3], positive [B, N], grasp
    [B, N, 4, 4] (zeros but for positives), width [B, N]."""
    points = torch.as_tensor(data["points"][rows], device=device)
    B, N = points.shape[:2]
    spans = [np.arange(data["pos_offset"][r], data["pos_offset"][r + 1]) for r in rows]
    which = np.concatenate(spans).astype(np.int64)
    view = torch.as_tensor(np.repeat(np.arange(B), [len(s) for s in spans]), device=device)
    point = torch.as_tensor(data["pos_index"][which].astype(np.int64), device=device)
    positive = torch.zeros(B, N, dtype=torch.bool, device=device)
    positive[view, point] = True
    grasp = torch.zeros(B, N, 4, 4, device=device)
    grasp[..., 3, 3] = 1.0
    grasp[view, point, :3, :] = torch.as_tensor(data["pos_grasp"][which], device=device).float()
    width = torch.zeros(B, N, device=device)
    width[view, point] = torch.as_tensor(data["pos_width"][which], device=device).float()
    return {"points": points, "positive": positive, "grasp": grasp, "width": width}


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
    # the best-scored contact and the 10 best: how often they are labelled positive
    top = out["logits"].topk(min(10, positive.shape[1]), dim=1).indices
    hits = positive.gather(1, top).float()
    return {"loss": total, "conf": conf, "adds": adds, "width": width, "top1_positive": hits[:, 0].mean(),
            "top10_positive": hits.mean()}


def pose_agreement(out: dict, batch: dict, max_distance: float = 0.02, max_angle_deg: float = 30.0) -> dict:
    """How often the best-scored predicted grasps are verified ones: the fraction of the top-1
    and top-10 grasps (by score) whose TCP lies within ``max_distance`` of a labelled grasp of
    the view (a collision-free verified grasp with a finger contact in the cloud) and whose
    rotation is within ``max_angle_deg`` of it (the fingers are interchangeable). Unlike
    ``top10_positive`` (is the contact point right?) this asks whether the whole grasp is: a
    model that keeps the points but turns the hands scores low."""
    flip = torch.diag(torch.tensor([-1.0, -1, 1, 1], device=out["T_grasp"].device))
    top = out["logits"].topk(min(10, out["logits"].shape[1]), dim=1).indices
    agree = []
    for b in range(len(top)):
        labels = batch["grasp"][b][batch["positive"][b]]  # [P, 4, 4]
        pred = out["T_grasp"][b, top[b]]  # [10, 4, 4]
        if len(labels) == 0:
            agree.append(torch.zeros(len(pred), device=pred.device))
            continue
        tcp = lambda T: T[..., :3, 3] + GRIPPER_DEPTH * T[..., :3, 2]  # noqa: E731
        near = torch.cdist(tcp(pred), tcp(labels)) <= max_distance
        cos_max = math.cos(math.radians(max_angle_deg))
        aligned = torch.zeros_like(near)
        for L in (labels, labels @ flip):  # rotation angle via trace(R_pred^T R_label)
            trace = torch.einsum("pij,lij->pl", pred[:, :3, :3], L[:, :3, :3])
            aligned |= (trace - 1) / 2 >= cos_max
        agree.append((near & aligned).any(dim=1).float())
    agree = torch.stack(agree)
    return {"top1_pose_agree": agree[:, 0].mean(), "top10_pose_agree": agree.mean()}


# ----------------------------------------------------------------------------- training
def retrain_command(args: Args) -> str:
    """The one command that trains this checkpoint again (every flag that changes what is
    trained, with the steps fixed; --time-limit may be added to split it into calls)."""
    words = ["python", "baselines/contact_graspnet/train.py"]
    for name in TRAINING_FLAGS:
        value = getattr(args, name)
        flag = "--" + name.replace("_", "-")
        if isinstance(value, bool):
            words += [flag] if value else []
        elif value in ((), ""):  # an unset folder flag
            continue
        elif isinstance(value, tuple):
            words += [flag, *map(str, value)]
        else:
            words += [flag, str(value)]
    return " ".join(words + ["--export"])


def _atomic_save(obj, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def train_mode(model: torch.nn.Module, freeze_bn: bool) -> None:
    """``model.train()``, but with every BatchNorm in eval mode (its running statistics kept
    and used) when ``freeze_bn``."""
    model.train()
    if freeze_bn:
        for module in model.modules():
            if isinstance(module, torch.nn.modules.batchnorm._BatchNorm):
                module.eval()


def main(args: Args) -> dict:
    from fetchbench_ms.tasks.splits import cli_guard

    # The objects the views are made of: train-split only (before anything is written).
    cli_guard(train_val_objects, args.val_fraction)
    # data-parallel under torchrun (WORLD_SIZE > 1): every process trains on its own share of
    # each step's batch (--batch-size per process); process 0 alone logs, validates and saves
    world, rank = int(os.environ.get("WORLD_SIZE", "1")), int(os.environ.get("RANK", "0"))
    dist = None
    if world > 1:
        import torch.distributed as dist

        if args.device.startswith("cuda"):
            local = int(os.environ.get("LOCAL_RANK", "0"))
            torch.cuda.set_device(local)
            args = dataclasses.replace(args, device=f"cuda:{local}")
        import datetime

        # the others wait at a barrier while process 0 makes the data: allow it hours, not minutes
        dist.init_process_group("nccl" if args.device.startswith("cuda") else "gloo",
                                timeout=datetime.timedelta(hours=3))
    lead = rank == 0
    run = Path(args.run)
    run.mkdir(parents=True, exist_ok=True)
    log_file = open(run / "log.txt", "a") if lead else None

    def log(message: str) -> None:
        if not lead:
            return
        line = f"[{time.strftime('%H:%M:%S')}] {message}"
        print(line, flush=True)
        log_file.write(line + "\n")
        log_file.flush()

    t_start = time.perf_counter()
    if args.init not in ("scratch", "pretrained", "ours") and not Path(args.init).is_file() \
            and not Path(args.init + ".planes.xz").is_file():
        raise ValueError(f"--init {args.init!r}: valid: scratch, pretrained, ours, or an exported cgn_ours.pt file")
    log(f"call: {' '.join(sys.argv)}" + (f" ({world} processes, {dist.get_backend()})" if dist else ""))
    torch.manual_seed(args.seed)
    torch.set_num_threads(max(1, min(torch.get_num_threads(), args.workers or torch.get_num_threads())))
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = True
    rng = np.random.default_rng(args.seed)
    if args.tiny:
        args = dataclasses.replace(args, num_points=min(args.num_points, 1024))
    config = CGNConfig(**TINY) if args.tiny else CGNConfig()
    model = ContactGraspNet(config).to(args.device)
    net = model  # what the training step calls: the DDP wrapper when data-parallel
    if args.init == "pretrained" and not args.tiny:  # before the data: a missing package fails at once
        from fetchbench_ms.grasp_prediction.predict import load_model

        model.load_state_dict(load_model("pretrained").state_dict())
    elif args.init != "scratch":  # an exported checkpoint: its network's config, whatever --tiny says
        from fetchbench_ms.grasp_prediction.predict import load_checkpoint, ours_checkpoint

        model = load_checkpoint(ours_checkpoint() if args.init == "ours" else args.init).to(args.device)
        config = model.config
        net = model
    # (weights that go on from the pretrained ones, ours among them, keep its BatchNorm statistics)
    freeze_bn = args.freeze_bn and args.init != "scratch" and not (args.tiny and args.init == "pretrained")
    log(f"farthest-point sampling on {args.device}: {fps_backend(torch.device(args.device))}")
    if dist and not lead:
        dist.barrier()  # process 0 makes (or finds) the cached data first; the others read it
    train, val, data_hash = load_or_build_data(args, run, log)
    if dist and lead:
        dist.barrier()
    val_sets = {"table_top": val}
    if args.task_views or args.val_task_views:
        hashes = [data_hash]
        parts = [train]
        for folder in args.task_views:
            views, digest = load_task_views(folder, "train", args.num_points)
            parts.append(views)
            hashes.append(f"train:{digest}")
            log(f"task views: {len(views['points'])} from {folder} (manifest {digest[:12]})")
        train = concat_views(parts)
        if args.val_task_views:
            val_sets["tasks"], digest = load_task_views(args.val_task_views, "val", args.num_points)
            hashes.append(f"val:{digest}")
            log(f"val task views: {len(val_sets['tasks']['points'])} from {args.val_task_views} (manifest {digest[:12]})")
        data_hash = hashlib.sha256("|".join(hashes).encode()).hexdigest()
    if len(train["points"]) == 0:
        raise ValueError("no training views: give --views > 0 or --task-views folders")
    data_seconds = time.perf_counter() - t_start
    if dist:
        # set_abstract_final is in the state dict only so that the pretrained weights load
        # strictly; forward never uses it, and DDP waits for a gradient of every trained parameter
        model.set_abstract_final.requires_grad_(False)
        net = torch.nn.parallel.DistributedDataParallel(model, device_ids=[args.device] if args.device.startswith("cuda")
                                                        else None)
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr)
    # plan["steps"] is None while --train-seconds is still timing the first steps (all warm-up)
    plan = {"steps": None if args.train_seconds > 0 else args.steps, "train_seconds": 0.0, "val_init": None,
            "best": None}

    def lr_factor(s: int) -> float:
        if s < args.warmup_steps:
            return (s + 1) / args.warmup_steps
        total = plan["steps"] or max(args.steps, s + 1)
        progress = min(1.0, (s - args.warmup_steps) / max(1, total - args.warmup_steps))
        final = args.lr_final / args.lr
        return final + (1 - final) * 0.5 * (1 + math.cos(math.pi * progress))

    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, lr_factor)
    step, ckpt = 0, run / "checkpoint.pt"
    if ckpt.is_file():
        saved = torch.load(ckpt, map_location=args.device, weights_only=False)
        if saved["data_sha256"] != data_hash:
            raise ValueError(f"{ckpt} was trained on other data ({saved['data_sha256'][:12]}, now {data_hash[:12]}): "
                             "use a new --run folder for other data flags")
        changed = [k for k in TRAINING_FLAGS if k != "steps" and saved["args"].get(k) != getattr(args, k)]
        if changed:
            raise ValueError(f"{ckpt} was trained with other {', '.join('--' + k.replace('_', '-') for k in changed)}: "
                             "resume with the same flags, or use a new --run folder")
        model.load_state_dict(saved["model"])
        optimizer.load_state_dict(saved["optimizer"])
        schedule.load_state_dict(saved["schedule"])
        step, rng, plan = saved["step"], saved["rng"], saved["plan"]
        log(f"resumed at step {step} of {plan['steps']}")

    # The contact points (level-1 farthest-point samples) of every training view, once per call:
    # a yaw about z keeps all distances, so they hold under the augmentation, and the 2,048
    # small sequential steps of the sampling (launch-bound on a GPU) leave the training step.
    t = time.perf_counter()
    train_contacts = torch.cat([farthest_point_sample(torch.as_tensor(train["points"][s:s + 256], device=args.device),
                                                      config.centers[0]) for s in range(0, len(train["points"]), 256)])
    log(f"contact points of {len(train_contacts)} views in {time.perf_counter() - t:.1f} s")

    def save() -> None:
        if not lead:
            return
        _atomic_save({"model": model.state_dict(), "optimizer": optimizer.state_dict(), "schedule": schedule.state_dict(),
                      "step": step, "rng": rng, "plan": plan, "args": dataclasses.asdict(args), "data_sha256": data_hash},
                     ckpt)

    @torch.no_grad()
    def validate_set(views: dict) -> dict:
        model.eval()
        sums: dict = {}
        count = len(views["points"])
        for s in range(0, count, args.batch_size):
            batch = batch_to_device(views, np.arange(s, min(count, s + args.batch_size)), args.device)
            index = farthest_point_sample(batch["points"], config.centers[0])
            out = model(batch["points"], index)
            for k, v in {**losses(out, batch, index, args), **pose_agreement(out, batch)}.items():
                sums[k] = sums.get(k, 0.0) + float(v) * len(batch["points"])
        train_mode(model, freeze_bn)
        return {k: round(v / count, 5) for k, v in sums.items()}

    def validate() -> dict:
        """Figures per validation set: ``table_top`` (held-out train-split objects) and, with
        --val-task-views, ``tasks`` (val-suite tasks through their cameras)."""
        return {name: validate_set(views) for name, views in val_sets.items()}

    def consider(figures: dict) -> None:
        """Keep the weights if their selection score is the best so far (``best.pt``)."""
        score = selection_score(figures)
        if plan["best"] is None or score > plan["best"]["score"]:
            plan["best"] = {"step": step, "score": score, "val": figures}
            _atomic_save({"model": model.state_dict(), "step": step}, run / "best.pt")
            log(f"best so far at step {step}: selection score {score:.4f}")

    def sync() -> None:
        if args.device.startswith("cuda"):
            torch.cuda.synchronize()

    if lead and step == 0 and plan["val_init"] is None:
        plan["val_init"] = validate()
        log(f"validation at init ({args.init}; held-out train-split objects): {plan['val_init']}")
    train_mode(model, freeze_bn)
    log(f"training from step {step} to {'auto' if plan['steps'] is None else plan['steps']} on {args.device} "
        f"({sum(p.numel() for p in model.parameters())} parameters, {len(train['points'])} views, data {data_hash[:12]})")
    history = []
    timing = (step + 5, step + 25)  # steps timed for --train-seconds (after the first, slow ones)
    t_call = time.perf_counter()
    while plan["steps"] is None or step < plan["steps"]:
        if plan["steps"] is None and step == timing[0]:
            sync()
            t_timing = time.perf_counter()
        # one draw for all processes (the same rng in each), each takes its share
        rows = rng.choice(len(train["points"]), size=min(args.batch_size * world, len(train["points"])), replace=False)
        angles = rng.uniform(0, 2 * np.pi, len(rows))
        rows, angles = rows[rank::world], angles[rank::world]
        batch = batch_to_device(train, rows, args.device)
        # augmentation: a random yaw about z (the clouds are z up, as at inference)
        angle = torch.as_tensor(angles, device=args.device, dtype=torch.float32)
        R = torch.zeros(len(rows), 4, 4, device=args.device)
        R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1] = angle.cos(), -angle.sin(), angle.sin(), angle.cos()
        R[:, 2, 2] = R[:, 3, 3] = 1.0
        batch["points"] = batch["points"] @ R[:, :3, :3].transpose(1, 2)
        batch["grasp"] = R[:, None] @ batch["grasp"]
        index = train_contacts[torch.as_tensor(rows, device=args.device)]
        parts = losses(net(batch["points"], index), batch, index, args)
        optimizer.zero_grad(set_to_none=True)
        parts["loss"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        schedule.step()
        step += 1
        history.append(parts["loss"].detach())  # read back at the end, not every step
        if plan["steps"] is None and step == timing[1]:
            sync()
            per_step = (time.perf_counter() - t_timing) / (timing[1] - timing[0])
            plan["steps"] = max(step + 1, int(args.train_seconds / per_step))
            if dist:  # process 0's figure for all, or they would stop at different steps
                shared = [plan["steps"]]
                dist.broadcast_object_list(shared, src=0)
                plan["steps"] = shared[0]
            log(f"--train-seconds {args.train_seconds:.0f}: {per_step:.3f} s per step, so --steps {plan['steps']}")
        if step % args.log_every == 0 or step == plan["steps"]:
            log(f"step {step} " + " ".join(f"{k} {float(v.detach()):.4f}" for k, v in parts.items())
                + f" lr {schedule.get_last_lr()[0]:.2e}")
        if step % args.ckpt_every == 0:
            plan["train_seconds"] += time.perf_counter() - t_call
            t_call = time.perf_counter()
            save()
        if args.val_every and step % args.val_every == 0 and step < (plan["steps"] or step + 1):
            if lead:
                figures = validate()
                log(f"validation at step {step}: {figures}")
                consider(figures)
            if dist:
                dist.barrier()
        stop = bool(args.time_limit and time.perf_counter() - t_start > args.time_limit
                    and step < (plan["steps"] or step + 1))
        if dist and args.time_limit:  # process 0 decides for all
            flag = torch.tensor([int(stop)], device=args.device)
            dist.broadcast(flag, src=0)
            stop = bool(flag.item())
        if stop:
            plan["train_seconds"] += time.perf_counter() - t_call
            save()
            log(f"time limit: checkpoint at step {step}; run the same command again to resume")
            if args.export:
                copy_log(run, args)
            return {"step": step, "done": False, "losses": [float(v) for v in history]}
    plan["train_seconds"] += time.perf_counter() - t_call
    save()
    if dist:
        dist.barrier()
        dist.destroy_process_group()
    if not lead:
        return {"step": step, "done": True, "losses": [float(v) for v in history]}
    figures = validate()
    log(f"validation: {figures}; training took {plan['train_seconds']:.0f} s")
    consider(figures)
    if plan["best"]["step"] != step:  # an earlier validation scored higher: those weights ship
        model.load_state_dict(torch.load(run / "best.pt", map_location=args.device, weights_only=True)["model"])
        figures = plan["best"]["val"]
        log(f"selected the weights of step {plan['best']['step']} (selection score {plan['best']['score']:.4f})")
    save()
    args = dataclasses.replace(args, steps=plan["steps"])
    if args.export:
        export(model, config, args, data_hash, plan, figures, data_seconds, log)
        copy_log(run, args)
    return {"step": step, "done": True, "losses": [float(v) for v in history], "val": figures,
            "val_init": plan["val_init"], "selected_step": plan["best"]["step"]}


def selection_score(figures: dict) -> float:
    """What checkpoints are chosen by: the mean of the top-1 and top-10 pose agreement
    (``pose_agreement``: the best-scored grasps are scene-consistent verified ones) on the
    val-suite task views when given, else on the table-top views of held-out objects."""
    chosen = figures.get("tasks", figures["table_top"])
    return 0.5 * (chosen["top1_pose_agree"] + chosen["top10_pose_agree"])


def copy_log(run: Path, args: Args) -> None:
    out = Path(args.export_dir)
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run / "log.txt", out / "cgn_ours.log.tmp")
    os.replace(out / "cgn_ours.log.tmp", out / "cgn_ours.log")


def export(model, config, args, data_hash, plan, figures, data_seconds, log) -> None:
    out = Path(args.export_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "cgn_ours.pt"
    state = {k: (v.half() if v.is_floating_point() else v) for k, v in model.state_dict().items()}
    _atomic_save({"state_dict": state, "config": dataclasses.asdict(config)}, path)
    meta = {"command": retrain_command(args), "data_sha256": data_hash, "data_version": DATA_VERSION,
            "steps": plan["steps"], "train_seconds": round(plan["train_seconds"], 1),
            "data_seconds_last_call": round(data_seconds, 1),
            "device": torch.cuda.get_device_name() if args.device.startswith("cuda") else "cpu",
            "args": dataclasses.asdict(args),
            "val_split": f"train-split objects with holdout(id, {args.val_fraction}) (sha256 of the id); never test-split",
            # the held-out objects' table-top views under "val" (as ever), val task views beside
            "val_init": plan["val_init"]["table_top"], "val": figures["table_top"],
            **({"val_tasks_init": plan["val_init"]["tasks"], "val_tasks": figures["tasks"]} if "tasks" in figures else {}),
            "selected": {"step": plan["best"]["step"], "score": plan["best"]["score"],
                         "rule": selection_score.__doc__.split("\n\n")[0].replace("\n    ", " ")},
            "checkpoint_sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    tmp = path.with_name("cgn_ours.json.tmp")
    tmp.write_text(json.dumps(meta, indent=1) + "\n")
    os.replace(tmp, path.with_suffix(".json"))
    log(f"exported {path} ({path.stat().st_size / 1e6:.1f} MB) and {path.with_suffix('.json')}")


if __name__ == "__main__":
    main(tyro.cli(Args))
