"""The Panda model: FK agrees with pytorch_kinematics and SAPIEN, spheres are conservative."""
import json

import numpy as np
import pytest
import torch
import trimesh

from fetchbench_ms.planning.exact import ExactRobot
from fetchbench_ms.planning.robot import FINGER_OPEN, Q_DEFAULT
from fetchbench_ms.planning.spheres import load_or_fit, sample_link_points


def test_fk_matches_pytorch_kinematics(robot):
    q = torch.as_tensor(np.random.default_rng(0).uniform(robot.q_min, robot.q_max, (64, 7)))
    ours = robot.link_poses(q, 0.03)
    full = torch.cat([q, torch.full((64, 2), 0.03, dtype=torch.float64)], 1)
    ref = {k: v.get_matrix() for k, v in robot.chain.forward_kinematics(full).items()}
    assert set(ref) <= set(ours)
    for link, T in ref.items():
        assert torch.allclose(ours[link], T, atol=1e-6), link


def test_jacobian_matches_pytorch_kinematics(robot):
    q = torch.as_tensor(np.random.default_rng(4).uniform(robot.q_min, robot.q_max, (32, 7)))
    assert torch.allclose(robot.tcp_jacobian(q), robot.arm_chain.jacobian(q), atol=1e-6)


def test_fk_matches_sapien(robot):
    import sapien

    scene = sapien.Scene()
    loader = scene.create_urdf_loader()
    loader.fix_root_link = True
    art = loader.load(robot.urdf_path)
    rng = np.random.default_rng(1)
    names = [j.name for j in art.get_active_joints()]
    for _ in range(5):
        q = rng.uniform(robot.q_min, robot.q_max)
        qpos = np.array([dict(zip([f"panda_joint{i}" for i in range(1, 8)], q)).get(n, 0.02) for n in names])
        art.set_qpos(qpos)
        ours = robot.link_poses(q, 0.02)
        for link in art.get_links():
            if link.name in ours:
                assert np.allclose(link.entity_pose.to_transformation_matrix(), ours[link.name][0].numpy(),
                                   atol=1e-5), link.name


def test_spheres_contain_link_geometry(robot):
    """Fresh samples (another seed than the fit) of every link's collision solid lie inside its spheres."""
    s = robot.spheres
    for i, link in enumerate(s.links):
        points = sample_link_points(robot.collision_meshes[link], seed=12345, surface_count=6000)
        mask = s.link_index == i
        d = np.linalg.norm(points[:, None] - s.centers_link[mask][None], axis=2) - s.radii[mask][None]
        assert d.min(axis=1).max() <= 0.0, f"{link}: a point lies {d.min(axis=1).max() * 1000:.2f} mm outside"


def test_spheres_are_not_loose(robot):
    # A loose model would make the shelf unreachable: radii stay close to the link thickness.
    assert robot.spheres.radii.max() < 0.085
    assert 30 <= len(robot.spheres.radii) <= 120


def test_default_configuration_has_no_self_collision(robot):
    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.world import CollisionWorld

    checker = CollisionChecker(robot, CollisionWorld())
    assert checker.valid(Q_DEFAULT)[0]


def test_self_collision_is_conservative(robot):
    """Where the exact link meshes of a checked pair touch, the spheres report collision too."""
    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.world import CollisionWorld

    checker = CollisionChecker(robot, CollisionWorld())
    exact = ExactRobot(robot, links=robot.spheres.links)
    pairs = {(robot.spheres.links[robot.spheres.link_index[a]], robot.spheres.links[robot.spheres.link_index[b]])
             for a, b in robot.self_collision_pairs}
    rng = np.random.default_rng(2)
    q = rng.uniform(robot.q_min, robot.q_max, (300, 7))
    sphere_free = checker.clearance(q).numpy() > 0
    n_exact_hits = 0
    for qi, free in zip(q, sphere_free):
        exact.pose(qi, FINGER_OPEN)
        if any(exact.link_pair_collides(a, b) for a, b in pairs):
            n_exact_hits += 1
            assert not free
    assert n_exact_hits > 0  # the sample did exercise real self-collisions


def test_sphere_cache_detects_corruption(tmp_path):
    meshes = {"box_link": trimesh.creation.box((0.1, 0.05, 0.05))}
    first = load_or_fit(meshes, b"inputs", tmp_path)
    again = load_or_fit(meshes, b"inputs", tmp_path)
    assert np.array_equal(first[0].radii, again[0].radii)
    path = next((tmp_path / "planning").glob("*.json"))
    record = json.loads(path.read_text())
    record["links"]["box_link"]["radii"][0] *= 0.5
    path.write_text(json.dumps(record))
    with pytest.raises(ValueError, match="corrupt or stale"):
        load_or_fit(meshes, b"inputs", tmp_path)
    # Other inputs are another key: never read from the old file.
    assert len(load_or_fit(meshes, b"other inputs", tmp_path)) == 1
