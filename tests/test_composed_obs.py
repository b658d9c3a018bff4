"""``obs_mode="composed_pointcloud"`` (``fetchbench_ms.envs.composed``): one render as an
episode starts, then every step's points composed from it by the target's and the links' poses."""
from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from fetchbench_ms.envs.composed import ComposedCloud, RobotPoints, robot_link_points
from fetchbench_ms.envs.pointcloud import (COMPOSED_OBS_MODE, LABEL_FURNITURE, LABEL_NONE, LABEL_OBJECT, LABEL_ROBOT,
                                           LABEL_TARGET, POLICY_CLOUD_SIZES)

N = sum(POLICY_CLOUD_SIZES.values())
N_SCENE, N_TARGET, N_ROBOT = POLICY_CLOUD_SIZES["scene"], POLICY_CLOUD_SIZES["target"], POLICY_CLOUD_SIZES["robot"]


def _pose(angle: float, t) -> torch.Tensor:
    """4x4: a turn about z by ``angle`` and a shift ``t``."""
    T = torch.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    T[:2, :2] = torch.tensor([[c, -s], [s, c]])
    T[:3, 3] = torch.tensor(t, dtype=torch.float32)
    return T


def test_robot_points_are_on_the_links_surfaces_by_area_and_the_same_every_time():
    big = trimesh.creation.box(extents=(0.4, 0.2, 0.2))  # area 0.4
    small = trimesh.creation.box(extents=(0.1, 0.1, 0.1))  # area 0.06
    robot = robot_link_points([big, None, small], 64)
    counts = np.bincount(robot.link_index.numpy(), minlength=3)
    assert counts.sum() == 64 and counts[1] == 0
    assert counts[0] == round(64 * 0.4 / 0.46) and counts[2] == 64 - counts[0]
    for link, mesh in ((0, big), (2, small)):
        points = robot.points_link[robot.link_index == link].numpy()
        assert np.abs(trimesh.proximity.signed_distance(mesh, points)).max() < 1e-6
        assert len(np.unique(points, axis=0)) == len(points)  # farthest-point kept: no repeats
    again = robot_link_points([big, None, small], 64)
    assert torch.equal(again.points_link, robot.points_link) and torch.equal(again.link_index, robot.link_index)
    with pytest.raises(ValueError, match="no visual geometry"):
        robot_link_points([None], 8)


def _camera_points(rng, with_target: bool = True):
    """A fake camera cloud (base frame): furniture, objects, the target in a 4 cm cube at (0.5, 0, 0.4), robot."""
    parts = [(LABEL_FURNITURE, rng.uniform(0.0, 0.8, (3000, 3))), (LABEL_OBJECT, rng.uniform(0.2, 0.6, (500, 3))),
             (LABEL_ROBOT, rng.uniform(0.0, 0.3, (800, 3)))]
    if with_target:
        parts.append((LABEL_TARGET, np.array([0.5, 0.0, 0.4]) + rng.uniform(-0.02, 0.02, (400, 3))))
    points = np.concatenate([p for _, p in parts]).astype(np.float32)
    labels = np.concatenate([np.full(len(p), label, np.uint8) for label, p in parts])
    return torch.from_numpy(points)[None], torch.from_numpy(labels)[None]


def _robot(n: int = N_ROBOT) -> RobotPoints:
    rng = np.random.default_rng(0)
    return RobotPoints(torch.arange(n) % 3, torch.from_numpy(rng.uniform(-0.05, 0.05, (n, 3)).astype(np.float32)))


def test_compose_keeps_the_scene_and_moves_the_target_and_links_rigidly():
    rng = np.random.default_rng(1)
    points, labels = _camera_points(rng)
    cloud = ComposedCloud(1, _robot(), "cpu")
    assert bool(cloud.stale.all())
    T_target_start = _pose(0.0, (0.5, 0.0, 0.4))
    cloud.start(torch.tensor([0]), points, labels, torch.tensor([5]), T_target_start[None])
    assert not bool(cloud.stale.any())
    links = torch.stack([_pose(0.1 * k, (0.1 * k, 0.0, 0.2)) for k in range(3)])[None]
    first, first_label = cloud.compose(T_target_start[None], links)
    assert first.shape == (1, N, 3) and first.dtype == torch.float16 and first_label.dtype == torch.uint8
    scene, target, robot = np.split(first_label[0].numpy(), [N_SCENE, N_SCENE + N_TARGET])
    assert set(scene) <= {LABEL_FURNITURE, LABEL_OBJECT} and set(target) == {LABEL_TARGET}
    assert set(robot) == {LABEL_ROBOT}
    # At the start pose the target's points are camera points of the target.
    seen = points[0, labels[0] == LABEL_TARGET]
    dist = torch.cdist(first[0, N_SCENE:N_SCENE + N_TARGET].float(), seen).min(1).values
    assert float(dist.max()) < 1e-3
    # The target lifted 10 cm and turned 90 degrees; link 1 turned: the scene block stays.
    T_target = _pose(np.pi / 2, (0.5, 0.0, 0.5))
    links_moved = links.clone()
    links_moved[0, 1] = _pose(1.0, (0.0, 0.3, 0.3))
    moved, moved_label = cloud.compose(T_target[None], links_moved)
    assert torch.equal(moved_label, first_label)
    assert torch.equal(moved[0, :N_SCENE], first[0, :N_SCENE])
    expected = (first[0, N_SCENE:N_SCENE + N_TARGET].float() - torch.tensor([0.5, 0.0, 0.4])) @ T_target[:3, :3].T \
        + T_target[:3, 3]
    assert torch.allclose(moved[0, N_SCENE:N_SCENE + N_TARGET].float(), expected, atol=2e-3)
    robot_first, robot_moved = first[0, N_SCENE + N_TARGET:].float(), moved[0, N_SCENE + N_TARGET:].float()
    on_link1 = (torch.arange(N_ROBOT) % 3) == 1
    assert torch.equal(robot_first[~on_link1], robot_moved[~on_link1])
    assert float((robot_first[on_link1] - robot_moved[on_link1]).norm(dim=1).min()) > 0.05


