"""The torch distances agree with the collision checker; the trajectory optimiser plans
around the shelf (where the straight line collides) a path the exact meshes accept;
batched and single plans agree."""
import dataclasses

import numpy as np
import pytest
import torch
import trimesh

from fetchbench_ms.planning.checker import Attachment, CollisionChecker
from fetchbench_ms.planning.demo_worlds import hand_pose, shelf_boxes, shelf_worlds
from fetchbench_ms.planning.distance import GRID_EXACT_BAND, GRID_RESOLUTION, GRID_TRUNCATION, TorchRobot, TorchWorld
from fetchbench_ms.planning.exact import ExactRobot
from fetchbench_ms.planning.ik import solve_ik
from fetchbench_ms.planning.robot import FINGER_OPEN, Q_DEFAULT
from fetchbench_ms.planning.rrt import densify
from fetchbench_ms.planning.trajopt import TrajoptConfig, plan_trajopt, plan_trajopt_batch, plan_trajopt_to_pose
from fetchbench_ms.planning.world import CollisionWorld, ConvexSet, PointCloudField


@pytest.fixture(scope="module")
def worlds():
    """The shelf with two convex objects on its lower board, and the same shelf as a 5 mm cloud."""
    world, exact = shelf_worlds()
    world.add("target", ConvexSet([trimesh.creation.box([0.06, 0.06, 0.12]).apply_translation([0.65, 0.1, 0.07])]))
    world.add("object:1", ConvexSet([trimesh.creation.icosphere(radius=0.04).apply_translation([0.66, -0.1, 0.05])]))
    points = [trimesh.sample.sample_surface_even(trimesh.creation.box(size).apply_transform(T), 3000, seed=1)[0]
              for _, T, size in shelf_boxes()]
    cloud = CollisionWorld().add("scene", PointCloudField(np.concatenate(points)))
    return world, exact, cloud


def _checkers(robot, worlds):
    world, _, cloud = worlds
    carried = Attachment.from_convex_parts([trimesh.creation.box([0.05, 0.05, 0.1]).apply_translation([0, 0, 0.15])])
    return [CollisionChecker(robot, world, exact_self_collision=False),
            CollisionChecker(robot, world, exclude=("target",), exact_self_collision=False),
            CollisionChecker(robot, cloud, exact_self_collision=False),
            CollisionChecker(robot, world, finger=0.02, exclude=("target",), attachment=carried,
                             ignore_links=("panda_leftfinger", "panda_rightfinger"), exact_self_collision=False)]


def test_distance_agrees_with_the_checker(robot, worlds):
    """Mesh worlds: the same numbers; the cloud's grid: within a cell; the verdict of
    every configuration (world, self spheres, carried object) the same outside a band."""
    checkers = _checkers(robot, worlds)
    rng = np.random.default_rng(0)
    # Half uniform in the limits, half near the default pose reaching into the shelf.
    q = np.concatenate([rng.uniform(robot.q_min, robot.q_max, (100, 7)), Q_DEFAULT + rng.normal(0, 0.5, (100, 7))])
    q = np.clip(q, robot.q_min, robot.q_max)
    tw = TorchWorld([c.world for c in checkers], [c.exclude for c in checkers])
    tr = TorchRobot(robot, checkers)
    q_t = torch.as_tensor(np.broadcast_to(q, (len(checkers),) + q.shape).copy(), dtype=torch.float32)
    centers, _ = tr.spheres(q_t)
    d = tw.distance(centers.reshape(len(checkers), -1, 3), GRID_TRUNCATION).numpy()
    clearance = tr.clearance(q_t, tw, GRID_TRUNCATION).numpy()
    for i, checker in enumerate(checkers):
        ref = checker.world.distance(centers[i].reshape(-1, 3).double(), GRID_TRUNCATION, checker.exclude).numpy()
        # The cloud's grid is exact at its vertices within GRID_EXACT_BAND of the cloud,
        # a lower bound beyond; trilinear in between.
        near = ref < (GRID_EXACT_BAND - GRID_RESOLUTION if i == 2 else GRID_TRUNCATION - 0.02)
        assert near.sum() > 500
        err = np.abs(ref - d[i])[near]
        tolerance = GRID_RESOLUTION if i == 2 else 1e-5
        assert err.max() < tolerance and np.median(err) < tolerance / 5, (i, err.max())
        ref_clear = checker.clearance(q).numpy()
        decided = np.abs(ref_clear) > (GRID_RESOLUTION if i == 2 else 1e-4)
        assert ((ref_clear > 0) == (clearance[i] > 0))[decided].all(), i
        assert (ref_clear < 0).sum() > 20 and (ref_clear > 0).sum() > 20  # both verdicts are tested


def test_distance_is_batched_and_differentiable(robot, worlds):
    checkers = _checkers(robot, worlds)
    q = torch.as_tensor(np.random.default_rng(1).uniform(robot.q_min, robot.q_max, (1, 50, 7)), dtype=torch.float32)
    both = TorchRobot(robot, checkers[:2]).clearance(q.expand(2, 50, 7), TorchWorld([c.world for c in checkers[:2]],
                                                                                   [c.exclude for c in checkers[:2]]))
    for i in range(2):
        one = TorchRobot(robot, checkers[i:i + 1]).clearance(q, TorchWorld([checkers[i].world], [checkers[i].exclude]))
        assert torch.allclose(both[i], one[0], atol=1e-6)
    tw = TorchWorld([worlds[0], worlds[2]])
    points = torch.tensor([[[0.7, 0.0, 0.31]], [[0.7, 0.0, 0.33]]], requires_grad=True)  # above the middle board
    d = tw.distance(points)
    d.sum().backward()
    assert torch.isfinite(points.grad).all()
    assert points.grad[0, 0, 2] > 0.5 and points.grad[1, 0, 2] > 0.5  # moving up moves away from the board


