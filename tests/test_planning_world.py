"""Signed distances of the collision worlds against exact geometry."""
import numpy as np
import pytest
import torch
import trimesh

from fetchbench_ms.planning.world import (BoxSet, CollisionWorld, ConvexSet, CylinderSet, PointCloudField,
                                          obstacle_sets_from_parts, pose_matrix)
from fetchbench_ms.scenes.spec import Part


def _points(n=600, seed=0, scale=0.3):
    return np.random.default_rng(seed).uniform(-scale, scale, (n, 3))


def _all(obstacle_set, points):
    """Exact distance for every (point, first obstacle) pair."""
    p = torch.as_tensor(points)
    idx = torch.arange(len(points))
    return obstacle_set.exact(p, idx, torch.zeros_like(idx)).numpy()


def _true_signed_distance(mesh, points):
    # trimesh: positive inside; ours: negative inside.
    return -trimesh.proximity.signed_distance(mesh, points)


def test_box_distance_is_exact():
    T = pose_matrix([0.02, -0.01, 0.03], [0.9238795, 0.0, 0.3826834, 0.0])
    size = np.array([0.2, 0.1, 0.06])
    d = _all(BoxSet(T[None], size[None] / 2), _points())
    mesh = trimesh.creation.box(size, transform=T)
    assert np.allclose(d, _true_signed_distance(mesh, _points()), atol=1e-6)


@pytest.mark.parametrize("capsule", [False, True])
def test_cylinder_and_capsule_distance(capsule):
    T = pose_matrix([0.0, 0.05, 0.0], [0.7071068, 0.7071068, 0.0, 0.0])
    cyl = CylinderSet(T[None], [0.05], [0.08], capsule=capsule)
    mesh = (trimesh.creation.capsule(height=0.16, radius=0.05, count=[64, 64]) if capsule
            else trimesh.creation.cylinder(radius=0.05, height=0.16, sections=256)).apply_transform(T)
    # Tessellated references sit slightly inside the true surface: compare at 1 mm.
    assert np.allclose(_all(cyl, _points()), _true_signed_distance(mesh, _points()), atol=1e-3)


def test_convex_distance_is_conservative_and_exact_inside():
    hull = trimesh.creation.icosphere(subdivisions=1, radius=0.1)
    hull.apply_transform(pose_matrix([0.03, 0.0, -0.02]))
    d = _all(ConvexSet([hull]), _points(2000))
    true = _true_signed_distance(hull, _points(2000))
    assert np.all(d <= true + 1e-9)  # never claims more clearance than there is
    inside = true < 0
    assert inside.any() and np.all(d[inside] < 0)
    assert np.allclose(d[inside], true[inside], atol=1e-6)


def test_point_cloud_field_is_conservative_and_tight():
    box = trimesh.creation.box((0.2, 0.2, 0.02))
    cloud, _ = trimesh.sample.sample_surface(box, 40000, seed=np.random.default_rng(0))
    field = PointCloudField(cloud, voxel=0.005)
    queries = _points(500, seed=1)
    d = field.distance(torch.as_tensor(queries), horizon=1.0).numpy()
    true = np.abs(_true_signed_distance(box, queries))
    assert np.all(d <= true + 1e-9)
    assert np.all(d >= true - 0.01)  # within two voxels of the truth


def test_world_groups_and_exclusion():
    world = CollisionWorld()
    world.add("scene", BoxSet(pose_matrix([0.0, 0.0, 0.0])[None], np.array([[0.1, 0.1, 0.1]])))
    world.add("target", BoxSet(pose_matrix([0.5, 0.0, 0.0])[None], np.array([[0.05, 0.05, 0.05]])))
    p = torch.tensor([[0.5, 0.0, 0.0]], dtype=torch.float64)
    assert world.distance(p)[0] == pytest.approx(-0.05)
    assert world.distance(p, horizon=1.0, exclude=("target",))[0] == pytest.approx(0.4)
    with pytest.raises(KeyError, match="valid: scene, target"):
        world.distance(p, exclude=("shelf",))


def test_parts_from_scene_spec_in_base_frame():
    parts = [Part("top", "box", (0.4, 0.4, 0.02), (1.0, 0.0, 0.5)),
             Part("leg", "cylinder", (0.02, 0.5), (1.0, 0.0, 0.25)),
             Part("bump", "convex_mesh", (), (1.0, 0.3, 0.5),
                  mesh_vertices=tuple(map(tuple, trimesh.creation.box((0.05, 0.05, 0.05)).vertices)))]
    T_base_scene = pose_matrix([-0.6, 0.0, -0.4])  # the base stands at (0.6, 0, 0.4) in the scene
    world = CollisionWorld()
    for s in obstacle_sets_from_parts(parts, T_base_scene):
        world.add("scene", s)
    probes = torch.tensor([[0.4, 0.0, 0.13], [0.4, 0.0, -0.1], [0.4, 0.3, 0.12]], dtype=torch.float64)
    d = world.distance(probes, horizon=1.0).numpy()
    assert d[0] == pytest.approx(0.02)  # 2 cm above the 2 cm top centred at z 0.1
    assert d[1] == pytest.approx(-0.02)  # inside the leg, 2 cm from its side
    assert d[2] == pytest.approx(-0.005)  # inside the convex bump, 5 mm below its top
