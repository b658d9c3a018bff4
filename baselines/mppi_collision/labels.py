"""Labelled queries for the scene-collision network (``fetchbench_ms.planning.collision_net``).

Per task of a train-split suite (``train`` or ``val``; the test suite is refused: its
scenes are for ``scripts/bench/bench_collision_net.py`` only), one file ``<out>/<task>.npz``:

- the input: the env's real camera clouds (both cameras, robot points removed as the
  point-cloud planners remove them), as ``collision_net.scene_grid`` (uint8);
- the queries: ``--configs`` arm configurations, a mix chosen to cover what a planner
  asks (uniform in the joint limits; around the start configuration; on and around the
  straight lines from the start to IK solutions of the target's grasps, where the hand is
  inside the furniture; and near the collision boundary, by bisecting between free and
  colliding queries and jittering the result);
- the labels: every sphere's exact clearance to the scene's true geometry (the oracle
  mesh world of ``planning.world_models.mesh_world``: furniture primitives, robot table, floor,
  every object's convex parts) with the formulas of the planners' exact checker
  (``planning.distance.TorchWorld`` with all convex planes: the checker's
  ``CollisionWorld.distance`` to float precision), in mm (int8, clipped to -50..100); and
  the query's collision label (the smallest clearance < 0, before rounding).

A task is "open" (fingers open, the target part of the scene: the approach) or, for 30%
of tasks (by a hash of the task id), "carry": the target left out of the cloud and of the
world, held by one of its annotated grasps, its convex parts as ``checker.Attachment``
spheres in the hand frame (their clearances are labelled too), the fingers not checked
(as the retrieval's checker).

Costs (one process): rendering a task ~1.5 s, grid 0.9 s, IK ~0.8 s, then the labels (every
convex plane of the scanned objects, parts grouped by plane count: ``plane_buckets``; a task
in all 3.5 CPU s on one core, ``scripts/bench/bench_round_labels.py --labeller collision``;
``--device cuda`` computes the labels on a GPU).

Each task's file is a shard: written whole under a temporary name and renamed, with fixed
zip metadata (``utils.io.npz_bytes``: the same seed and flags give the same bytes on one
machine). Worker processes (one env each) take tasks from a shared queue, so the run scales
with cores. Resumable: finished tasks are skipped (the flags are checked against
``<out>/config.json``); ``--time-limit`` stops starting tasks. When every task of the slice
is labelled, ``<out>/manifest.json`` lists every task file in the folder with its content
hash and one sha256 over them all (the same hash ``train.py`` records as its data hash); the
end line gives the labelled queries per core-minute.

    python baselines/mppi_collision/labels.py --suite train --tasks 0:3000 --out /data/mppi/train --workers 60
    python baselines/mppi_collision/labels.py --suite val --tasks 0:64 --out /tmp/mppi/val --workers 4
"""
from __future__ import annotations

import hashlib
import json
import multiprocessing as mp
import os
import queue as queue_module
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ALLOWED_SUITES = ("train", "val")
ARM_SPHERES = 77  # the Panda's world-checked spheres (planning.robot.WORLD_LINKS)
ATT_SPHERES = 64  # a carried object's spheres (checker.Attachment's default)
MM_RANGE = (-50, 100)


@dataclass
class Args:
    suite: str = "train"  # train-split suites only: train | val
    tasks: str = "0:960"  # slice of the suite's task order, "a:b"
    out: str = "/tmp/mppi/train"  # one .npz per task
    configs: int = 6000  # queries per task
    workers: int = 0  # processes (each owns one env; 0: all cores)
    seed: int = 0
    carry_share: float = 0.3  # share of tasks labelled as "carry" (target held, fingers unchecked)
    time_limit: float = 0.0  # s; > 0: start no task after this long (re-run to continue)
    device: str = "cpu"  # where the exact distances are computed (cuda: faster labels)


# Flags that change what a task's file holds (config.json; a rerun into the folder must match).
DATA_FLAGS = ("suite", "configs", "seed", "carry_share")


def task_seed(task_id: str, seed: int) -> int:
    return int(hashlib.sha256(f"{task_id}|{seed}".encode()).hexdigest()[:8], 16)