def test_trajopt_plans_into_the_shelf_collision_free_on_exact_meshes(robot, shelf_problem):
    checker, exact, goals = shelf_problem
    assert not any(checker.motion_valid(Q_DEFAULT, g) for g in goals)  # the straight line collides
    result = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(rrt_fallback=False, device="cpu"))
    assert result.success and result.status == "solved" and result.planner == "trajopt", result.status
    assert np.allclose(result.path[0], Q_DEFAULT) and np.allclose(result.path[-1], goals[result.goal_index])
    dense = densify(result.path, 0.01)
    exact_robot = ExactRobot(robot)
    collisions = [exact_robot.world_collisions(q, exact, FINGER_OPEN) for q in dense]
    assert not any(collisions), next(c for c in collisions if c)
    assert robot.within_limits(dense).all()


def test_trajopt_to_a_pose_goal_reaches_it(robot, shelf_problem):
    checker = shelf_problem[0]
    target = hand_pose([0.68, -0.1, 0.12])
    result = plan_trajopt_to_pose(checker, Q_DEFAULT, target, config=TrajoptConfig(rrt_fallback=False, device="cpu"))
    assert result.success and result.goal_index == 0, result.status
    T_end = robot.tcp_pose(result.path[-1][None])[0].numpy()
    assert np.linalg.norm(T_end[:3, 3] - target[:3, 3]) < 0.003
    assert checker.valid(densify(result.path, 0.02)).all()


def test_trajopt_batched_and_single_agree(robot, shelf_problem):
    checker, _, goals = shelf_problem
    cfg = TrajoptConfig(rrt_fallback=False, device="cpu")
    free = hand_pose([0.3, 0.3, 0.5], approach=(0, 0, -1))
    other = solve_ik(robot, free, checker=checker, q_seed=Q_DEFAULT, n_seeds=16, rng=np.random.default_rng(2)).q[:2]
    problems = [(checker, Q_DEFAULT, goals), (checker, Q_DEFAULT, other)]
    batch = plan_trajopt_batch(problems, config=cfg)
    single = plan_trajopt(checker, Q_DEFAULT, goals, config=cfg)
    assert batch[0].status == single.status == "solved" and batch[1].success
    assert batch[0].goal_index == single.goal_index
    assert len(batch[0].path) == len(single.path) and np.allclose(batch[0].path, single.path, atol=1e-3)


def test_ga_mesh_trajopt_runs_a_smoke_task_end_to_end(tmp_path, monkeypatch):
    """``fetchbench eval --method ga-mesh-trajopt --suite smoke --tasks 0:1`` on the CPU (~40 s)."""
    import json

    from fetchbench_ms.cli import main

    monkeypatch.setenv("FETCHBENCH_TRAJOPT_DEVICE", "cpu")
    assert main(["eval", "--method", "ga-mesh-trajopt", "--suite", "smoke", "--tasks", "0:1",
                 "--pipeline", "ours", "--out", str(tmp_path)]) == 0
    record = json.loads((tmp_path / "results.jsonl").read_text().splitlines()[0])
    assert not record.get("error"), record["error"]
    assert record["phases"]["pregrasp_plan"] and record["phases"]["retrieval_plan"], record["notes"]
    assert record["success"], record["notes"]


def _trajectory_costs(robot, worlds):
    """The optimiser's costs (``trajopt_costs.TrajectoryCosts``) of the four checkers' problems, its
    robot and config."""
    from fetchbench_ms.planning.trajopt_costs import TrajectoryCosts

    checkers = _checkers(robot, worlds)
    # three collision points a segment (FULL_COUNTS'): more configurations between waypoints,
    # so that the wild trajectories below bring links near two obstacles of a kind
    cfg = TrajoptConfig(device="cpu", collision_substeps=3)
    tw = TorchWorld([c.world for c in checkers], [c.exclude for c in checkers], max_planes=cfg.max_planes)
    tr = TorchRobot(robot, checkers)
    return TrajectoryCosts(tr, tw, cfg, robot.q_min, robot.q_max), tr, cfg


def test_grouped_broad_phase_gives_the_flat_costs_and_gradients(robot, worlds):
    """The link-by-link broad phase (``SphereGroups``) drops only pairs beyond the horizon:
    the trajectory costs and their gradients are bitwise those of the flat sphere test."""
    costs, tr, cfg = _trajectory_costs(robot, worlds)
    checkers = _checkers(robot, worlds)
    rng = np.random.default_rng(3)
    traj = torch.as_tensor(np.clip(Q_DEFAULT + rng.normal(0, 0.6, (len(checkers), 6, 12, 7)), robot.q_min,
                                   robot.q_max), dtype=torch.float32)
    out = []
    for groups in (tr.groups, None):
        tr.groups = groups
        x = traj.clone().requires_grad_(True)
        total, collision = costs(x)
        (grad,) = torch.autograd.grad(total.sum(), x)
        out.append((total.detach(), collision.detach(), grad))
    assert (out[0][1] > 0).all()  # every trajectory touches something: the pairs are tested
    for a, b in zip(*out):
        assert torch.equal(a, b)


def test_sphere_centres_link_by_link_match_the_per_sphere_transform(robot, worlds):
    """``TorchRobot.spheres`` transforms each link's spheres at once; the centres are the
    per-sphere transform's (``PandaModel``'s link poses) up to float rounding."""
    checkers = _checkers(robot, worlds)[:1]
    tr = TorchRobot(robot, checkers)
    q = np.clip(Q_DEFAULT + np.random.default_rng(4).normal(0, 0.5, (20, 7)), robot.q_min, robot.q_max)
    centers, _ = tr.spheres(torch.as_tensor(q[None], dtype=torch.float32))
    gripper = robot.gripper_q(tr.finger).double()
    poses = robot.fk.forward(torch.cat([torch.as_tensor(q), gripper.expand(20, -1)], dim=1))
    sp = robot.spheres
    T = torch.stack([poses[link] for link in sp.links], dim=1)[:, torch.as_tensor(sp.link_index)]
    ref = torch.einsum("nsij,sj->nsi", T[..., :3, :3], torch.as_tensor(sp.centers_link)) + T[..., :3, 3]
    assert torch.allclose(centers[0].double(), ref, atol=1e-5)


