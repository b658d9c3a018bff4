"""The env options toward the original FetchBench (``fetchbench_ms.envs.options``):
``sim_freq`` (physics 120 or 60 Hz, control 20 Hz) and ``camera_placement`` ("task" or the
original's "paper" heuristic), and ``parse_env_options`` for ``NAME=VALUE`` strings."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms.envs import parse_env_options, settle_and_hold
from fetchbench_ms.tasks.camera_views import in_frustum, support_height_range
from fetchbench_ms.tasks.spec import pose_matrix

#: Cheap envs: suite tasks (pre-settled, no sampling) and no renderer.
CHEAP = dict(obs_mode="state", render_backend="none")


def _count_physics_steps(base) -> list:
    """Count ``base.scene.step`` calls from now on (returns the one-element counter)."""
    counter = [0]
    step = base.scene.step

    def counted():
        counter[0] += 1
        step()

    base.scene.step = counted
    return counter


@pytest.mark.parametrize("kwargs, sim_freq", [({}, 120), ({"sim_freq": 60}, 60), ({"sim_freq": "60"}, 60),
                                              ({"sim_config": {"sim_freq": 60}}, 60)])
def test_sim_freq_sets_the_physics_rate_and_keeps_control_at_20_hz(kwargs, sim_freq):
    env = gym.make("FetchBench-v0", **CHEAP, **kwargs)
    try:
        base = env.unwrapped
        env.reset(seed=3)
        assert base.sim_freq == sim_freq and base.control_freq == 20
        assert base.scene.px.timestep == pytest.approx(1.0 / sim_freq)
        counter = _count_physics_steps(base)
        env.step(torch.zeros(env.action_space.shape))
        assert counter[0] == sim_freq // 20  # 3 or 6 physics steps an action
        counter[0] = 0
        info = settle_and_hold(env, seconds=10.0)
        assert counter[0] == 10 * sim_freq  # 600 at 60 Hz, as the original's hold
        # A suite task rests: nothing moves through the hold at either rate.
        assert float(info["max_others_moved"]) < 0.02 and float(info["target_moved"]) < 0.02
        assert env.unwrapped.metadata["render_fps"] == 20
    finally:
        env.close()


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"sim_freq": 100}, r"unknown sim_freq 100; valid: 120, 60"),
        ({"sim_freq": "fast"}, r"unknown sim_freq 'fast'; valid: 120, 60"),
        ({"sim_freq": 60.5}, r"unknown sim_freq 60.5; valid: 120, 60"),
        ({"sim_freq": True}, r"unknown sim_freq True; valid: 120, 60"),
        ({"sim_freq": 60, "sim_config": {"sim_freq": 120}}, r"sim_config sets sim_freq=120 but the sim_freq kwarg is 60"),
        ({"camera_placement": "left"}, r"unknown camera_placement 'left'; valid: task, paper"),
        ({"camera_placement": None}, r"unknown camera_placement None; valid: task, paper"),
    ],
)
def test_bad_option_values_name_the_valid_ones(kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make("FetchBench-v0", **CHEAP, **kwargs)


def test_parse_env_options_validates_names_and_values():
    assert parse_env_options(["sim_freq=60", "camera_placement=paper"]) == {"sim_freq": 60, "camera_placement": "paper"}
    assert parse_env_options([" sim_freq = 120 ", "camera_placement=task"]) == {"sim_freq": 120,
                                                                                "camera_placement": "task"}
    assert parse_env_options([]) == {}
    valid = "valid: sim_freq=120|60; camera_placement=task|paper"
    for options, what in ((["sim_freq=50"], "bad value '50'"), (["camera_placement=left"], "bad value 'left'"),
                          (["frequency=60"], "unknown env option 'frequency'"), (["sim_freq"], "not NAME=VALUE"),
                          (["sim_freq=60", "sim_freq=120"], "given twice")):
        with pytest.raises(ValueError, match=what) as raised:
            parse_env_options(options)
        message = str(raised.value)
        assert valid in message and "\n" not in message
    # What it returns is what gym.make takes.
    env = gym.make("FetchBench-v0", **CHEAP, **parse_env_options(["sim_freq=60"]))
    try:
        assert env.unwrapped.sim_freq == 60
    finally:
        env.close()


def _eye_and_aim(camera) -> tuple[np.ndarray, np.ndarray]:
    """A camera's eye and a point 1 m along its view axis (SAPIEN: x forward)."""
    T = pose_matrix(camera.position, camera.quat_wxyz)
    return T[:3, 3], T[:3, 3] + T[:3, 0]


def _mount_poses(base) -> dict:
    return {side: base.built.camera_mounts[side].pose.raw_pose[0].numpy() for side in ("left", "right")}


def _pose_of(camera) -> np.ndarray:
    return np.array(list(camera.position) + list(camera.quat_wxyz), dtype=np.float32)


