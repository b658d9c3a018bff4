"""The training-data commands of the grasp network and the collision network on tiny slices:
baselines/contact_graspnet/task_views.py (views of train tasks through their own cameras,
scene-consistent labels), train.py reading them (alone and mixed, checkpoint selection,
torch DDP over 2 CPU processes with gloo), baselines/mppi_collision/labels.py (sharded,
resumable, manifest). Each makes real views / labels of real tasks (an env per process);
all but the refusals are marked slow (``pytest -m slow tests/test_training_data_at_scale.py``)."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from script_modules import load_script

ROOT = Path(__file__).resolve().parents[1]
CGN = ROOT / "baselines" / "contact_graspnet"
MPPI = ROOT / "baselines" / "mppi_collision"


def load(path: Path, name: str):
    """A baselines script as a module (they are scripts, not a package)."""
    return load_script(path, name)


@pytest.fixture(scope="module")
def views_module():
    """task_views.py imported by its own name (its spawned workers import it so)."""
    sys.path.insert(0, str(CGN))
    import task_views

    return task_views


@pytest.fixture(scope="module")
def train_views(views_module, tmp_path_factory):
    """Views of train tasks 0:2 (one shard each, 1,024 points: the --tiny trainer's count)."""
    out = tmp_path_factory.mktemp("task_views") / "train"
    args = views_module.Args(suite="train", tasks="0:2", out=str(out), num_points=1024, shard_tasks=1, workers=2)
    result = views_module.main(args)
    return args, result


@pytest.mark.slow  # ~2.5 min on a busy 2-core machine: an env per worker, two tasks made twice
def test_task_views_are_sharded_resumable_and_the_same_bytes_per_seed(views_module, train_views, capsys):
    args, result = train_views
    out = Path(args.out)
    manifest = result["manifest"]
    assert [s["file"] for s in manifest["shards"]] == ["shard-00000.npz", "shard-00001.npz"]
    assert manifest["tasks"] == 2 and manifest["views"] == sum(m["views"] for m in result["made"]) >= 2
    with np.load(out / "shard-00001.npz") as z:
        assert z["points"].shape[1:] == (1024, 3) and z["points"].dtype == np.float32
        assert set(z["task_id"]) == {"train/0001"}
        assert len(z["pos_index"]) == z["pos_offset"][-1] > 0  # some points carry grasps
        first = (out / "shard-00001.npz").read_bytes()
    # a shard lost (or never finished) is made again by the same command: the same bytes
    (out / "shard-00001.npz").unlink()
    again = views_module.main(args)
    assert [m["index"] for m in again["made"]] == [1]
    assert (out / "shard-00001.npz").read_bytes() == first
    assert again["manifest"]["sha256"] == manifest["sha256"]
    assert "views and" in capsys.readouterr().out  # the per-core-minute line
    # other flags into the same folder: refused, nothing written
    with pytest.raises(SystemExit) as stop:
        views_module.main(views_module.Args(**{**vars(args), "positive_radius": 0.01}))
    assert stop.value.code == 2


@pytest.mark.slow  # ~3 min on a busy 2-core machine: every grasp of three objects against the world
def test_a_view_is_the_evaluation_crop_and_no_label_is_a_colliding_grasp(views_module):
    """The labels of train/0000's views, checked against the task's oracle world: every
    positive point's grasp stays out of the furniture and of every object but the one it is
    on; grasps were dropped (the check is not empty) and each one dropped collides."""
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.grasp_prediction.predict import T_CGN_HAND
    from fetchbench_ms.grasp_labels import load_grasps
    from fetchbench_ms.planning.world_models import mesh_world, object_poses_base

    train = views_module._trainer()
    env = gym.make("FetchBench-v0", obs_mode="pointcloud", task_suite="train", control_mode="pd_joint_pos")
    args = views_module.Args(num_points=4096, views_per_task=3, max_grasps=10**6)  # every grasp tested
    views = views_module.task_views(env, "train/0000", args)
    world = mesh_world(env)
    task = env.unwrapped.tasks[0]
    assert views[0]["object_id"] == task.target.object_id  # view 0 is the crop inference makes
    groups = {p.object_id: ("target" if k == task.target_index else f"object:{k}") for k, p in enumerate(task.objects)}
    checked = 0
    for view in views:
        T = np.tile(np.eye(4), (len(view["pos_index"]), 1, 1))
        T[:, :3, :] = view["pos_grasp"].astype(np.float64)
        T[:, :3, 3] += view["mean"]
        T_base_hand = T @ np.linalg.inv(train.T_HAND_CGN)  # the hand (or its half-turn: the same open hand)
        assert np.allclose(train.T_HAND_CGN @ T_CGN_HAND, np.eye(4))
        points = view["points"][view["pos_index"]] + view["mean"]
        owner = views_module.object_owner(points, world, len(task.objects), task.target_index)
        assert (owner >= 0).all()  # positives lie on objects, never on furniture
        for k in np.unique(owner):
            group = "target" if k == task.target_index else f"object:{k}"
            hands = T_base_hand[owner == k]
            # a label is the hand or its half-turn about the approach (the other finger's contact)
            turned = hands @ np.diag([-1.0, -1.0, 1.0, 1.0])
            collides = views_module.hand_collides(world, hands, (group,))
            assert not (collides & views_module.hand_collides(world, turned, (group,))).any()
            checked += len(hands)
        # the dropped grasps of the view's object do collide
        k = list(groups).index(view["object_id"])
        grasps = load_grasps(view["object_id"]).successful
        T_all = object_poses_base(env)[k][None] @ grasps.T_object_hand
        hit = views_module.hand_collides(world, T_all, (groups[view["object_id"]],))
        assert hit.sum() == view["grasps_total"] - view["grasps_kept"]
    assert checked > 0 and any(v["grasps_kept"] < v["grasps_total"] for v in views)
    env.close()


@pytest.mark.slow  # ~1 min: every grasp of a task's objects against its world, twice
def test_the_hand_test_in_clusters_gives_the_flat_tests_verdicts(views_module):
    """hand_collides tests the hand's points in clusters of nearby points (a faster broad
    phase); over every verified grasp of train/0000's objects it answers as the flat test of
    the annotation's hand points does, and collisions and free grasps both occur."""
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.grasp_labels import load_grasps
    from fetchbench_ms.planning.world_models import mesh_world, object_poses_base

    local = views_module._trainer().hand_points()
    ordered = views_module._hand_points()
    assert len(ordered) % 2 ** views_module.HAND_CLUSTER_DEPTH == 0
    assert np.array_equal(np.unique(ordered, axis=0), np.unique(local, axis=0))  # the same points, reordered
    runs = ordered.reshape(2 ** views_module.HAND_CLUSTER_DEPTH, -1, 3)
    run_radius = np.linalg.norm(runs - runs.mean(axis=1, keepdims=True), axis=2).max(axis=1)
    assert run_radius.max() < 0.5 * np.linalg.norm(local - local.mean(axis=0), axis=1).max()  # runs are compact
    env = gym.make("FetchBench-v0", obs_mode="pointcloud", task_suite="train", control_mode="pd_joint_pos")
    env.reset(seed=0, options={"task_id": "train/0000"})
    world = mesh_world(env)
    task = env.unwrapped.tasks[0]
    verdicts = 0
    for k, (placement, T_base_object) in enumerate(zip(task.objects, object_poses_base(env))):
        T_base_hand = T_base_object[None] @ load_grasps(placement.object_id).successful.T_object_hand
        group = ("target" if k == task.target_index else f"object:{k}",)
        points = np.einsum("nij,kj->nki", T_base_hand[:, :3, :3], local) + T_base_hand[:, None, :3, 3]
        flat = (world.distance(points.reshape(-1, 3), 0.01, group).numpy().reshape(len(T_base_hand), -1)
                < -views_module.COLLISION_DEPTH).any(axis=1)
        clustered = views_module.hand_collides(world, T_base_hand, group)
        assert np.array_equal(clustered, flat), placement.object_id
        verdicts += len(flat)
        hits = int(flat.sum()) if k == 0 else hits + int(flat.sum())
    assert 0 < hits < verdicts
    env.close()


def test_test_tasks_and_test_objects_are_refused_before_anything_is_written(views_module, tmp_path, monkeypatch):
    from fetchbench_ms.tasks import splits

    for suite in ("test", "smoke"):
        with pytest.raises(SystemExit) as stop:
            views_module.main(views_module.Args(suite=suite, tasks="0:1", out=str(tmp_path / suite)))
        assert stop.value.code == 2 and not (tmp_path / suite).exists()
    # a train task whose object were of the test split
    from fetchbench_ms.tasks.suite import load_suite

    object_id = load_suite("train").get(load_suite("train").ids()[0]).objects[0].object_id
    monkeypatch.setattr(splits, "is_test_object", lambda o: o == object_id)
    with pytest.raises(SystemExit) as stop:
        views_module.main(views_module.Args(suite="train", tasks="0:1", out=str(tmp_path / "objects")))
    assert stop.value.code == 2 and not (tmp_path / "objects").exists()


@pytest.fixture(scope="module")
def val_views(views_module, tmp_path_factory):
    out = tmp_path_factory.mktemp("task_views") / "val"
    views_module.main(views_module.Args(suite="val", tasks="0:1", out=str(out), num_points=1024, shard_tasks=1,
                                        workers=1))
    return out


def run_trainer(tmp_path: Path, *flags: str, processes: int = 1) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    launcher = ([sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc-per-node={processes}"]
                if processes > 1 else [sys.executable])
    command = [*launcher, str(CGN / "train.py"), "--run-dir", str(tmp_path / "run"), "--tiny", "--device", "cpu",
               "--val-views", "2", "--batch-size", "2", "--log-every", "1", "--workers", "1", "--export",
               "--export-dir", str(tmp_path / "export"), *flags]
    return subprocess.run(command, env=env, capture_output=True, text=True, timeout=1200, cwd=ROOT)


@pytest.mark.slow  # ~45 s (with val task views made)
def test_trainer_on_task_views_alone_chooses_the_checkpoint_on_val_task_views(train_views, val_views, tmp_path):
    args, _ = train_views
    done = run_trainer(tmp_path, "--views", "0", "--task-views", args.out, "--val-task-views", str(val_views),
                       "--steps", "4", "--val-every", "2", "--warmup-steps", "1")
    assert done.returncode == 0, done.stderr[-3000:]
    meta = json.loads((tmp_path / "export" / "cgn_ours.json").read_text())
    assert "top10_pose_agree" in meta["val"] and "top10_pose_agree" in meta["val_tasks"] and meta["val_tasks_init"]
    assert meta["selected"]["step"] in (2, 4) and "val-suite task views" in meta["selected"]["rule"]
    assert "--task-views" in meta["command"] and "--val-every 2" in meta["command"]
    log = (tmp_path / "run" / "log.txt").read_text()
    assert "validation at step 2" in log and "task views:" in log


@pytest.mark.slow  # ~20 s past the views
def test_trainer_data_parallel_over_two_gloo_processes(train_views, val_views, tmp_path):
    """torchrun with 2 CPU processes: table-top and task views mixed, the batch split between
    the processes; process 0 alone writes the log, checkpoint and export."""
    args, _ = train_views
    done = run_trainer(tmp_path, "--views", "2", "--task-views", args.out, "--steps", "3", "--warmup-steps", "1",
                       processes=2)
    assert done.returncode == 0, done.stderr[-3000:]
    log = (tmp_path / "run" / "log.txt").read_text()
    assert "(2 processes, gloo)" in log and "step 3 loss" in log
    assert log.count("call:") == 1  # one writer
    import torch

    saved = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    assert saved["step"] == 3 and (tmp_path / "export" / "cgn_ours.pt").is_file()


@pytest.mark.slow  # ~1.5 min on a busy 2-core machine
def test_collision_labels_are_sharded_resumable_and_hashed_as_the_trainer_hashes(tmp_path, capsys):
    sys.path.insert(0, str(MPPI))
    import labels  # by its own name: its spawned workers import it so

    args = labels.Args(suite="train", tasks="0:2", out=str(tmp_path / "labels"), configs=200, workers=2)
    manifest = labels.main(args)
    out = Path(args.out)
    assert manifest["tasks"] == 2 and manifest["queries"] == 400
    assert "labelled queries" in capsys.readouterr().out  # the per-core-minute line
    first = (out / "train_0001.npz").read_bytes()
    (out / "train_0001.npz").unlink()
    again = labels.main(labels.Args(**{**vars(args), "workers": 1}))
    assert (out / "train_0001.npz").read_bytes() == first and again["sha256"] == manifest["sha256"]
    mppi_train = load(MPPI / "train.py", "mppi_train")
    assert mppi_train.Tasks(str(out), "cpu").hash == manifest["sha256"]
    with pytest.raises(SystemExit):
        labels.main(labels.Args(**{**vars(args), "configs": 300}))