def test_pair_cache_gives_the_fresh_costs_and_gradients(robot, worlds):
    """``PairCache`` reuses the broad phase's pairs while the spheres move less than its slack:
    over trajectories that move by small and large steps, the costs and gradients are bitwise
    those of a fresh broad phase, and fewer configurations are searched."""
    from fetchbench_ms.planning.distance import PairCache

    costs, _, cfg = _trajectory_costs(robot, worlds)
    checkers = _checkers(robot, worlds)
    rng = np.random.default_rng(5)
    traj = np.clip(Q_DEFAULT + rng.normal(0, 0.6, (len(checkers), 6, 12, 7)), robot.q_min, robot.q_max)
    cache, unfiltered = PairCache(0.03), PairCache(0.03)
    unfiltered.exact_filter = False  # pairs within the widened horizon by their bounding spheres only
    for step in (0.0, 0.002, 0.002, 0.05, 0.001, 0.3, 0.002):
        moved = traj.copy()
        moved[:, :3] += rng.normal(0, step, moved[:, :3].shape)  # half the trajectories move
        traj = np.clip(moved, robot.q_min, robot.q_max)
        out = []
        for c in (None, cache, unfiltered):
            x = torch.as_tensor(traj, dtype=torch.float32).requires_grad_(True)
            total, collision = costs(x, c)
            (grad,) = torch.autograd.grad(total.sum(), x)
            out.append((total.detach(), collision.detach(), grad))
        assert (out[0][1] > 0).any()
        for a, b, c in zip(*out):
            assert torch.equal(a, b) and torch.equal(a, c)
        assert sum(map(len, cache.keys)) < sum(map(len, unfiltered.keys))
    n = (traj.shape[2] - 1) * cfg.collision_substeps + 1
    assert traj.shape[0] * traj.shape[1] * n < cache.searches < 7 * traj.shape[0] * traj.shape[1] * n


def test_measuring_the_near_pairs_first_gives_the_same_costs_and_gradients(robot, worlds, monkeypatch):
    """The differentiable pass over only the pairs nearer than the cost's horizon (measured
    without gradients first, ``MEASURE_NEAR_FIRST``) gives bitwise the costs and gradients of
    the pass over every broad-phase pair, fresh and through a ``PairCache``; without
    gradients (the particles' costs) the costs are bitwise the same too."""
    from fetchbench_ms.planning import distance
    from fetchbench_ms.planning.distance import PairCache

    costs, _, cfg = _trajectory_costs(robot, worlds)
    checkers = _checkers(robot, worlds)
    rng = np.random.default_rng(6)
    traj = np.clip(Q_DEFAULT + rng.normal(0, 0.6, (len(checkers), 6, 12, 7)), robot.q_min, robot.q_max)
    caches = {True: PairCache(0.03), False: PairCache(0.03)}
    for step in (0.0, 0.002, 0.05):
        traj = np.clip(traj + rng.normal(0, step, traj.shape), robot.q_min, robot.q_max)
        for use_cache in (False, True):
            out = []
            for first in (True, False):
                monkeypatch.setattr(distance, "MEASURE_NEAR_FIRST", first)
                x = torch.as_tensor(traj, dtype=torch.float32).requires_grad_(True)
                total, collision = costs(x, caches[first] if use_cache else None)
                (grad,) = torch.autograd.grad(total.sum(), x)
                out.append((total.detach(), collision.detach(), grad))
            assert (out[0][1] > 0).any()
            for a, b in zip(*out):
                assert torch.equal(a, b)
                assert torch.equal(a.view(torch.int32), b.view(torch.int32))  # zeros' signs too
        with torch.no_grad():  # the particles' costs: the distances the search measured, the same values
            total, collision = costs(torch.as_tensor(traj, dtype=torch.float32))
        assert torch.equal(total, out[0][0]) and torch.equal(collision, out[0][1])


def test_fixed_shape_costs_give_the_sparse_costs_and_gradients(robot, worlds):
    """``trajopt_graph.FixedShapeCosts`` (no pair lists: the shapes a CUDA graph replays)
    gives the sparse costs and gradients up to float rounding on all four worlds (boxes and
    convex parts, a point cloud, a carried object), with no link over the obstacle cap."""
    from fetchbench_ms.planning.trajopt_graph import FixedShapeCosts

    costs, _, cfg = _trajectory_costs(robot, worlds)
    fixed = FixedShapeCosts(costs.robot, costs.world, cfg, costs.q_min, costs.q_max, max_obstacles=16)
    rng = np.random.default_rng(7)
    traj = torch.as_tensor(np.clip(Q_DEFAULT + rng.normal(0, 0.6, (4, 6, 12, 7)), robot.q_min, robot.q_max),
                           dtype=torch.float32)
    out = []
    for c in (costs, fixed):
        x = traj.clone().requires_grad_(True)
        total, collision = c(x)
        (grad,) = torch.autograd.grad(total.sum(), x)
        out.append((total.detach(), collision.detach(), grad))
    assert (out[0][1] > 0).any(dim=1).all()  # every world's trajectories touch something
    for a, b in zip(*out):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-6 * float(a.abs().max()))
    assert fixed.over_cap.tolist() == [0, 0, 0, 0]
    # Wilder trajectories bring links near two obstacles of a kind: a cap of one counts them
    # (and drops pairs: the cost is not higher), a cap of two has room for them (the same cost).
    wild = torch.as_tensor(np.clip(Q_DEFAULT + np.random.default_rng(7).normal(0, 1.0, traj.shape), robot.q_min,
                                   robot.q_max), dtype=torch.float32)
    out = []
    for cap in (1, 2):
        capped = FixedShapeCosts(costs.robot, costs.world, cfg, costs.q_min, costs.q_max, max_obstacles=cap)
        with torch.no_grad():
            out.append((capped(wild)[1], capped.over_cap))
    with torch.no_grad():
        _, reference = costs(wild)
    assert out[0][1].sum() > 0 and (out[0][0] <= reference + 1e-3).all() and not torch.allclose(out[0][0], reference)
    assert out[1][1].sum() == 0 and torch.allclose(out[1][0], reference, rtol=1e-5)