def _boundary(q_free: np.ndarray, q_hit: np.ndarray, label_fn, steps: int = 4) -> np.ndarray:
    """Bisection on the segments between free and colliding configurations: points within
    1/2^steps of a segment's length from the collision boundary."""
    a, b = q_free.copy(), q_hit.copy()
    for _ in range(steps):
        mid = 0.5 * (a + b)
        hit = label_fn(mid)
        b = np.where(hit[:, None], mid, b)
        a = np.where(hit[:, None], a, mid)
    return 0.5 * (a + b)


#: Convex parts go to the torch worlds of ``plane_buckets`` by plane count, at most these many.
PLANE_BUCKETS = (16, 32, 64, 128, 256)


def plane_buckets(world):
    """``world`` as a few worlds that hold all its obstacles between them: the first the
    boxes, cylinders and the convex parts of at most ``PLANE_BUCKETS[0]`` planes, each further
    one the parts of the next plane-count range. A torch world pads every convex part to the
    largest plane count among them (a scanned object's hull has up to ~370 planes, the mean
    part ~30), so one world a range does several times less work; the minimum over them is
    the same distance to the bit (a padding plane never binds, and the minimum of the same
    values is the same in any order)."""
    from fetchbench_ms.planning.world import CollisionWorld, ConvexSet

    edges = (0,) + PLANE_BUCKETS + (np.inf,)
    buckets = [CollisionWorld() for _ in edges[1:]]
    for name, sets in world.groups.items():
        for obstacle_set in sets:
            if not isinstance(obstacle_set, ConvexSet):
                buckets[0].add(name, obstacle_set)
                continue
            counts = obstacle_set.plane_counts()
            for bucket, lo, hi in zip(buckets, edges[:-1], edges[1:]):
                index = np.flatnonzero((counts > lo) & (counts <= hi))
                if len(index):
                    bucket.add(name, obstacle_set.subset(index))
    return [b for b in buckets if b.groups]


class Labeller:
    """Exact sphere clearances of configurations in one world (base frame)."""

    def __init__(self, world, exclude: tuple, finger: float, attachment, carry: bool, device: str = "cpu"):
        import torch

        from fetchbench_ms.planning.collision_net import RobotSpheres
        from fetchbench_ms.planning.distance import TorchWorld
        from fetchbench_ms.planning.robot import panda

        self.torch = torch
        self.robot = panda()
        self.device = torch.device(device)
        self.worlds = [TorchWorld([w], [exclude], self.device, torch.float32, max_planes=None)
                       for w in plane_buckets(world)]
        self.spheres = RobotSpheres(self.device)
        checked = ~self.spheres.finger_mask.cpu().numpy() if carry else np.ones(ARM_SPHERES, bool)
        self.checked = np.concatenate([checked, np.full(ATT_SPHERES, attachment is not None)])
        radii = np.concatenate([self.spheres.radii.cpu().numpy(),
                                attachment.radii if attachment is not None else np.zeros(ATT_SPHERES)])
        self.radii = torch.as_tensor(radii, device=self.device, dtype=torch.float32)
        att_c = attachment.centers_hand if attachment is not None else np.zeros((ATT_SPHERES, 3))
        self.att_c = torch.as_tensor(att_c, device=self.device, dtype=torch.float32)
        self.finger = finger

    def centers(self, q: np.ndarray):
        """(B, 77 + 64, 3) sphere centres: the arm's world spheres, then the carried object's."""
        return self.spheres.centers(self.torch.as_tensor(q), self.finger, self.att_c)

    def clearance(self, q: np.ndarray, chunk: int = 250) -> np.ndarray:
        """(B, 141) exact clearance of every sphere (m) up to the label range (beyond it, any
        value >= its top); unchecked spheres get +inf."""
        torch = self.torch
        out = []
        horizon = MM_RANGE[1] / 1000
        with torch.no_grad():
            for part in np.array_split(q, max(1, int(np.ceil(len(q) / chunk)))):
                c = self.centers(part).reshape(1, -1, 3)
                r = self.radii.repeat(len(part))
                d = torch.full((c.shape[1],), 10.0, device=self.device)
                # Only obstacles whose bounding sphere comes within the label range of a sphere.
                for world in self.worlds:
                    for idx, dist in world.pairs(c, horizon, r[None]):
                        d = torch.minimum(d, dist) if idx is None else d.scatter_reduce(0, idx, dist, reduce="amin")
                out.append((d - r).reshape(len(part), -1).double().cpu().numpy())
        d = np.concatenate(out) if out else np.zeros((0, len(self.checked)))
        return np.where(self.checked, d, np.inf)

    def collides(self, q: np.ndarray) -> np.ndarray:
        return self.clearance(q).min(axis=1) < 0


