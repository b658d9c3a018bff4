"""Contact-GraspNet training views of FetchBench tasks, seen through each task's own cameras.

Each view is what ``cgn-ptd-*`` feeds the network at evaluation: the env's two cameras'
point clouds fused in the robot-base frame (``envs.fetch_clouds`` on the reset observation:
furniture, clutter, occlusion and robot points left out), cropped to the cube about one
object and drawn to ``--num-points`` with ``grasp_prediction.predict.region_index`` (inference's own
crop), mean-centred. View 0 of a task crops about the task's target (exactly what inference
sees); further views (``--views-per-task``) crop about the other objects seen, largest first.

Labels are scene-consistent, as the original's: every task object's physics-verified grasps
(``fetchbench_ms.grasp_labels``; at most ``--max-grasps`` per object, drawn with the task's seed)
are placed at the object's pose, and a grasp whose open hand comes into the scene (the oracle
mesh world of ``planning.world_models.mesh_world``: furniture, robot table, floor, the other
objects; more than 1 mm deep) is dropped. Each kept grasp's two finger contacts carry it in
CGN's frame (``train.finger_contacts``). A cloud point's object comes from the segmentation
(target, or another object: then the one whose convex parts are within 5 mm); a point within
``--positive-radius`` of a contact of its own object's kept grasps is positive and carries
the nearest such contact's grasp. Only the positive points' labels are stored, as ``train.build_views`` does.

Output: ``<out>/shard-NNNNN.npz``, one per ``--shard-tasks`` consecutive tasks of the slice,
each written atomically with fixed zip metadata (``utils.io.npz_bytes``) (same seed and flags: same bytes); the arrays
of ``train.build_views`` (points, pos_offset, pos_index, pos_grasp, pos_width) and per view
``task_id``, ``object_id``, ``mean`` (base frame), ``grasps_kept`` / ``grasps_total``, and
``shard_task_id``, the tasks the shard covers. A rerun
skips the shards present (the flags are checked against ``<out>/config.json``); when every
shard is there, ``<out>/manifest.json`` lists them with their sha256 and one hash over all.
Worker processes (``--workers``, one env each) take shards from a queue, so the run scales
with cores; the end line gives views and kept grasps per core-minute.

The suite must be a train-split one (``train`` or ``val``); test tasks and test-split objects
are refused before anything is written.

    python baselines/contact_graspnet/task_views.py --suite train --tasks 0:6000 --out /data/cgn/task_views/train \\
        --workers 60
    python baselines/contact_graspnet/task_views.py --suite val --tasks 0:200 --out /data/cgn/task_views/val --workers 60
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ALLOWED_SUITES = ("train", "val")
VIEWS_VERSION = 1  # bump when what a seed produces changes
MIN_SEEN_POINTS = 50  # an object with fewer points in the fused cloud gets no view of its own
COLLISION_DEPTH = 0.001  # m: a hand point deeper than this in the scene is a collision (train.collision_free's)


@dataclass
class Args:
    suite: str = "train"  # train-split suites only: train | val
    tasks: str = "0:6000"  # slice of the suite's task order, "a:b"
    out: str = "runs/cgn/task_views/train"  # shards, config.json, manifest.json
    views_per_task: int = 2  # view 0 about the target, the others about the other objects seen
    num_points: int = 20000  # points per view (as cgn-ptd-* at evaluation)
    positive_radius: float = 0.005  # m, cloud point to finger contact
    max_grasps: int = 300  # verified grasps per object tested against the scene
    shard_tasks: int = 16  # tasks per shard file
    seed: int = 0
    workers: int = 0  # processes, one env each (0: all cores)
    time_limit: float = 0.0  # s; > 0: start no shard after this long (re-run to continue)


# Flags that change the bytes of a shard (config.json holds them; a rerun must match).
DATA_FLAGS = ("suite", "views_per_task", "num_points", "positive_radius", "max_grasps", "shard_tasks", "seed")


def _trainer():
    """train.py beside this file, as the module ``cgn_train`` (a script, not a package)."""
    if "cgn_train" not in sys.modules:
        import importlib.util

        spec = importlib.util.spec_from_file_location("cgn_train", Path(__file__).resolve().parent / "train.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules["cgn_train"] = module  # (dataclasses look their module up there)
        spec.loader.exec_module(module)
    return sys.modules["cgn_train"]


HAND_CLUSTER_DEPTH = 4  # the hand's points in 2**4 clusters for the scene test's broad phase


@functools.lru_cache(maxsize=1)
def _hand_points() -> np.ndarray:
    """The open hand's test points (``train.hand_points``: surface samples with a fixed seed),
    made once and ordered into 2**HAND_CLUSTER_DEPTH equal runs of nearby points (halved at the
    median of the longest side, recursively; the last point repeated to make the halves equal):
    each run is one cluster of ``world.distance``'s broad phase. Order and repeats change
    nothing of what ``hand_collides`` answers (any point too deep)."""
    points = _trainer().hand_points()
    runs = 2 ** HAND_CLUSTER_DEPTH
    points = np.concatenate([points, np.repeat(points[-1:], -len(points) % runs, axis=0)])

    def split(block: np.ndarray, depth: int) -> list[np.ndarray]:
        if depth == 0:
            return [block]
        axis = int(np.argmax(block.max(axis=0) - block.min(axis=0)))
        order = np.argsort(block[:, axis], kind="stable")
        half = len(block) // 2
        return split(block[order[:half]], depth - 1) + split(block[order[half:]], depth - 1)

    return np.concatenate(split(points, HAND_CLUSTER_DEPTH))


def task_seed(task_id: str, seed: int) -> int:
    return int(hashlib.sha256(f"cgn-views|{task_id}|{seed}".encode()).hexdigest()[:8], 16)


# ----------------------------------------------------------------------------- labels
def hand_collides(world, T_base_hand: np.ndarray, exclude: tuple[str, ...]) -> np.ndarray:
    """(N,) whether the open hand at each pose ((N, 4, 4), base frame) reaches more than
    ``COLLISION_DEPTH`` into ``world`` (groups ``exclude`` left out: the grasped object)."""
    local = _hand_points()
    if len(T_base_hand) == 0:
        return np.zeros(0, dtype=bool)
    points = np.einsum("nij,kj->nki", T_base_hand[:, :3, :3], local) + T_base_hand[:, None, :3, 3]
    # clusters of nearby hand points: most are near few obstacles (world.distance's cluster broad phase)
    distance = world.distance(points.reshape(-1, 3), horizon=0.01, exclude=exclude,
                              cluster_size=len(local) >> HAND_CLUSTER_DEPTH).numpy()
    return (distance.reshape(len(T_base_hand), -1) < -COLLISION_DEPTH).any(axis=1)


def scene_labels(task, world, T_base_objects: list[np.ndarray], max_grasps: int, rng: np.random.Generator) -> dict:
    """Finger contacts (base frame) of every object's verified grasps that are free in the
    scene, with their CGN-frame labels and widths; per object the grasps tested and kept."""
    from fetchbench_ms.grasp_labels import load_grasps, objects_with_grasps

    with_grasps = set(objects_with_grasps())
    contacts, labels, widths, owners, kept, total = [], [], [], [], [], []
    for k, (placement, T_base_object) in enumerate(zip(task.objects, T_base_objects)):
        if placement.object_id not in with_grasps:
            kept.append(0)
            total.append(0)
            continue
        grasps = load_grasps(placement.object_id).successful
        pick = np.sort(rng.permutation(len(grasps.width))[:max_grasps])
        T_base_hand = T_base_object[None] @ grasps.T_object_hand[pick]
        group = "target" if k == task.target_index else f"object:{k}"
        free = ~hand_collides(world, T_base_hand, (group,))
        c, lab, w = _trainer().finger_contacts(T_base_hand[free], np.asarray(grasps.width, dtype=np.float64)[pick][free])
        contacts.append(c)
        labels.append(lab)
        widths.append(w)
        owners.append(np.full(len(c), k))
        kept.append(int(free.sum()))
        total.append(len(pick))
    return {"contacts": np.concatenate(contacts) if contacts else np.zeros((0, 3)),
            "labels": np.concatenate(labels) if labels else np.zeros((0, 4, 4)),
            "widths": np.concatenate(widths) if widths else np.zeros(0),
            "owner": np.concatenate(owners) if owners else np.zeros(0, int), "kept": kept, "total": total}


def object_owner(points: np.ndarray, world, n_objects: int, target_index: int) -> np.ndarray:
    """(N,) the task object each point lies on (within 5 mm of its convex parts), -1 for none."""
    groups = ["target" if k == target_index else f"object:{k}" for k in range(n_objects)]
    distance = np.stack([world.distance(points, horizon=0.01, exclude=tuple(g for g in world.group_names if g != name))
                         .numpy() for name in groups])
    owner = distance.argmin(axis=0)
    return np.where(distance.min(axis=0) < 0.005, owner, -1)


def label_view(points: np.ndarray, owner: np.ndarray, scene: dict, radius: float) -> dict:
    """Per point of a view (base frame; ``owner``: the object it lies on, -1 for none):
    positive (within ``radius`` of a finger contact of a kept grasp of its own object), and
    the grasp ((4, 4), CGN frame) and width of that nearest contact."""
    from scipy.spatial import cKDTree

    positive = np.zeros(len(points), dtype=bool)
    grasp, width = np.zeros((len(points), 4, 4)), np.zeros(len(points))
    for k in np.unique(owner[owner >= 0]):
        mine = np.flatnonzero(scene["owner"] == k)
        on = np.flatnonzero(owner == k)
        if len(mine) == 0:
            continue
        distance, nearest = cKDTree(scene["contacts"][mine]).query(points[on])
        near = distance < radius
        positive[on[near]] = True
        grasp[on[near]] = scene["labels"][mine[nearest[near]]]
        width[on[near]] = scene["widths"][mine[nearest[near]]]
    return {"positive": positive, "grasp": grasp, "width": width}


def task_views(env, task_id: str, args: Args) -> list[dict]:
    """The views of one task (module docstring), each with only its positive points' labels."""
    from fetchbench_ms.envs import fetch_clouds
    from fetchbench_ms.envs.pointcloud import LABEL_FURNITURE, LABEL_OBJECT, _np
    from fetchbench_ms.grasp_prediction.predict import region_index
    from fetchbench_ms.planning.world_models import mesh_world, object_poses_base

    seed = task_seed(task_id, args.seed)
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed % 2**31, options={"task_id": task_id})
    u = env.unwrapped
    task = u.tasks[0]
    clouds = fetch_clouds(obs)
    # the cloud cgn-ptd-* crops: target then scene (furniture and other objects), base frame
    points = np.concatenate([clouds.target, clouds.scene]).astype(np.float32)
    is_target = np.arange(len(points)) < len(clouds.target)
    label = _np(obs["pointcloud"]["fetch_label"][0])
    # fetch_clouds keeps each cloud's points in observation order, so the labels line up
    scene_label = label[(label == LABEL_FURNITURE) | (label == LABEL_OBJECT)]
    is_object = np.concatenate([np.ones(len(clouds.target), bool), scene_label == LABEL_OBJECT])
    world = mesh_world(env)
    T_base_objects = object_poses_base(env)
    scene = scene_labels(task, world, T_base_objects, args.max_grasps, rng)
    owner = np.full(len(points), -1)
    owner[is_object] = object_owner(points[is_object], world, len(task.objects), task.target_index)
    owner[is_target] = task.target_index
    # the target first, then the other objects seen (with grasps kept), most points first
    seen = [(int((owner == k).sum()), k) for k in range(len(task.objects))
            if k != task.target_index and scene["kept"][k] > 0 and (owner == k).sum() >= MIN_SEEN_POINTS]
    order = [k for _, k in sorted(seen, key=lambda s: (-s[0], s[1]))]
    if is_target.any():  # (a target no camera sees has no crop: inference has nothing to grasp either)
        order.insert(0, task.target_index)
    views = []
    for k in order[:args.views_per_task]:
        pick = region_index(points, owner == k, args.num_points, rng)
        view_points = points[pick].astype(np.float64)
        labelled = label_view(view_points, owner[pick], scene, args.positive_radius)
        mean = view_points.mean(0)
        index = np.flatnonzero(labelled["positive"])
        grasp = labelled["grasp"][index].copy()
        grasp[:, :3, 3] -= mean
        views.append({"points": (view_points - mean).astype(np.float32), "pos_index": index.astype(np.int32),
                      "pos_grasp": grasp[:, :3, :].astype(np.float16),
                      "pos_width": labelled["width"][index].astype(np.float16),
                      "task_id": task_id, "object_id": task.objects[k].object_id, "mean": mean,
                      "grasps_kept": scene["kept"][k], "grasps_total": scene["total"][k]})
    return views