def test_broad_phase_on_the_nearest_bounding_spheres_gives_the_same_costs(robot, worlds):
    """``broad_candidates``: the broad phase measures exactly only the obstacles of the nearest
    bounding spheres. Bounding spheres are never farther than their obstacles, so the costs and
    gradients are those of measuring every obstacle unless more bounding spheres than that are
    within the horizon; those links are counted in ``over_cap``, and their cost is not higher."""
    import dataclasses

    from fetchbench_ms.planning.trajopt_graph import FixedShapeCosts

    costs, _, cfg = _trajectory_costs(robot, worlds)
    assert max(kind.O for kind in costs.world.kinds) > 6  # the candidates are fewer than a kind's obstacles
    traj = torch.as_tensor(np.clip(Q_DEFAULT + np.random.default_rng(7).normal(0, 0.6, (4, 6, 12, 7)), robot.q_min,
                                   robot.q_max), dtype=torch.float32)

    def run(candidates, trajectories):
        fixed = FixedShapeCosts(costs.robot, costs.world, dataclasses.replace(cfg, broad_candidates=candidates),
                                costs.q_min, costs.q_max, max_obstacles=4)
        x = trajectories.clone().requires_grad_(True)
        total, collision = fixed(x)
        (grad,) = torch.autograd.grad(total.sum(), x)
        return total.detach(), collision.detach(), grad, fixed.over_cap.clone()

    every, nearest = run(None, traj), run(6, traj)
    assert (every[1] > 0).any(dim=1).all()
    for a, b in zip(every[:3], nearest[:3]):
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-6 * float(a.abs().max()))
    assert every[3].tolist() == nearest[3].tolist() == [0, 0, 0, 0]
    # fewer candidates (at least max_obstacles: 1 means 4) than the bounding spheres near some
    # links: those are counted, and their cost is never higher
    few = run(1, traj)
    assert few[3].sum() > 0 and (few[1] <= every[1] + 1e-3).all()


def test_baked_grid_reads_the_world_within_half_a_cell_diagonal(robot, worlds, monkeypatch):
    """``baked_grid``: every obstacle of each world (boxes, convex parts, a point cloud, less a
    carried object's group) read through one grid measured at its vertices: within half a cell
    diagonal of the exact distance (it is 1-Lipschitz) up to the truncation, at least about the
    truncation beyond; the grid is measured once per world and resolution."""
    from fetchbench_ms.planning import distance
    from fetchbench_ms.planning.distance import GRID_TRUNCATION, baked_grid_values, grid_shape

    checkers = _checkers(robot, worlds)
    res = 0.03
    args = ([c.world for c in checkers], [c.exclude for c in checkers])
    exact = TorchWorld(*args, max_planes=24)
    baked = TorchWorld(*args, max_planes=24, baked_grid=res)
    assert baked.kinds == [] and tuple(baked.grid.shape) == (len(checkers), 1, *grid_shape(res)[::-1])
    rng = np.random.default_rng(0)
    points = torch.as_tensor(rng.uniform((-0.3, -0.7, -0.1), (1.1, 0.7, 1.3), (len(checkers), 4000, 3)),
                             dtype=torch.float32)
    d_exact, d_baked = exact.distance(points, GRID_TRUNCATION), baked.distance(points, GRID_TRUNCATION)
    tol = 0.5 * np.sqrt(3) * res + 1e-4
    near = d_exact < GRID_TRUNCATION - tol
    assert near.sum(dim=1).min() > 50  # every world has points near its obstacles
    assert float((d_baked - d_exact).abs()[near].max()) <= tol
    assert float(d_baked[~near].min()) >= GRID_TRUNCATION - 2 * tol
    c = checkers[0]
    assert baked_grid_values(c.world, c.exclude, res, max_planes=24) is baked_grid_values(c.world, c.exclude, res,
                                                                                         max_planes=24)
    # the vertices measured in other chunks (a GPU's): the same grid
    fresh = checkers[1]
    fresh.world.__dict__.pop("_baked_grids", None)
    small = baked_grid_values(fresh.world, fresh.exclude, res, max_planes=24)
    fresh.world.__dict__.pop("_baked_grids", None)
    monkeypatch.setitem(distance.BAKED_CHUNK, "cpu", 1000)
    assert torch.equal(baked_grid_values(fresh.world, fresh.exclude, res, max_planes=24), small)


SMALL = dict(n_waypoints=12, seeds=4, opt_iters=25, collision_substeps=2, rrt_fallback=False, device="cpu")


def test_checking_the_first_configurations_first_plans_the_same_with_fewer_computed(robot, shelf_problem):
    """``motion_check_first`` (the direct segments and shortcuts checked first at 16
    configurations spread along them, the seeds' paths at their first 16): the same plan, goal
    and count of checks as whole-segment batches, with fewer configurations computed (the
    shelf's direct segments collide along the way)."""
    checker, _, goals = shelf_problem
    calls = []
    clearance = checker._clearance_parts
    checker._clearance_parts = lambda q, bound=None: (calls.append(len(q)), clearance(q, bound))[1]
    try:
        plans, computed = [], []
        for first in (0, 16):
            k0 = len(calls)
            plans.append(plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(motion_check_first=first, **SMALL)))
            computed.append(sum(calls[k0:]))
    finally:
        del checker._clearance_parts
    whole, first = plans
    assert whole.status == first.status == "solved" and whole.goal_index == first.goal_index
    assert np.array_equal(whole.path, first.path) and whole.n_checked == first.n_checked
    assert computed[0] == whole.n_checked
    assert computed[1] < whole.n_checked


