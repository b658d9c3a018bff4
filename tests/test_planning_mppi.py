"""The scene-collision network and MPPI (issue 18): the scene grid is the cloud's distance;
a tiny network trained for a few seconds on exact labels of a shelf calls a hand deep in a
board colliding and the start free; MPPI reaches a free goal in an empty world and goes
around the shelf's boards (where the straight line collides) on a path the checker accepts;
the network cost runs from a checkpoint and a missing one is a clear error; ga-mesh-mppi runs
a smoke task end to end on the CPU."""
import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from fetchbench_ms.planning import collision_net
from fetchbench_ms.planning.checker import CollisionChecker
from fetchbench_ms.planning.collision_net import NetConfig, RobotSpheres, SceneCollisionNet, grid_from_uint8, scene_grid
from fetchbench_ms.planning.demo_worlds import hand_pose, shelf_boxes, shelf_worlds
from fetchbench_ms.planning.ik import solve_ik
from fetchbench_ms.planning.mppi import MppiConfig, SceneClearance, plan_mppi
from fetchbench_ms.planning.robot import Q_DEFAULT
from fetchbench_ms.planning.rrt import densify
from fetchbench_ms.planning.world import CollisionWorld, PointCloudField

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "baselines" / "mppi_collision"))
import labels as labelling  # noqa: E402
import train as training  # noqa: E402


@pytest.fixture(scope="module")
def shelf(robot):
    world, _ = shelf_worlds()
    points = np.concatenate([trimesh.sample.sample_surface_even(trimesh.creation.box(size).apply_transform(T), 4000,
                                                                seed=1)[0] for _, T, size in shelf_boxes()])
    checker = CollisionChecker(robot, world)
    goals = solve_ik(robot, hand_pose([0.68, -0.1, 0.12]), checker=checker, q_seed=Q_DEFAULT, n_seeds=32,
                     rng=np.random.default_rng(1)).q[:4]
    return world, points, checker, goals


def test_scene_grid_is_the_clouds_distance(shelf):
    _, points, _, _ = shelf
    grid = torch.as_tensor(scene_grid(points))
    field = PointCloudField(points, collision_net.CLOUD_VOXEL)
    rng = np.random.default_rng(0)
    near = points[rng.integers(len(points), size=300)] + rng.normal(0, 0.02, (300, 3))
    exact = field.distance(torch.as_tensor(near), 0.3).numpy()
    net = SceneCollisionNet(NetConfig((4, 8, 8), 8))
    scene = {"distance": grid.permute(2, 1, 0).reshape(1, -1, 1), "distance_shape": tuple(grid.shape[::-1])}
    s = (torch.as_tensor(near, dtype=torch.float32)[None] - net.lo) / net.span
    read = collision_net._trilinear(scene["distance"], scene["distance_shape"], s)[0, :, 0].numpy()
    # Trilinear between exact vertex values: within about a cell's curvature of the true distance.
    assert np.abs(read - np.minimum(exact, collision_net.TRUNCATION)).max() < 0.012
    assert np.median(np.abs(read - exact)) < 0.003
    assert (grid_from_uint8(collision_net.grid_to_uint8(grid.numpy())) - grid).abs().max() < 0.001