def test_camera_placement_paper_is_the_originals_heuristic_and_deterministic_per_task():
    env = gym.make("FetchBench-v0", **CHEAP, camera_placement="paper")
    other = gym.make("FetchBench-v0", **CHEAP, camera_placement="paper")
    try:
        base = env.unwrapped
        for seed in (3, 4, 5):
            env.reset(seed=seed)
            task, spec = base.tasks[0], base._scene_specs[0]
            left, right = base.camera_poses[0]
            # Not the task's (scored) pair; the task itself is kept as given.
            assert left != task.camera_left and right != task.camera_right
            assert base.tasks[0] == task
            # The camera mounts carry the paper pair (the sensors ride on them).
            mounts = _mount_poses(base)
            np.testing.assert_allclose(mounts["left"], _pose_of(left), atol=1e-5)
            np.testing.assert_allclose(mounts["right"], _pose_of(right), atol=1e-5)
            # The task's fov; mirrored in y about the support region's centre.
            assert left.fov_x == right.fov_x == task.camera_left.fov_x
            center = np.asarray(spec.camera_target.center)
            assert left.position[0] == pytest.approx(right.position[0], abs=1e-6)
            assert left.position[2] == pytest.approx(right.position[2], abs=1e-6)
            assert left.position[1] - center[1] == pytest.approx(center[1] - right.position[1], abs=1e-5)
            assert left.position[1] > right.position[1]
            # They look at the supports: the region's centre is in both views, and the
            # vertical view spans the supports' heights at the aim point.
            z_lo, z_hi = support_height_range(spec)
            for camera in (left, right):
                eye, aim = _eye_and_aim(camera)
                assert in_frustum(eye, aim, center[None], camera.fov_x, 4 / 3).all()
                forward = (aim - eye)
                t = (center[:2] - eye[:2]) @ forward[:2] / (forward[:2] @ forward[:2])  # the aim column near the centre
                column = eye + t * forward
                heights = np.array([[column[0], column[1], z_lo], [column[0], column[1], z_hi]])
                assert in_frustum(eye, aim, heights, camera.fov_x, 4 / 3).all()
            # The same task gives the same pair: in another env, and after another task.
            other.reset(options={"task": task.to_dict()})
            assert other.unwrapped.camera_poses[0] == (left, right)
            np.testing.assert_array_equal(_mount_poses(other.unwrapped)["left"], mounts["left"])
            env.reset(seed=seed + 10)
            assert base.camera_poses[0] != (left, right)
            env.reset(options={"task": task.to_dict()})
            assert base.camera_poses[0] == (left, right)
            _, info = env.reset(options={"task": task.to_dict()})  # the loaded task again: no rebuild
            assert not info["reconfigure"]
            np.testing.assert_allclose(_mount_poses(base)["right"], mounts["right"], atol=1e-6)
    finally:
        env.close()
        other.close()


def test_camera_placement_task_keeps_the_tasks_cameras():
    for kwargs in ({}, {"camera_placement": "task"}):
        env = gym.make("FetchBench-v0", **CHEAP, **kwargs)
        try:
            base = env.unwrapped
            env.reset(seed=4)
            task = base.tasks[0]
            assert base.camera_placement == "task"
            assert base.camera_poses[0] == (task.camera_left, task.camera_right)
            mounts = _mount_poses(base)
            np.testing.assert_allclose(mounts["left"], _pose_of(task.camera_left), atol=1e-5)
            np.testing.assert_allclose(mounts["right"], _pose_of(task.camera_right), atol=1e-5)
        finally:
            env.close()


def test_paper_cameras_are_the_sensors_poses_with_the_tasks_fov_and_resolution():
    """With a renderer: the sensors stand where the paper pair says, at the env's resolution."""
    env = gym.make("FetchBench-v0", obs_mode="rgb", camera_placement="paper")
    try:
        base = env.unwrapped
        obs, _ = env.reset(seed=3)
        task = base.tasks[0]
        for side, camera in zip(("left", "right"), base.camera_poses[0]):
            assert obs["sensor_data"][f"{side}_camera"]["rgb"].shape == (1, 240, 320, 3)
            params = base._sensors[f"{side}_camera"].get_params()
            cam2world = params["cam2world_gl"][0].numpy()
            np.testing.assert_allclose(cam2world[:3, 3], camera.position, atol=1e-4)
            # OpenGL axes: the camera looks along -z; SAPIEN's forward (x) is the same direction.
            forward = pose_matrix(camera.position, camera.quat_wxyz)[:3, 0]
            np.testing.assert_allclose(-cam2world[:3, 2], forward, atol=1e-4)
            fx = float(params["intrinsic_cv"][0, 0, 0])
            assert 2 * np.arctan(320 / 2 / fx) == pytest.approx(task.camera_left.fov_x, abs=1e-4)
            assert not np.allclose(camera.position, getattr(task, f"camera_{side}").position)
    finally:
        env.close()