def test_particle_pieces_bound_the_dense_broad_phase_and_change_no_plan(monkeypatch, shelf_problem):
    """``max_dense``: the fixed-shape particle rounds evaluate their trajectories in pieces
    whose broad-phase tensor (configurations x link groups x every padded obstacle's planes)
    stays within it; each trajectory's costs are its own, so the plan is bitwise the same."""
    from fetchbench_ms.planning import trajopt_graph

    checker, _, goals = shelf_problem
    shapes = []
    real = trajopt_graph.FixedShapeCosts.__call__

    def spy(self, traj, cache=None):
        shapes.append((tuple(traj.shape), self.dense_per_config()))
        return real(self, traj, cache)

    monkeypatch.setattr(trajopt_graph.FixedShapeCosts, "__call__", spy)
    whole = plan_trajopt(checker, Q_DEFAULT, goals,
                         config=TrajoptConfig(cuda_graph=True, max_dense=1 << 40, **SMALL))
    n_whole = len(shapes)
    pieces = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(cuda_graph=True, max_dense=1 << 22, **SMALL))
    assert whole.status == pieces.status == "solved" and np.array_equal(whole.path, pieces.path)
    (_, S8, T, _), dense = shapes[0]
    per_config = (T - 1) * SMALL["collision_substeps"] + 1  # the particle rounds' dense configurations
    assert dense == 11 * (192 * 24 + 48 * 3 + 32 * 3)  # the padded world: 11 link groups
    piece = shapes[n_whole][0][1]
    assert piece < S8 and piece * per_config * dense <= 1 << 22 < (piece + 1) * per_config * dense
    assert len(shapes) - n_whole == n_whole + TrajoptConfig().mppi_iters * (-(-S8 // piece) - 1)  # more calls


def test_fixed_shape_loop_plans_as_the_sparse_loop(robot, shelf_problem):
    """The fixed-shape Adam loop (blocks of ten iterations, the convergence test on the
    device; on CUDA it is replayed as a graph) plans the shelf problem as the default sparse
    loop does: the same seed and goal, the same waypoints up to float rounding. With
    ``cuda_graph`` on a CPU it runs the same loop uncaptured: bitwise the same plan."""
    checker, _, goals = shelf_problem
    sparse = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(**SMALL))
    fixed = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(fixed_shape=True, **SMALL))
    graph = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(cuda_graph=True, **SMALL))
    assert sparse.status == fixed.status == "solved" and fixed.goal_index == sparse.goal_index
    assert len(fixed.path) == len(sparse.path) and np.allclose(fixed.path, sparse.path, atol=1e-3)
    assert graph.status == "solved" and np.array_equal(graph.path, fixed.path)
    # the broad phase on the nearest bounding spheres (6 of the shelf's 7 boxes) plans the same
    six = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(fixed_shape=True, max_obstacles=6, **SMALL))
    near = plan_trajopt(checker, Q_DEFAULT, goals,
                        config=TrajoptConfig(fixed_shape=True, max_obstacles=6, broad_candidates=6, **SMALL))
    assert near.status == six.status == "solved" and near.goal_index == six.goal_index
    assert len(near.path) == len(six.path) and np.allclose(near.path, six.path, atol=1e-3)
    # the world through a baked grid: a plan the exact checker passed, the same plan in the graph's loop
    baked = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(fixed_shape=True, world_grid=0.015, **SMALL))
    baked_graph = plan_trajopt(checker, Q_DEFAULT, goals,
                               config=TrajoptConfig(cuda_graph=True, world_grid=0.015, **SMALL))
    assert baked.status == "solved" and baked_graph.status == "solved" and np.array_equal(baked.path, baked_graph.path)
    assert all(checker.motion_valid(a, b, 0.02) for a, b in zip(baked.path[:-1], baked.path[1:]))


def test_compiled_cost_function_plans_as_the_eager_loop(robot, shelf_problem):
    """``compile_backend``: the fixed-shape loop's cost function through ``torch.compile``
    (here AOTAutograd's eager backend: the same tracing and forward/backward split as
    ``inductor``, no compiler needed) plans the shelf problem as the eager loop, to float
    rounding; a cached loop (``cuda_graph``'s bookkeeping on a CPU) reuses its compiled function
    for the next problem of its shapes."""
    import torch._dynamo

    from fetchbench_ms.planning import trajopt_graph

    checker, _, goals = shelf_problem
    eager = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(fixed_shape=True, **SMALL))
    torch._dynamo.reset()
    compiled_cfg = TrajoptConfig(fixed_shape=True, compile_backend="aot_eager", **SMALL)
    compiled = plan_trajopt(checker, Q_DEFAULT, goals, config=compiled_cfg)
    assert compiled.status == eager.status == "solved" and compiled.goal_index == eager.goal_index
    assert len(compiled.path) == len(eager.path) and np.allclose(compiled.path, eager.path, atol=1e-3)
    # the world through a baked grid (grid_sample and its backward) traces too
    grid_cfg = TrajoptConfig(fixed_shape=True, world_grid=0.015, **SMALL)
    grid_eager = plan_trajopt(checker, Q_DEFAULT, goals, config=grid_cfg)
    torch._dynamo.reset()
    grid_compiled = plan_trajopt(checker, Q_DEFAULT, goals,
                                 config=dataclasses.replace(grid_cfg, compile_backend="aot_eager"))
    assert grid_compiled.status == grid_eager.status == "solved"
    assert len(grid_compiled.path) == len(grid_eager.path) and np.allclose(grid_compiled.path, grid_eager.path,
                                                                            atol=1e-3)
    torch._dynamo.reset()
    cache = trajopt_graph.graph_cache(2)
    cache.clear()
    graph_cfg = dataclasses.replace(compiled_cfg, cuda_graph=True, graph_capacity=(16, 4, 8))
    first = plan_trajopt(checker, Q_DEFAULT, goals, config=graph_cfg)
    (loop, *_), = cache.entries.values()
    assert loop.cost_fn is not loop.costs  # the compiled wrapper
    second = plan_trajopt(checker, Q_DEFAULT, goals[::-1].copy(), config=graph_cfg)
    (again, *_), = cache.entries.values()
    assert again is loop and first.status == second.status == "solved"
    cache.clear()
    torch._dynamo.reset()


