"""The trajectory optimiser's work that does not change its numbers: the pair cache sorts its
pairs after their exact-distance filter and the clearance takes them unordered, the convex
parts' thinned planes are kept on their sets. Against the reference (every broad-phase pair
list sorted), costs, clearances, gradients and plans are bitwise equal."""
import numpy as np
import pytest
import torch
import trimesh

from fetchbench_ms.planning import distance
from fetchbench_ms.planning.checker import CollisionChecker
from fetchbench_ms.planning.demo_worlds import hand_pose, shelf_worlds
from fetchbench_ms.planning.distance import PairCache, SphereGroups, TorchRobot, TorchWorld
from fetchbench_ms.planning.ik import solve_ik
from fetchbench_ms.planning.robot import Q_DEFAULT
from fetchbench_ms.planning.trajopt import FULL_COUNTS, TrajoptConfig, plan_trajopt
from fetchbench_ms.planning.trajopt_costs import TrajectoryCosts
from fetchbench_ms.planning.world import ConvexSet
from test_planning_trajopt import _checkers, worlds  # noqa: F401 (a fixture)


@pytest.fixture(scope="module")
def checkers(robot, worlds):
    """Boxes and convex parts, a point cloud, a carried object (test_planning_trajopt's worlds)."""
    return _checkers(robot, worlds)


@pytest.fixture
def reference(monkeypatch):
    """A context that sorts every broad-phase pair list (``ordered=True`` everywhere)."""
    def use():
        candidates = SphereGroups.candidates

        def ordered(self, points, radii, kind, horizon, prepared=None, ordered=True):
            return candidates(self, points, radii, kind, horizon, prepared, True)

        monkeypatch.setattr(SphereGroups, "candidates", ordered)
    return use


def _costs(robot, checkers, cfg):
    tw = TorchWorld([c.world for c in checkers], [c.exclude for c in checkers], max_planes=cfg.max_planes)
    return TrajectoryCosts(TorchRobot(robot, checkers), tw, cfg, robot.q_min, robot.q_max)


def _evaluate(robot, checkers, traj, steps):
    """Particle costs, clearances and the cached Adam costs and gradients over a few moves."""
    cfg = TrajoptConfig(device="cpu")
    costs = _costs(robot, checkers, cfg)
    cache, out, rng = PairCache(cfg.broad_phase_slack), [], np.random.default_rng(8)
    for step in steps:
        traj = np.clip(traj + rng.normal(0, step, traj.shape), robot.q_min, robot.q_max)
        x = torch.as_tensor(traj, dtype=torch.float32)
        with torch.no_grad():
            out += list(costs(x))
            out.append(costs.robot.clearance(x.reshape(len(checkers), -1, 7), costs.world, cfg.eta))
        x.requires_grad_(True)
        total, collision = costs(x, cache)
        out += [total.detach(), collision.detach(), torch.autograd.grad(total.sum(), x)[0]]
    return out


def test_unsorted_broad_phase_gives_the_reference_costs_clearances_and_gradients(robot, checkers, reference):
    traj = np.clip(Q_DEFAULT + np.random.default_rng(7).normal(0, 0.6, (len(checkers), 6, 12, 7)), robot.q_min,
                   robot.q_max)
    steps = (0.0, 0.002, 0.05, 0.3)
    new = _evaluate(robot, checkers, traj, steps)
    reference()
    ref = _evaluate(robot, checkers, traj, steps)
    assert (ref[1] > 0).any(dim=1).all()  # every world is touched: pairs are summed
    for a, b in zip(new, ref):
        assert torch.equal(a.view(torch.int32), b.view(torch.int32))  # bitwise, zeros' signs too


@pytest.mark.parametrize("counts", [{}, FULL_COUNTS], ids=["default", "full-counts"])
def test_plans_are_bitwise_the_reference_plans(robot, reference, counts):
    world, _ = shelf_worlds()
    checker = CollisionChecker(robot, world)
    goals = solve_ik(robot, hand_pose([0.68, -0.1, 0.12]), checker=checker, q_seed=Q_DEFAULT, n_seeds=32,
                     rng=np.random.default_rng(1)).q[:4]
    cfg = TrajoptConfig(rrt_fallback=False, device="cpu", **counts)
    new = plan_trajopt(checker, Q_DEFAULT, goals, config=cfg)
    reference()
    ref = plan_trajopt(checker, Q_DEFAULT, goals, config=cfg)
    assert new.status == ref.status == "solved"
    assert new.goal_index == ref.goal_index and np.array_equal(new.path, ref.path)


def test_thinned_planes_are_kept_once_per_set_and_cap(robot):
    world, _ = shelf_worlds()
    part = ConvexSet([trimesh.creation.icosphere(radius=0.04).apply_translation([0.66, -0.1, 0.05])])
    world.add("object", part)
    first = TorchWorld([world], max_planes=24)
    again = TorchWorld([world], max_planes=24)
    assert list(part.__dict__["_fewer_planes"]) == [24]
    wider = TorchWorld([world], max_planes=48)
    assert sorted(part.__dict__["_fewer_planes"]) == [24, 48]  # one entry per cap the planner used
    convex = [[k for k in w.kinds if k.kind == "convex"][0] for w in (first, again, wider)]
    assert torch.equal(convex[0].t["planes"], convex[1].t["planes"])
    fresh = [distance._fewer_planes(p, 24) for p in part.planes.numpy()]
    assert all(np.array_equal(a, b) for a, b in zip(fresh, part.__dict__["_fewer_planes"][24]))
    assert convex[2].t["planes"].shape[2] > convex[0].t["planes"].shape[2] == 24