def sample_configs(labeller: Labeller, q0: np.ndarray, q_goals: np.ndarray, n: int, rng
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(n, 7) queries and their (n, 141) sphere clearances."""
    robot = labeller.robot
    lo, hi = robot.q_min, robot.q_max
    n_uniform, n_start, n_boundary = int(0.25 * n), int(0.15 * n), int(0.25 * n)
    n_goal = n - n_uniform - n_start - n_boundary
    parts = [rng.uniform(lo, hi, (n_uniform, 7)), q0 + rng.normal(0, 1, (n_start, 1)) * 0.5 * rng.normal(0, 1, (n_start, 7))]
    if len(q_goals):
        g = q_goals[rng.integers(len(q_goals), size=n_goal)]
        s = rng.uniform(0.3, 1.15, (n_goal, 1)) ** 0.5  # most near the goal end, some past it
        sigma = rng.choice([0.0, 0.03, 0.1, 0.3], size=(n_goal, 1), p=[0.1, 0.3, 0.4, 0.2])
        parts.append(q0 + s * (g - q0) + sigma * rng.normal(0, 1, (n_goal, 7)))
    else:
        parts.append(rng.uniform(lo, hi, (n_goal, 7)))
    q = np.clip(np.concatenate(parts), lo, hi)
    clearance = labeller.clearance(q)
    hit = clearance.min(axis=1) < 0
    free, coll = q[~hit], q[hit]
    if len(free) and len(coll):
        i, j = rng.integers(len(free), size=n_boundary), rng.integers(len(coll), size=n_boundary)
        # Pair each free query with a colliding one near it (the nearer of two draws).
        j2 = rng.integers(len(coll), size=n_boundary)
        near = np.abs(coll[j2] - free[i]).sum(1) < np.abs(coll[j] - free[i]).sum(1)
        j = np.where(near, j2, j)
        edge = _boundary(free[i], coll[j], labeller.collides)
        edge = edge + rng.choice([0.005, 0.02, 0.05], size=(n_boundary, 1)) * rng.normal(0, 1, (n_boundary, 7))
    else:
        edge = rng.uniform(lo, hi, (n_boundary, 7))
    edge = np.clip(edge, lo, hi)
    q = np.concatenate([q, edge])
    clearance = np.concatenate([clearance, labeller.clearance(edge)])
    order = rng.permutation(len(q))
    return q[order], clearance[order]


def label_task(env, task_id: str, args: Args) -> dict:
    """Everything one task's file holds (see the module docstring)."""
    from fetchbench_ms.envs import fetch_clouds
    from fetchbench_ms.planning.checker import Attachment
    from fetchbench_ms.planning.collision_net import grid_to_uint8, scene_grid
    from fetchbench_ms.planning.ik import solve_ik
    from fetchbench_ms.planning.robot import panda
    from fetchbench_ms.grasp_labels.candidates import object_grasps, retreat, tcp_from_hand
    from fetchbench_ms.objects.loading import load_object
    from fetchbench_ms.planning.world_models import mesh_world, object_poses_base, remove_robot_points

    t0 = time.perf_counter()
    seed = task_seed(task_id, args.seed)
    rng = np.random.default_rng(seed)
    carry = (seed % 1000) / 1000 < args.carry_share
    obs, _ = env.reset(seed=seed % 2**31, options={"task_id": task_id})
    u = env.unwrapped
    clouds = fetch_clouds(obs)
    q_full = u.agent.robot.get_qpos()[0].cpu().numpy().astype(float)
    scene = remove_robot_points(clouds.scene, q_full)
    cloud = scene if carry else np.concatenate([scene, clouds.target])
    t_render = time.perf_counter() - t0
    grid = scene_grid(cloud)
    t_grid = time.perf_counter() - t0 - t_render
    world = mesh_world(env)
    task = u.tasks[0]
    T_base_object = object_poses_base(env)[task.target_index]
    grasps = object_grasps(task.target.object_id).T_object_hand
    pick = rng.permutation(len(grasps))[:16]
    T_hand = T_base_object[None] @ grasps[pick]
    T_tcp = tcp_from_hand(T_hand)
    robot = panda()
    q0 = q_full[:7]
    targets = np.concatenate([T_tcp, retreat(T_tcp, 0.04), retreat(T_tcp, 0.10)])
    ik = solve_ik(robot, targets, checker=None, q_seed=q0, n_seeds=2, rng=rng)
    attachment = None
    if carry:
        T_hand_object = np.linalg.inv(T_hand[0])
        parts = [p.copy().apply_transform(T_hand_object) for p in load_object(task.target.object_id).convex_parts]
        attachment = Attachment.from_convex_parts(parts, seed=seed % 2**31)
        if len(attachment.radii) < ATT_SPHERES:  # pad: far above, never near
            pad = ATT_SPHERES - len(attachment.radii)
            attachment = Attachment(np.concatenate([attachment.centers_hand, np.tile([[0, 0, 5.0]], (pad, 1))]),
                                    np.concatenate([attachment.radii, np.full(pad, 1e-3)]))
    t_ik = time.perf_counter() - t0 - t_render - t_grid
    labeller = Labeller(world, ("target",) if carry else (), 0.04, attachment, carry, args.device)
    q, clearance = sample_configs(labeller, q0, ik.q, args.configs, rng)
    label = clearance.min(axis=1) < 0
    mm = np.clip(np.round(np.where(np.isfinite(clearance), clearance, 1.0) * 1000), *MM_RANGE).astype(np.int8)
    return dict(task_id=task_id, suite=args.suite, grid=grid_to_uint8(grid), q=q.astype(np.float32), clearance_mm=mm,
                label=label, checked=labeller.checked, radii=labeller.radii.cpu().numpy(),
                att_centers_hand=labeller.att_c.cpu().numpy(), carry=carry, finger=0.04,
                seconds=np.array([t_render, t_grid, t_ik, time.perf_counter() - t0 - t_render - t_grid - t_ik]))


def task_path(out: Path, task_id: str) -> Path:
    return out / (task_id.replace("/", "_") + ".npz")


def _save(path: Path, data: dict) -> None:
    """The task's file, whole or not at all, same arrays same bytes (timings left out)."""
    from fetchbench_ms.utils.io import atomic_write_bytes, npz_bytes

    atomic_write_bytes(path, npz_bytes({k: v for k, v in data.items() if k != "seconds"}))


def labels_digest(files: list[Path]) -> str:
    """sha256 over task files (sorted): each name and its q, clearance_mm, label and grid
    bytes; ``train.py``'s data hash of a folder is this over its files."""
    h = hashlib.sha256()
    for f in sorted(files):
        with np.load(f) as z:
            h.update(f.name.encode())
            for key in ("q", "clearance_mm", "label", "grid"):
                h.update(np.ascontiguousarray(z[key]).tobytes())
    return h.hexdigest()


def write_manifest(out: Path, config: dict) -> dict:
    """``<out>/manifest.json``: every task file in ``out`` with its queries, collision share and
    content hash (``labels_digest`` of it alone), and ``labels_digest`` of them all."""
    from fetchbench_ms.utils.io import atomic_write_text

    files = sorted(f for f in out.glob("*.npz") if not f.name.endswith(".tmp.npz"))
    entries = []
    for f in files:
        with np.load(f) as z:
            entries.append({"file": f.name, "task_id": str(z["task_id"]), "carry": bool(z["carry"]),
                            "queries": int(len(z["q"])), "collide": round(float(z["label"].mean()), 4),
                            "sha256": labels_digest([f])})
    manifest = {"config": config, "tasks": len(entries), "queries": sum(e["queries"] for e in entries),
                "sha256": labels_digest(files), "files": entries}
    atomic_write_text(out / "manifest.json", json.dumps(manifest, indent=1) + "\n")
    return manifest


def _worker(args: Args, tasks, t_start: float, results) -> None:
    """Label tasks taken from the shared ``tasks`` queue (None: no more) until it is empty or
    the time limit has passed; one env for them all."""
    import gymnasium as gym
    import torch

    import fetchbench_ms  # noqa: F401  (registers the envs)

    torch.set_num_threads(1)
    env = gym.make("FetchBench-v0", obs_mode="pointcloud", task_suite=args.suite, control_mode="pd_joint_pos")
    out = Path(args.out)
    while True:
        task_id = tasks.get()
        if task_id is None or (args.time_limit > 0 and time.time() - t_start > args.time_limit):
            break
        path = task_path(out, task_id)
        if path.exists():
            continue
        data = label_task(env, task_id, args)
        _save(path, data)
        results.put((task_id, float(data["label"].mean()), len(data["q"]), data["seconds"].tolist()))
    env.close()
    results.put(None)


def main(args: Args, reporting_only: bool = False) -> dict | None:
    """Label the tasks. ``reporting_only``: the test suite is allowed (the benchmark script
    measures the network there; nothing trains on its files, ``train.py`` refuses them)."""
    from fetchbench_ms.tasks.splits import cli_guard, refuse_test
    from fetchbench_ms.tasks.suite import load_suite

    if not reporting_only:
        cli_guard(refuse_test, args.suite, "collision-net labelling")  # exit 2, before anything is written
    if args.suite not in ALLOWED_SUITES and not (reporting_only and args.suite == "test"):
        raise SystemExit(f"labels come from train-split suites only; got {args.suite!r}; valid: {', '.join(ALLOWED_SUITES)}")
    if args.workers < 0 or args.configs < 1:
        raise SystemExit(f"--workers must be >= 0 (0: all cores) and --configs >= 1; got {args.workers}, {args.configs}")
    suite = load_suite(args.suite)
    try:
        a, b = (int(x) if x else None for x in args.tasks.split(":"))
    except ValueError:
        raise SystemExit(f"--tasks {args.tasks!r}: expected a slice a:b of the suite's {len(suite)} tasks") from None
    ids = suite.ids()[slice(a, b)]
    if not ids:
        raise SystemExit(f"--tasks {args.tasks!r} selects none of the {len(suite)} tasks of suite {args.suite!r}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = {k: getattr(args, k) for k in DATA_FLAGS}
    config_path = out / "config.json"
    if config_path.is_file():
        saved = json.loads(config_path.read_text())
        if saved != config:
            changed = sorted(k for k in set(saved) | set(config) if saved.get(k) != config.get(k))
            raise SystemExit(f"{out} holds labels made with other {', '.join(changed)} ({saved}); use a new --out")
    else:
        from fetchbench_ms.utils.io import atomic_write_text

        atomic_write_text(config_path, json.dumps(config, indent=1, sort_keys=True) + "\n")
    todo = [t for t in ids if not task_path(out, t).exists()]
    workers = max(1, min(args.workers or os.cpu_count() or 1, len(todo) or 1))
    print(f"{len(ids)} tasks, {len(todo)} to label, {workers} workers", flush=True)
    t_start = time.time()
    done, queries = 0, 0
    if todo:
        ctx = mp.get_context("spawn")
        tasks, results = ctx.Queue(), ctx.Queue()
        for task_id in todo + [None] * workers:
            tasks.put(task_id)
        procs = [ctx.Process(target=_worker, args=(args, tasks, t_start, results)) for _ in range(workers)]
        for p in procs:
            p.start()
        running = len(procs)
        while running:
            try:
                item = results.get(timeout=60)
            except queue_module.Empty:  # a worker that died (killed, out of memory) sends nothing
                if not any(p.is_alive() for p in procs):
                    break
                continue
            if item is None:
                running -= 1
                continue
            done += 1
            task_id, share, count, sec = item
            queries += count
            print(f"{task_id} collide {share:.2f} render {sec[0]:.2f}s grid {sec[1]:.2f}s ik {sec[2]:.2f}s "
                  f"labels {sec[3]:.2f}s [{done}/{len(todo)} in {time.time() - t_start:.0f}s]", flush=True)
        for p in procs:
            p.join()
        wall = time.time() - t_start
        if done:
            print(f"labelled {done} tasks, {queries} queries in {wall:.0f} s with {workers} workers: "
                  f"{queries / (workers * wall / 60):.0f} labelled queries ({done / (workers * wall / 60):.2f} tasks) "
                  "per core-minute", flush=True)
    left = [t for t in ids if not task_path(out, t).exists()]
    print(f"done: {len(ids) - len(left)} of {len(ids)} tasks labelled in {out}" + (" (re-run to continue)" if left else ""),
          flush=True)
    if left:
        return None
    manifest = write_manifest(out, config)
    print(f"manifest {out / 'manifest.json'}: {manifest['tasks']} tasks, {manifest['queries']} queries, "
          f"sha256 {manifest['sha256'][:16]}", flush=True)
    return manifest


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))