def test_fixed_shape_loop_stops_at_the_sparse_loops_convergence_test(robot, worlds):
    """``_AdamLoop`` over the sparse costs takes the sparse loop's steps: it stops at the same
    convergence test (a block of ten converged leaves the state before its last step) and
    ends at the same trajectories up to float rounding (its bias corrections are float32
    tensors, the sparse loop's Python floats)."""
    from fetchbench_ms.planning import trajopt_graph
    from fetchbench_ms.planning.trajopt_graph import _AdamLoop

    costs, _, cfg = _trajectory_costs(robot, worlds)
    rng = np.random.default_rng(8)
    traj = torch.as_tensor(np.clip(Q_DEFAULT + rng.normal(0, 0.3, (4, 3, 10, 7)), robot.q_min, robot.q_max),
                           dtype=torch.float32)
    start, goal, interior = traj[:, :, :1], traj[:, :, -1:], traj[:, :, 1:-1]
    for converged, iters in ((0.005, 45), (1.0, 45)):  # 1.0: the second test (iteration 19) stops
        cfg.converged, cfg.opt_iters = converged, iters
        loop = _AdamLoop(costs, interior, start, goal, cfg)
        loop.costs.over_cap = torch.zeros(4, dtype=torch.long)
        blocks = []
        original = loop.block
        loop.block = lambda n, check: (blocks.append(n), original(n, check))
        got = loop.run(False, lambda: None)
        # The sparse loop, as trajopt._optimise writes it.
        x_ref, m, v, previous, ran = interior.clone(), 0 * interior, 0 * interior, float("inf"), iters
        for it in range(iters):
            x = x_ref.detach().requires_grad_(True)
            total, _ = costs(torch.cat([start, x, goal], dim=2))
            (grad,) = torch.autograd.grad(total.sum(), x)
            if it % 10 == 9:
                if float(total.detach().sum()) > (1 - converged) * previous:
                    ran = it + 1  # iterations evaluated; the last one's step not taken
                    break
                previous = float(total.detach().sum())
            m = 0.9 * m + 0.1 * grad
            v = 0.999 * v + 0.001 * grad * grad
            step = cfg.lr * (m / (1 - 0.9 ** (it + 1))) / ((v / (1 - 0.999 ** (it + 1))).sqrt() + 1e-8)
            x_ref = torch.minimum(torch.maximum(x_ref - step, costs.q_min), costs.q_max)
        assert sum(blocks) == ran and (converged < 1 or ran == 20)
        assert torch.allclose(got, x_ref, atol=1e-4)
        assert trajopt_graph.CHECK_EVERY == 10


def test_fixed_shape_warm_start_moves_the_seeds_as_the_sparse_one(robot, shelf_problem):
    """With ``fixed_shape`` the particle warm start scores its particles with the fixed-shape
    costs (no host syncs in its rounds): with no Adam iterations, the warm-started
    trajectories are the default's up to float rounding (the costs agree to rounding, the
    particles are the same draws), on the unpadded world and on the world padded to the
    graph capacities (``cuda_graph``); and the warm start did move them off the seeds."""
    from fetchbench_ms.planning.trajopt import _optimise, _prepare, _seeds

    checker, _, goals = shelf_problem
    out = {}
    padded = dict(cuda_graph=True, graph_capacity=(16, 4, 8))
    for name, extra in (("sparse", {}), ("fixed", dict(fixed_shape=True)), ("padded", padded)):
        cfg = TrajoptConfig(**dict(SMALL, opt_iters=0, mppi_iters=3), **extra)
        pr = _prepare(checker, Q_DEFAULT, goals, 0.0, cfg.resolution, cfg.motion_check_first)
        assert pr.result is None
        out[name] = _optimise([pr], robot, cfg, deadline=float("inf"))
        if extra:
            assert pr.extras["over_cap_warm"] == 0 and pr.extras["over_capacity"] is False
    seeds, _ = _seeds([pr], cfg, robot.q_min, robot.q_max)
    assert np.abs(out["sparse"][0] - seeds).max() > 0.05  # the warm start moved the seeds
    for name in ("fixed", "padded"):
        assert np.allclose(out[name][0], out["sparse"][0], atol=1e-4)
        assert np.allclose(out[name][2], out["sparse"][2], rtol=1e-4)  # the final costs
        assert np.array_equal(out[name][1], out["sparse"][1])


