"""The broad phase skips an obstacle set whose bounding ball is beyond the horizon from the
query points' box: the distances are the same to the bit as without the skip."""
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


def test_skipping_far_sets_changes_no_distance(monkeypatch):
    rng = np.random.default_rng(0)
    world = _world(rng)
    queries = [rng.normal(c, s, (n, 3)) for c, s, n in
               [((0.3, 0.1, 0.5), 0.05, 300), ((0, 0, 0), 0.5, 500), ((1.2, -1, 0.2), 0.02, 40), ((0, 0, 0), 0.0, 1)]]
    queries.append(np.zeros((0, 3)))
    skipped = []
    real_gap = W._box_gap

    def counting_gap(*args):
        gap = real_gap(*args)
        skipped.append(gap)
        return gap

    monkeypatch.setattr(W, "_box_gap", counting_gap)
    fast = [world.distance(q, horizon, exclude) for q in queries for horizon in (0.05, 0.1)
            for exclude in ((), ("object:1",))]
    monkeypatch.setattr(W, "_box_gap", lambda *args: -np.inf)  # never skip
    full = [world.distance(q, horizon, exclude) for q in queries for horizon in (0.05, 0.1)
            for exclude in ((), ("object:1",))]
    assert all(torch.equal(a, b) for a, b in zip(fast, full))
    assert any(g > 0.2 for g in skipped)  # sets were skipped


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