# ----------------------------------------------------------------------------- shards
def shard_arrays(views: list[dict], num_points: int) -> dict:
    if not views:  # tasks with no object seen
        return {**_trainer().empty_views(num_points), "task_id": np.zeros(0, "<U1"), "object_id": np.zeros(0, "<U1"),
                "mean": np.zeros((0, 3)), "grasps_kept": np.zeros(0, np.int64), "grasps_total": np.zeros(0, np.int64)}
    counts = np.array([len(v["pos_index"]) for v in views], dtype=np.int64)
    return {"points": np.stack([v["points"] for v in views]),
            "pos_offset": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            **{k: np.concatenate([v[k] for v in views]) for k in ("pos_index", "pos_grasp", "pos_width")},
            "task_id": np.array([v["task_id"] for v in views]), "object_id": np.array([v["object_id"] for v in views]),
            "mean": np.stack([v["mean"] for v in views]).astype(np.float64),
            "grasps_kept": np.array([v["grasps_kept"] for v in views], dtype=np.int64),
            "grasps_total": np.array([v["grasps_total"] for v in views], dtype=np.int64)}


def shard_path(out: Path, index: int) -> Path:
    return out / f"shard-{index:05d}.npz"


_ENV = None


def _init_worker(suite: str) -> None:
    import gymnasium as gym
    import torch

    import fetchbench_ms  # noqa: F401  (registers the envs)

    global _ENV
    torch.set_num_threads(1)
    _ENV = gym.make("FetchBench-v0", obs_mode="pointcloud", task_suite=suite, control_mode="pd_joint_pos")