def test_a_captured_block_updates_its_state_in_place_so_loops_can_share_one_pool(robot, shelf_problem):
    """``graph_pool="shared"`` (the default) captures every loop of a process into one memory
    pool. That is safe because a block allocates nothing that outlives it: every tensor it
    reads or writes between replays (the trajectories, Adam's moments, the convergence state,
    the counts) is allocated with the loop and updated in place, so a block leaves its
    storage where it found it. ``"loop"`` gives each graph a pool of its own (None); another
    name is one line naming the choices."""
    from fetchbench_ms.planning import trajopt_graph

    checker, _, goals = shelf_problem
    cfg = TrajoptConfig(cuda_graph=True, graph_capacity=(16, 4, 8), **SMALL)
    assert cfg.graph_pool == "shared" and cfg.graph_pool in trajopt_graph.GRAPH_POOLS
    cache = trajopt_graph.graph_cache(cfg.graph_cache)
    cache.clear()
    plan_trajopt_batch([(checker, Q_DEFAULT, goals)], config=cfg)
    (loop, _, _), = cache.entries.values()
    buffers = loop._state() + [loop.start, loop.goal, loop.block_corrections]
    before = [(t.data_ptr(), t.clone()) for t in buffers]
    loop.load(loop.interior + 0.01, loop.start, loop.goal)  # a new problem's values, then a block
    loop.block(trajopt_graph.CHECK_EVERY, check=True)
    after = loop._state() + [loop.start, loop.goal, loop.block_corrections]
    assert [t.data_ptr() for t in after] == [ptr for ptr, _ in before]
    assert not torch.equal(loop.interior, before[0][1])  # the block did step, in place
    cache.clear()
    assert trajopt_graph.graph_pool("loop", torch.device("cpu")) is None
    with pytest.raises(ValueError, match="unknown graph_pool 'pooled'; valid: shared, loop"):
        trajopt_graph.graph_pool("pooled", torch.device("cpu"))
    with pytest.raises(ValueError, match="unknown graph_pool 'pooled'; valid: shared, loop"):
        TrajoptConfig(graph_pool="pooled")
    with pytest.raises(ValueError, match="certify needs a step floor > 0 rad"):
        TrajoptConfig(certify=0.0)


def test_every_capture_warms_up_on_the_one_side_stream_of_its_device(monkeypatch):
    """torch keeps a cuBLAS and a cuBLASLt workspace for every stream that ran a matrix
    product and never frees them: a side stream per capture grew a worker's CUDA memory by
    64 MB a capture. The warm-up stream is made once per process and device (a stand-in for
    ``torch.cuda.Stream`` here: a CPU has no streams)."""
    from fetchbench_ms.planning import trajopt_graph

    made = []

    class Stream:
        def __init__(self, device=None):
            made.append(device)

    monkeypatch.setattr(torch.cuda, "Stream", Stream)
    monkeypatch.setattr(trajopt_graph, "_WARMUP_STREAMS", {})
    gpu0, gpu1 = torch.device("cuda", 0), torch.device("cuda", 1)
    first = trajopt_graph.warmup_stream(gpu0)
    assert all(trajopt_graph.warmup_stream(gpu0) is first for _ in range(5))
    assert trajopt_graph.warmup_stream(gpu1) is not first
    assert made == [gpu0, gpu1]


def test_cuda_graph_loop_is_reused_across_problems_and_the_cache_stays_bounded(robot, shelf_problem):
    """``cuda_graph`` (on a CPU: the same bookkeeping, uncaptured): the worlds are padded to
    the graph capacities, so two different problems (other scenes, starts and goals) share
    one cached loop; the second only copies its world and seeds into the first one's
    buffers, and plans bitwise as it does from an empty cache, and as the unpadded
    fixed-shape plan up to float rounding. Other shapes (more seeds) get their own loop;
    the cache keeps at most ``graph_cache`` of them."""
    from fetchbench_ms.planning import trajopt_graph

    checker, _, goals = shelf_problem
    # Another scene (the shelf and a box above it), another start, the goals it leaves valid.
    scene, _ = shelf_worlds()
    scene.add("box", ConvexSet([trimesh.creation.box([0.15, 0.15, 0.15]).apply_translation([0.3, 0.3, 0.6])]))
    cluttered = CollisionChecker(robot, scene)
    q_other = np.clip(Q_DEFAULT + 0.05, robot.q_min, robot.q_max)
    other = goals[cluttered.valid(goals)][::-1]
    assert len(other) and not any(cluttered.motion_valid(q_other, g) for g in other)
    first, second = (checker, Q_DEFAULT, goals), (cluttered, q_other, other)
    cfg = TrajoptConfig(cuda_graph=True, graph_cache=2, graph_capacity=(16, 4, 8), **SMALL)
    cache = trajopt_graph.graph_cache(cfg.graph_cache)
    cache.clear()
    n0 = dict(cache.counts)
    a = plan_trajopt_batch([first], config=cfg)[0]
    b = plan_trajopt_batch([second], config=cfg)[0]
    assert a.status == "solved" and b.success
    assert cache.counts["new"] - n0["new"] == 1 and cache.counts["reused"] - n0["reused"] == 1
    # The cached loop's costs are now the second problem's, bitwise, and not the first one's.
    from fetchbench_ms.planning.trajopt_costs import TrajectoryCosts

    (loop, _, _), = cache.entries.values()
    rng = np.random.default_rng(4)
    traj = torch.as_tensor(np.clip(Q_DEFAULT + rng.normal(0, 0.8, (1, 64, cfg.n_waypoints, 7)), robot.q_min,
                                   robot.q_max), dtype=torch.float32)
    fresh = []
    for c in (first[0], cluttered):
        own_world = TorchWorld([c.world], [c.exclude], max_planes=cfg.max_planes)
        own = TrajectoryCosts(TorchRobot(robot, [c]), own_world, cfg, robot.q_min, robot.q_max)
        with torch.no_grad():
            fresh.append(trajopt_graph.fixed_shape_costs(own, cfg)[0](traj)[1])
    with torch.no_grad():
        cached = loop.costs(traj)[1]
    assert torch.equal(cached, fresh[1]) and not torch.equal(cached, fresh[0])
    cache.clear()
    b_fresh = plan_trajopt_batch([second], config=cfg)[0]
    assert b.status == b_fresh.status and b.goal_index == b_fresh.goal_index
    assert np.array_equal(b.path, b_fresh.path)
    b_fixed = plan_trajopt_batch([second], config=TrajoptConfig(fixed_shape=True, **SMALL))[0]
    assert b_fixed.goal_index == b.goal_index and len(b_fixed.path) == len(b.path)
    assert np.allclose(b_fixed.path, b.path, atol=1e-3)
    # A world over a capacity (8 boxes, a capacity of 4) is padded to the next multiple: a
    # shape (and a configuration) of its own, the same plan.
    over = TrajoptConfig(cuda_graph=True, graph_cache=2, graph_capacity=(4, 4, 8), **SMALL)
    a_over = plan_trajopt_batch([first], config=over)[0]
    assert np.array_equal(a_over.path, a.path) and len(cache.entries) == 2
    # Bounded: three more shapes through a cache of two.
    for seeds in (5, 6, 7):
        plan_trajopt_batch([first], config=TrajoptConfig(**dict(vars(cfg), seeds=seeds)))
        assert len(cache.entries) <= 2
    assert cache.counts["evicted"] >= 3
    cache.clear()