@pytest.fixture(scope="module")
def tiny_net(robot, shelf, tmp_path_factory):
    """A tiny network trained for a few seconds on exact labels of the shelf (its cloud:
    the boards' surfaces), and held-out labelled queries."""
    world, points, _, goals = shelf
    rng = np.random.default_rng(0)
    labeller = labelling.Labeller(world, (), 0.04, None, False)
    q, clearance = labelling.sample_configs(labeller, Q_DEFAULT, goals, 1200, rng)
    mm = np.clip(np.round(np.where(np.isfinite(clearance), clearance, 1.0) * 1000), *labelling.MM_RANGE)
    grid = torch.as_tensor(scene_grid(points))
    batch = lambda rows: dict(grid=grid[None], q=torch.as_tensor(q[rows], dtype=torch.float32)[None],
                              mm=torch.as_tensor(mm[rows], dtype=torch.float32)[None],
                              label=torch.as_tensor(clearance[rows].min(1) < 0)[None],
                              checked=torch.as_tensor(labeller.checked)[None], radii=labeller.radii[None],
                              att=labeller.att_c[None])
    torch.manual_seed(0)
    net = SceneCollisionNet(NetConfig((4, 8, 8), 16))
    spheres = RobotSpheres()
    args = training.Args(cls_weight=0.2)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    held_out = batch(np.arange(1000, 1200))
    with torch.no_grad():
        before, _ = training.loss_fn(training.forward(net, spheres, held_out), held_out, args)
    for step in range(25):
        b = batch(rng.integers(1000, size=256))
        loss, _ = training.loss_fn(training.forward(net, spheres, b), b, args)
        opt.zero_grad()
        loss.backward()
        opt.step()
    net.eval()
    with torch.no_grad():
        after, _ = training.loss_fn(training.forward(net, spheres, held_out), held_out, args)
    path = tmp_path_factory.mktemp("net") / "collision_net.pt"
    collision_net.save_checkpoint(net, path)
    return net, grid, held_out, float(before), float(after), path


def test_labels_are_the_checkers_clearances(robot, shelf):
    """labels.py's sphere clearances are the collision checker's world distances minus the
    radii (the shelf's boxes; within the label range), and its verdict the checker's."""
    world, _, checker, goals = shelf
    labeller = labelling.Labeller(world, (), 0.04, None, False)
    rng = np.random.default_rng(3)
    q = np.clip(Q_DEFAULT + rng.normal(0, 0.6, (60, 7)), robot.q_min, robot.q_max)
    q = np.concatenate([q, goals, labelling._boundary(Q_DEFAULT[None].repeat(len(goals), 0), goals, labeller.collides)])
    label = labeller.clearance(q)[:, : labelling.ARM_SPHERES]
    from fetchbench_ms.planning.robot import WORLD_LINKS

    mask = robot.sphere_mask(WORLD_LINKS)
    centers = robot.sphere_centers(q)[:, mask]
    exact = world.distance(centers.reshape(-1, 3), 0.3).numpy().reshape(len(q), -1) - robot.spheres.radii[mask]
    near = exact < 0.09
    assert near.sum() > 100 and np.abs(label[near] - exact[near]).max() < 1e-4
    assert ((label.min(1) < 0) == (exact.min(1) < 0)).all()
    assert (label.min(1) < 0).any() and (label.min(1) >= 0).any()


def test_labels_from_plane_count_buckets_are_those_of_one_world(robot, shelf, monkeypatch):
    """The labeller measures convex parts in torch worlds by plane count (``plane_buckets``):
    every obstacle lands in exactly one bucket, and the clearances are those of one world
    padded to the largest part, to the bit."""
    from fetchbench_ms.planning.world import ConvexSet

    world, _, _, goals = shelf
    rng = np.random.default_rng(4)
    mixed = CollisionWorld(groups={name: list(sets) for name, sets in world.groups.items()})
    hulls = []
    for k, n in enumerate((8, 60, 300, 900)):  # hulls of ~10 to a few hundred planes
        T = np.eye(4)
        T[:3, 3] = (0.55 + 0.08 * k, -0.25 + 0.15 * k, 0.15)
        hulls.append(trimesh.Trimesh(rng.normal(0, 0.04, (n, 3))).convex_hull.apply_transform(T))
    mixed.add("objects", ConvexSet(hulls))
    counts = mixed.groups["objects"][0].plane_counts()
    buckets = labelling.plane_buckets(mixed)
    assert len(buckets) >= 3 and len(np.unique(np.searchsorted(labelling.PLANE_BUCKETS, counts))) >= 3
    assert sorted(c for b in buckets for s in b.groups.get("objects", []) for c in s.plane_counts()) == sorted(counts)
    q = np.concatenate([np.clip(Q_DEFAULT + rng.normal(0, 0.6, (80, 7)), robot.q_min, robot.q_max), goals])
    bucketed = labelling.Labeller(mixed, (), 0.04, None, False).clearance(q)
    monkeypatch.setattr(labelling, "plane_buckets", lambda w: [w])
    one = labelling.Labeller(mixed, (), 0.04, None, False).clearance(q)
    assert np.array_equal(bucketed, one)
    hulls_only = CollisionWorld()
    hulls_only.add("objects", mixed.groups["objects"][0])
    near_hulls = labelling.Labeller(hulls_only, (), 0.04, None, False).clearance(q) < labelling.MM_RANGE[1] / 1000
    assert near_hulls.sum() > 50  # the hulls' own clearances were among those compared