def _shard_job(job) -> dict:
    """Make and write one shard; returns its counts and seconds."""
    from fetchbench_ms.utils.io import atomic_write_bytes, npz_bytes

    args, index, task_ids = job
    t = time.perf_counter()
    views = []
    for task_id in task_ids:
        try:
            views += task_views(_ENV, task_id, args)
        except Exception as error:  # name the task: a rerun would stop at it again
            raise RuntimeError(f"{task_id}: {type(error).__name__}: {error}") from error
    arrays = {**shard_arrays(views, args.num_points), "shard_task_id": np.array(task_ids)}
    # fixed zip metadata, stored: the same arrays give the same bytes; renamed into place whole
    atomic_write_bytes(shard_path(Path(args.out), index), npz_bytes(arrays, compress=False))
    return {"index": index, "views": len(views), "grasps_kept": int(arrays["grasps_kept"].sum()),
            "positives": int(len(arrays["pos_index"])), "seconds": time.perf_counter() - t}


def write_manifest(out: Path, config: dict) -> dict:
    """``<out>/manifest.json``: every shard in ``out`` (all slices made into it) with its
    sha256, and one sha256 over the config and the shards' hashes."""
    from fetchbench_ms.utils.io import atomic_write_text, sha256_file

    entries = []
    for path in sorted(out.glob("shard-*.npz")):
        with np.load(path) as z:
            views, positives, task_ids = len(z["points"]), len(z["pos_index"]), [str(t) for t in z["shard_task_id"]]
        entries.append({"file": path.name, "tasks": [task_ids[0], task_ids[-1]], "task_count": len(task_ids),
                        "views": views, "positives": positives, "sha256": sha256_file(path)})
    digest = hashlib.sha256(json.dumps(config, sort_keys=True).encode())
    for entry in entries:
        digest.update(f"{entry['file']}:{entry['sha256']};".encode())
    manifest = {"config": config, "views": sum(e["views"] for e in entries),
                "tasks": sum(e["task_count"] for e in entries), "shards": entries, "sha256": digest.hexdigest()}
    atomic_write_text(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")
    return manifest


def main(args: Args) -> dict:
    from fetchbench_ms.tasks.splits import cli_guard, refuse_test, refuse_test_objects, refuse_test_task_ids
    from fetchbench_ms.tasks.suite import load_suite
    from fetchbench_ms.utils.io import atomic_write_text

    cli_guard(refuse_test, args.suite, "Contact-GraspNet training views")  # exit 2 before anything is written
    if args.suite not in ALLOWED_SUITES:
        print(f"error: --suite {args.suite!r}: views come from train-split suites only; valid: "
              f"{', '.join(ALLOWED_SUITES)}", file=sys.stderr)
        raise SystemExit(2)
    if args.views_per_task < 1 or args.shard_tasks < 1 or args.num_points < 1 or args.max_grasps < 1:
        print("error: --views-per-task, --shard-tasks, --num-points and --max-grasps must be >= 1", file=sys.stderr)
        raise SystemExit(2)
    suite = load_suite(args.suite)
    try:
        a, b = (int(x) if x else None for x in args.tasks.split(":"))
    except ValueError:
        print(f"error: --tasks {args.tasks!r}: expected a slice a:b of the suite's {len(suite)} tasks", file=sys.stderr)
        raise SystemExit(2) from None
    ids = suite.ids()[slice(a, b)]
    if not ids:
        print(f"error: --tasks {args.tasks!r} selects no task of the {len(suite)} of suite {args.suite!r}",
              file=sys.stderr)
        raise SystemExit(2)
    cli_guard(refuse_test_task_ids, ids, "Contact-GraspNet training views")
    cli_guard(refuse_test_objects, sorted({p.object_id for t in ids for p in suite.get(t).objects}),
              "Contact-GraspNet training views")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # shards are numbered by their place in the whole suite, so slices of one folder agree
    start = 0 if a is None else (a if a >= 0 else len(suite) + a)
    if start % args.shard_tasks:
        print(f"error: --tasks must start at a multiple of --shard-tasks ({args.shard_tasks}); got {start}",
              file=sys.stderr)
        raise SystemExit(2)
    config = {"version": VIEWS_VERSION, **{k: getattr(args, k) for k in DATA_FLAGS}}
    config_path = out / "config.json"
    if config_path.is_file():
        saved = json.loads(config_path.read_text())
        if saved != config:
            changed = sorted(k for k in set(saved) | set(config) if saved.get(k) != config.get(k))
            print(f"error: {out} holds views made with other {', '.join(changed)} ({saved}); use a new --out",
                  file=sys.stderr)
            raise SystemExit(2)
    else:
        atomic_write_text(config_path, json.dumps(config, indent=1, sort_keys=True) + "\n")
    shards = [(start // args.shard_tasks + i, ids[s:s + args.shard_tasks])
              for i, s in enumerate(range(0, len(ids), args.shard_tasks))]
    todo = [(args, index, task_ids) for index, task_ids in shards if not shard_path(out, index).is_file()]
    workers = max(1, min(args.workers or os.cpu_count() or 1, len(todo) or 1))
    print(f"{len(ids)} tasks of {args.suite} in {len(shards)} shards, {len(todo)} to make, {workers} workers",
          flush=True)
    t_start = time.perf_counter()
    made = []
    if todo:
        import multiprocessing

        from fetchbench_ms.utils.workers import one_thread_per_spawned_worker

        with one_thread_per_spawned_worker(), \
                multiprocessing.get_context("spawn").Pool(workers, _init_worker, (args.suite,)) as pool:
            pending = pool.imap_unordered(_shard_job, todo)
            for _ in todo:
                if args.time_limit and time.perf_counter() - t_start > args.time_limit:
                    pool.terminate()  # a shard cut short leaves only a temporary file, never a shard
                    break
                result = next(pending)
                made.append(result)
                print(f"shard {result['index']:05d}: {result['views']} views, {result['grasps_kept']} grasps kept, "
                      f"{result['positives']} positive points, {result['seconds']:.1f} s "
                      f"[{len(made)}/{len(todo)} in {time.perf_counter() - t_start:.0f} s]", flush=True)
    wall = time.perf_counter() - t_start
    if made:
        core_minutes = workers * wall / 60
        views, kept = sum(m["views"] for m in made), sum(m["grasps_kept"] for m in made)
        print(f"made {len(made)} shards, {views} views in {wall:.0f} s with {workers} workers: "
              f"{views / core_minutes:.1f} views and {kept / core_minutes:.0f} scene-consistent grasps "
              f"per core-minute", flush=True)
    missing = [index for index, _ in shards if not shard_path(out, index).is_file()]
    if missing:
        print(f"{len(missing)} of {len(shards)} shards still to make: run the same command again", flush=True)
        return {"made": made, "manifest": None}
    manifest = write_manifest(out, config)
    print(f"manifest {out / 'manifest.json'}: {manifest['views']} views of {manifest['tasks']} tasks, "
          f"sha256 {manifest['sha256'][:16]}", flush=True)
    if not made and not todo:
        print("nothing to make: every shard was already there", flush=True)
    return {"made": made, "manifest": manifest}


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))