def test_an_unseen_target_stays_zeros_labelled_none():
    points, labels = _camera_points(np.random.default_rng(2), with_target=False)
    cloud = ComposedCloud(1, _robot(), "cpu")
    cloud.start(torch.tensor([0]), points, labels, torch.tensor([1]), _pose(0.0, (0.5, 0.0, 0.4))[None])
    out, label = cloud.compose(_pose(0.3, (0.5, 0.2, 0.6))[None], torch.eye(4).repeat(1, 3, 1, 1))
    assert (label[0, N_SCENE:N_SCENE + N_TARGET] == LABEL_NONE).all()
    assert (out[0, N_SCENE:N_SCENE + N_TARGET] == 0).all()
    with pytest.raises(ValueError, match="robot points"):
        ComposedCloud(1, _robot(10), "cpu")


def test_the_env_renders_once_an_episode_and_composes_each_step():
    """No camera renders after the episode's first observation; the scene block stays, the robot's
    points follow the arm, and a reset to the same seed gives the same bytes again."""
    import gymnasium as gym
    from mani_skill.sensors.camera import Camera

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.policies.data import observation_input

    env = gym.make("FetchBench-v0", obs_mode=COMPOSED_OBS_MODE, control_mode="pd_joint_delta_pos",
                   task_suite="train")
    captures = []
    capture = Camera.capture
    Camera.capture = lambda self: (captures.append(1), capture(self))[1]
    try:
        obs, _ = env.reset(seed=4)
        assert env.unwrapped.obs_mode == COMPOSED_OBS_MODE and len(captures) == 2  # the two cameras, once
        first = obs["pointcloud"]["points"][0].clone()
        assert obs["pointcloud"]["points"].shape == (1, N, 3) and "sensor_data" not in obs
        labels = obs["pointcloud"]["point_label"][0].numpy()
        assert set(labels[N_SCENE + N_TARGET:]) == {LABEL_ROBOT}
        assert set(labels[N_SCENE:N_SCENE + N_TARGET]) == {LABEL_TARGET}  # the train task's target is seen
        action = torch.zeros((1, 8))
        action[0, 1] = 1.0  # the shoulder: 0.1 rad a step
        for _ in range(5):
            obs, *_ = env.step(action)
        assert len(captures) == 2
        moved = obs["pointcloud"]["points"][0]
        assert torch.equal(moved[:N_SCENE], first[:N_SCENE])
        assert float((moved[N_SCENE + N_TARGET:].float() - first[N_SCENE + N_TARGET:].float()).norm(dim=1).max()) > 0.05
        assert np.array_equal(observation_input(obs).points, moved[None].numpy())  # the policy reads it as it is
        again, _ = env.reset(seed=4)
        assert len(captures) == 4 and torch.equal(again["pointcloud"]["points"][0], first)
    finally:
        Camera.capture = capture
        env.close()
    with pytest.raises(ValueError, match="renderer"):
        gym.make("FetchBench-v0", obs_mode=COMPOSED_OBS_MODE, render_backend="none")


def test_a_hybrid_env_composes_what_the_composed_env_observes():
    """A hybrid's env renders full clouds for its grasp network; ``composed_pointcloud_obs()``
    taken at the episode's start gives the composed env's points to the bit, and composing later
    steps renders nothing."""
    import gymnasium as gym
    from mani_skill.sensors.camera import Camera

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.policies.deploy import composed_observation

    kwargs = dict(control_mode="pd_joint_delta_pos", task_suite="train")
    composed_env = gym.make("FetchBench-v0", obs_mode=COMPOSED_OBS_MODE, **kwargs)
    cloud_env = gym.make("FetchBench-v0", obs_mode="pointcloud", **kwargs)
    captures = []
    capture = Camera.capture
    try:
        expected, _ = composed_env.reset(seed=6)
        cloud_env.reset(seed=6)
        Camera.capture = lambda self: (captures.append(1), capture(self))[1]
        got = composed_observation(cloud_env)
        assert len(captures) == 2  # the start's render
        assert torch.equal(got["pointcloud"]["points"], expected["pointcloud"]["points"])
        assert torch.equal(got["pointcloud"]["point_label"], expected["pointcloud"]["point_label"])
        action = torch.zeros((1, 8))
        action[0, 3] = 1.0
        for env in (composed_env, cloud_env):
            env.unwrapped._step_action(action)  # no observation: as the hybrid's executor steps
        expected = composed_env.unwrapped.get_obs()
        captures.clear()
        got = composed_observation(cloud_env)
        assert not captures
        assert torch.equal(got["pointcloud"]["points"], expected["pointcloud"]["points"])
        assert torch.equal(got["agent"]["qpos"], expected["agent"]["qpos"])
    finally:
        Camera.capture = capture
        composed_env.close()
        cloud_env.close()