# The fixed-shape loop is slow on a CPU (~5 s here, with fewer iterations).
GRAPH_ON_CPU = dict(cuda_graph=True, graph_capacity=(16, 4, 8), mppi_iters=1, opt_iters=10)


@pytest.mark.parametrize("extra", [{}, dict(max_verify=0, rrt_fallback=True),
                                   pytest.param(GRAPH_ON_CPU, marks=pytest.mark.slow)],
                         ids=["sparse", "fallback", "cuda-graph"])
def test_phase_timer_reports_every_phase_and_changes_no_plan(robot, shelf_problem, extra):
    """``phase_times`` (a report only): the plans of a batch (two searched problems, one the
    straight segment solves) are bitwise the untimed ones; each result's ``extras["phase_s"]``
    has the phases it went through, the batch's phases the same for both optimised problems
    (``batch_size`` 2), within the problem's wall time. Off, there is no report. With
    ``cuda_graph`` the timed plan replays the untimed plan's cached loop."""
    from fetchbench_ms.planning.trajopt import BATCH_PHASES

    checker, _, goals = shelf_problem
    near = np.clip(Q_DEFAULT + 0.01, robot.q_min, robot.q_max)[None]
    batch = [(checker, Q_DEFAULT, goals), (checker, Q_DEFAULT, goals[::-1][:2]), (checker, Q_DEFAULT, near)]
    cfg = TrajoptConfig(**dict(SMALL, **extra))
    off = plan_trajopt_batch(batch, config=cfg)
    on = plan_trajopt_batch(batch, config=TrajoptConfig(**dict(vars(cfg), phase_times=True)))
    for a, b in zip(off, on):
        assert (a.status, a.planner, a.goal_index, a.n_checked) == (b.status, b.planner, b.goal_index, b.n_checked)
        assert np.array_equal(a.path, b.path) and "phase_s" not in a.extras
    assert [r.status for r in on] == ["solved", "solved", "direct"]
    assert on[2].extras["phase_s"].keys() == {"prepare"}
    own = {"prepare", "select"} | ({"fallback"} if "max_verify" in extra else set())
    for r in on[:2]:
        phases = dict(r.extras["phase_s"])
        assert phases.pop("batch_size") == 2 and phases.keys() == own | set(BATCH_PHASES)
        assert min(phases.values()) >= 0 and sum(phases.values()) <= r.planning_time + 1e-3
    assert all(on[0].extras["phase_s"][k] == on[1].extras["phase_s"][k] for k in BATCH_PHASES)
    if extra.get("cuda_graph"):
        assert on[0].extras["loop"] == "replayed"



def test_the_pipelines_planner_takes_the_runs_counts_and_loop(monkeypatch):
    """``trajopt.plan`` (the pipeline's entry) plans with the run's ``trajopt_counts`` and
    ``trajopt_loop`` and ``trajopt_certify``, and with the defaults when the run names none."""
    from fetchbench_ms.planning import trajopt
    from fetchbench_ms.planning.rrt import PlanRequest

    seen = []
    monkeypatch.setattr(trajopt, "plan_trajopt", lambda *a, config=None, **k: seen.append(config))
    for options in ({"trajopt_counts": "16x80x3"}, {"trajopt_counts": None, "trajopt_loop": None}, {},
                    {"trajopt_loop": "graph"}, {"trajopt_counts": "16x80x3", "trajopt_loop": "grid"},
                    {"trajopt_loop": "cpu"}, {"trajopt_certify": 0.005, "trajopt_loop": "graph"},
                    {"trajopt_certify": "off"}):
        trajopt.plan(PlanRequest(None, np.zeros(7), np.zeros((1, 7)), seed=0, max_checks=10, checks_per_try=10,
                                 time_limit=1.0, options=options))
    assert seen[0] == TrajoptConfig(**trajopt.FULL_COUNTS)
    assert seen[1] == seen[2] == TrajoptConfig() and (seen[1].seeds, seen[1].opt_iters) == (8, 40)
    assert seen[3] == TrajoptConfig(fixed_shape=True, cuda_graph=True)
    assert seen[4] == TrajoptConfig(**trajopt.FULL_COUNTS, fixed_shape=True, cuda_graph=True, world_grid=0.015)
    assert seen[5] == TrajoptConfig(device="cpu")  # on the CPU even where CUDA is
    assert seen[6] == TrajoptConfig(fixed_shape=True, cuda_graph=True, certify=0.005)
    assert seen[7] == TrajoptConfig(certify=None)


def test_certified_checks_give_paths_free_at_any_finer_step(robot, shelf_problem):
    """``TrajoptConfig.certify``: the optimiser's direct segments, chosen path and shortcuts are
    certified free between their checked configurations (``CollisionChecker.certified``), so
    the plan is valid re-checked ten times finer than it was planned; the default check
    counts only the configurations, and certifying costs midpoints on top."""
    checker, _, goals = shelf_problem
    plain = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(**SMALL))
    sure = plan_trajopt(checker, Q_DEFAULT, goals, config=TrajoptConfig(certify=0.005, **SMALL))
    assert plain.status == sure.status == "solved"
    assert all(checker.motion_valid(a, b, 0.002) for a, b in zip(sure.path[:-1], sure.path[1:]))
    assert sure.n_checked > plain.n_checked