def test_tiny_network_learns_the_shelf(robot, tiny_net):
    net, grid, held_out, before, after, _ = tiny_net
    assert after < 0.8 * before, (before, after)
    spheres = RobotSpheres()
    with torch.no_grad():
        scene = net.encode(grid)
        c = net.sphere_clearance(scene, spheres.centers(held_out["q"][0]), spheres.radii).amin(-1)
    figures = training.confusion(c.numpy() < 0, held_out["label"][0].numpy())
    assert figures["accuracy"] >= 0.9, figures
    # Hand-made: the hand deep inside the middle board (0.3 m up, 16 cm in), and the start pose.
    inside = solve_ik(robot, hand_pose([0.71, 0.0, 0.3 - 0.1034 + 0.05], approach=(0, 0, -1)), q_seed=Q_DEFAULT,
                      n_seeds=16, rng=np.random.default_rng(0))
    assert inside.found
    q = torch.as_tensor(np.stack([inside.q[0], Q_DEFAULT]), dtype=torch.float32)
    with torch.no_grad():
        p = net.probability(scene, spheres.centers(q), spheres.radii).numpy()
    assert p[0] > 0.9 and p[1] < 0.1, p


def test_mppi_reaches_a_free_goal_in_an_empty_world(robot):
    checker = CollisionChecker(robot, CollisionWorld())
    goal = Q_DEFAULT + np.array([0.8, 0.4, -0.3, 0.5, 0.2, -0.4, 0.6])
    result = plan_mppi(checker, Q_DEFAULT, goal, config=MppiConfig(cost="distance", device="cpu"))
    assert result.success and result.status == "solved" and result.executed and result.planner == "mppi"
    assert np.abs(result.path[-1] - goal).max() <= 0.01 and np.allclose(result.path[0], Q_DEFAULT)
    straight = np.abs(goal - Q_DEFAULT).sum()
    assert np.abs(np.diff(result.path, axis=0)).sum() < 1.5 * straight
    assert robot.within_limits(result.path).all()


def test_mppi_goes_around_the_shelf_boards(robot, shelf):
    _, _, checker, goals = shelf
    assert not any(checker.motion_valid(Q_DEFAULT, g) for g in goals)  # the straight line collides
    moves = []

    def execute(path):  # a robot that lags a little behind: MPPI replans from where it is
        moves.append(path)
        return path[-1] + np.clip(path[0] - path[-1], -0.002, 0.002)

    result = plan_mppi(checker, Q_DEFAULT, goals, execute, MppiConfig(cost="distance", device="cpu"))
    assert result.status == "solved", result
    assert len(moves) >= 2  # receding horizon: several executed pieces
    assert np.abs(result.path[-1] - goals[result.goal_index]).max() <= 0.01 + 0.002
    assert checker.valid(densify(result.path, 0.02)).all()


def test_mppi_with_the_network_cost(robot, shelf, tiny_net):
    _, points, _, _ = shelf
    cloud = CollisionWorld().add("scene", PointCloudField(points))
    checker = CollisionChecker(robot, cloud)
    goal = Q_DEFAULT + np.array([0.5, 0.0, 0.0, 0.3, 0.0, -0.3, 0.0])
    cfg = MppiConfig(cost="network", device="cpu", checkpoint=str(tiny_net[-1]), max_replans=5)
    result = plan_mppi(checker, Q_DEFAULT, goal, config=cfg)
    assert result.status == "solved" and np.abs(result.path[-1] - goal).max() <= 0.01


