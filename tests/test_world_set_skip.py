"""The broad phase measures a point against a set's members only when the point is within the
horizon of the set's one bounding ball: the distances below the horizon are the same to the bit
as measuring every pair."""
import numpy as np
import pytest
import torch
import trimesh

from fetchbench_ms.planning import world as W


def _world(rng) -> W.CollisionWorld:
    world = W.CollisionWorld()
    for k in range(6):
        T = np.eye(4)
        T[:3, 3] = rng.uniform(-1.5, 1.5, 3)
        world.add("scene", W.box_set(T[None], rng.uniform(0.02, 0.4, (1, 3))))
        T2 = T.copy()
        T2[:3, 3] += rng.uniform(-0.3, 0.3, 3)
        world.add(f"object:{k}", W.ConvexSet([trimesh.creation.box(rng.uniform(0.03, 0.2, 3)).apply_transform(T2)]))
    world.add("scene", W.CylinderSet(np.eye(4)[None], [0.05], [0.3]))
    return world


def _every_pair(world: W.CollisionWorld, points: np.ndarray, exclude) -> torch.Tensor:
    """The reference: every point measured against every member of every included set."""
    points = torch.as_tensor(points, dtype=torch.float64).reshape(-1, 3)
    out = torch.full((len(points),), W.FAR, dtype=torch.float64)
    for name, sets in world.groups.items():
        if name in exclude or not len(points):
            continue
        for s in sets:
            idx_p, idx_o = (g.reshape(-1) for g in torch.meshgrid(torch.arange(len(points)), torch.arange(len(s)),
                                                                   indexing="ij"))
            out = out.scatter_reduce(0, idx_p, s.exact(points, idx_p, idx_o), reduce="amin")
    return out


def test_points_far_from_a_set_are_not_measured_against_it_and_no_distance_changes(monkeypatch):
    """Below the horizon every distance is the every-pair reference's to the bit (the same
    member, the same formula); beyond it none is below the horizon; a point's distance does
    not depend on the other points of its batch; and the sets' bounding balls kept most pairs
    from being measured at all."""
    rng = np.random.default_rng(0)
    world = _world(rng)
    queries = [rng.normal(c, s, (n, 3)) for c, s, n in
               [((0.3, 0.1, 0.5), 0.05, 300), ((0, 0, 0), 0.5, 500), ((1.2, -1, 0.2), 0.02, 40), ((0, 0, 0), 0.0, 1)]]
    queries.append(np.zeros((0, 3)))
    measured = [0]
    for sets in world.groups.values():
        for s in sets:
            exact = s.exact
            monkeypatch.setattr(s, "exact", lambda p, i, o, exact=exact: (measured.__setitem__(0, measured[0] + len(i)),
                                                                          exact(p, i, o))[1])
    pairs = 0
    for q in queries:
        for horizon in (0.05, 0.1):
            for exclude in ((), ("object:1",)):
                got = world.distance(q, horizon, exclude)
                pairs += len(q) * sum(len(s) for n, sets in world.groups.items() if n not in exclude for s in sets)
                measured_before = measured[0]
                ref = _every_pair(world, q, exclude)
                measured[0] = measured_before  # the reference's pairs do not count
                near = ref < horizon
                assert torch.equal(got[near], ref[near])
                assert (got[~near] >= horizon - 1e-9).all()
                if len(q) > 1:  # one point alone, and in its batch: the same bits
                    assert torch.equal(world.distance(q[:1], horizon, exclude), got[:1])
    assert measured[0] < pairs / 10


def test_the_bounding_ball_holds_every_member():
    rng = np.random.default_rng(1)
    centers, radii = torch.as_tensor(rng.normal(size=(20, 3))), torch.as_tensor(rng.uniform(0, 0.5, 20))
    c, r = W.bounding_ball(centers, radii)
    assert ((centers - torch.as_tensor(c)).norm(dim=1) + radii <= r + 1e-12).all()


def _clustered_queries(rng, clusters: int, size: int) -> np.ndarray:
    """Poses of a small rigid point set (a hand's points), many near the obstacles."""
    local = rng.normal(0, 0.04, (size, 3))
    centers = rng.uniform(-1.6, 1.6, (clusters, 3))
    return (centers[:, None] + local[None]).reshape(-1, 3)


def test_the_cluster_broad_phase_gives_the_same_distances_below_the_horizon():
    rng = np.random.default_rng(2)
    world = _world(rng)
    world.add("scene", W.CylinderSet(np.eye(4)[None], [0.08], [0.2], capsule=True))
    points = _clustered_queries(rng, 400, 24)
    for horizon in (0.01, 0.05, 0.3):
        for exclude in ((), ("object:1",)):
            flat = world.distance(points, horizon, exclude)
            clustered = world.distance(points, horizon, exclude, cluster_size=24)
            near = flat < horizon - 1e-6
            assert near.sum() > 20 and (~near).sum() > 20  # both kinds of point are tested
            assert torch.equal(clustered[near], flat[near])  # same obstacle, same formula: same bits
            assert (clustered[~near] >= horizon - 1e-6).all()  # far points stay far


def test_the_cluster_broad_phase_needs_whole_clusters():
    world = _world(np.random.default_rng(3))
    with pytest.raises(ValueError, match="cluster_size 7"):
        world.distance(np.zeros((10, 3)), 0.05, cluster_size=7)