def test_mppi_reaches_goals_a_cautious_cost_model_calls_in_contact(robot, shelf, monkeypatch):
    """The network at its decision margin (29.5 mm) calls configurations within ~3 cm of
    a surface colliding; a pre-grasp is ~4 cm from its target, near the boards. Without the
    goal credit and the exact final approach MPPI hovered outside that fence until its replans
    ran out (on val: 0 of 7 first tasks reached the pre-grasp); with them it reaches the goal on
    a path the exact checker passes."""
    _, _, checker, goals = shelf
    goals = goals[:3]  # within 2 cm of a board (the fourth has 3.6 cm)
    exact_clearance = SceneClearance.clearance
    monkeypatch.setattr(SceneClearance, "clearance", lambda self, q: exact_clearance(self, q) - 0.02)
    cautious = SceneClearance(checker, "distance", "cpu").clearance(torch.as_tensor(goals, dtype=torch.float32))
    assert checker.valid(goals).all() and (cautious < 0).all()  # free, and "in contact" for the cost model
    cfg = MppiConfig(cost="distance", device="cpu", max_replans=12)
    fenced = plan_mppi(checker, Q_DEFAULT, goals, config=dataclasses.replace(cfg, goal_region=0, exact_snap_distance=0))
    assert fenced.status == "budget"  # replans ran out: a count budget, never "timeout"
    # Judged over three sampling seeds: whether one seed's particles stall in front of the
    # fence hangs on the last bits of the float arithmetic (seed 0 solves on the machine
    # this was written on and stalls on an AMD EPYC; seeds 1-11 solve on both).
    results = [plan_mppi(checker, Q_DEFAULT, goals, config=dataclasses.replace(cfg, seed=seed)) for seed in (0, 1, 2)]
    solved = [r for r in results if r.status == "solved"]
    assert len(solved) >= 2, [r.status for r in results]
    for result in solved:
        assert np.abs(result.path[-1] - goals[result.goal_index]).max() <= 0.01
        assert checker.valid(densify(result.path, 0.02)).all()


def test_missing_checkpoint_is_a_clear_error(robot, tmp_path, monkeypatch):
    from fetchbench_ms.evaluation.methods import resolve_run

    monkeypatch.setattr(collision_net, "checkpoint_path", lambda: tmp_path / "none.pt")
    collision_net.load_collision_net.cache_clear()
    with pytest.raises(FileNotFoundError, match="baselines/mppi_collision"):
        resolve_run("ga-ptd-mppi")
    with pytest.raises(FileNotFoundError, match="cost='distance'"):
        plan_mppi(CollisionChecker(robot, CollisionWorld().add("scene", PointCloudField(np.zeros((1, 3))))),
                  Q_DEFAULT, Q_DEFAULT + 0.1, config=MppiConfig(cost="network", device="cpu"))
    with pytest.raises(ValueError, match="point-cloud world"):  # the network reads clouds, not meshes
        plan_mppi(CollisionChecker(robot, shelf_worlds()[0]), Q_DEFAULT, Q_DEFAULT + 0.1,
                  config=MppiConfig(cost="network", device="cpu"))
    with pytest.raises(ValueError, match="valid: network, distance"):
        MppiConfig(cost="mesh")
    collision_net.load_collision_net.cache_clear()


def test_ga_mesh_mppi_runs_a_smoke_task_end_to_end(tmp_path, monkeypatch):
    """``fetchbench eval --method ga-mesh-mppi --suite smoke --tasks 0:1`` on the CPU (~50 s)."""
    import json

    from fetchbench_ms.cli import main

    monkeypatch.setenv("FETCHBENCH_MPPI_DEVICE", "cpu")
    assert main(["eval", "--method", "ga-mesh-mppi", "--suite", "smoke", "--tasks", "0:1",
                 "--pipeline", "ours", "--out", str(tmp_path)]) == 0
    record = json.loads((tmp_path / "results.jsonl").read_text().splitlines()[0])
    assert not record.get("error"), record["error"]
    assert record["phases"]["pregrasp_plan"] and record["phases"]["retrieval_plan"], record["notes"]
    assert record["success"], record["notes"]
