"""The three task filters (stable, visible, reachable) on the env, and env lookup of suite tasks."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fetchbench_ms.tasks.filters import FilterEnv
from fetchbench_ms.tasks.suite import load_suite


@pytest.fixture(scope="module")
def filter_env():
    env = FilterEnv()
    yield env
    env.close()


@pytest.fixture(scope="module")
def normal_task():
    """A task of the shipped smoke suite: it passed every filter when the suite was made."""
    smoke = load_suite("smoke")
    return smoke.get(smoke.ids()[0])


def test_a_normal_task_passes_every_filter(filter_env, normal_task):
    check = filter_env.check(normal_task, targets=[normal_task.target_index])
    k = normal_task.target_index
    assert check.stable and check.max_move < 0.05
    assert check.visible(k) and check.reachable[k]
    assert check.passes(k) and check.rejection(k) is None


def test_a_hovering_object_is_unstable(filter_env):
    # On an open Desk: nothing above its objects catches the lifted one (under a shelf
    # board a lifted object can wedge against the board above and barely move).
    smoke = load_suite("smoke")
    task = next(smoke.get(i) for i in smoke.ids() if smoke.get(i).scene_type == "Desk")
    other = (task.target_index + 1) % len(task.objects)
    o = task.objects[other]
    assert o.support_label == "on_table"
    lifted = replace(o, position=(o.position[0], o.position[1], o.position[2] + 0.25))
    objects = list(task.objects)
    objects[other] = lifted
    check = filter_env.check(replace(task, objects=tuple(objects)), targets=[])
    assert not check.stable and check.max_move > 0.05
    assert check.rejection(task.target_index) == "stable"


def test_a_target_hidden_from_one_camera_is_not_visible(filter_env, normal_task):
    # The left camera turned round (looking away from the furniture, +180 deg about z).
    from scipy.spatial.transform import Rotation

    cam = normal_task.camera_left
    w, x, y, z = cam.quat_wxyz
    turned = (Rotation.from_quat([x, y, z, w]) * Rotation.from_euler("z", np.pi)).as_quat()  # about its own up axis
    turned = (float(turned[3]), float(turned[0]), float(turned[1]), float(turned[2]))
    task = replace(normal_task, camera_left=replace(cam, quat_wxyz=turned))
    check = filter_env.check(task, targets=[])
    k = normal_task.target_index
    assert check.pixels[k, 0] <= check.min_pixels < check.pixels[k, 1]
    assert not check.visible(k) and check.rejection(k) == "visible"


def test_a_target_out_of_reach_is_unreachable(filter_env, normal_task):
    # The robot (and its table) 1.5 m further back: the arm reaches about 0.85 m.
    shift = np.array([-1.5, 0.0, 0.0])
    task = replace(
        normal_task,
        robot_base_position=tuple(float(v) for v in np.add(normal_task.robot_base_position, shift)),
        robot_table_center=tuple(float(v) for v in np.add(normal_task.robot_table_center, shift)),
    )
    k = normal_task.target_index
    check = filter_env.check(task, targets=[k])
    assert check.reachable[k] is False and check.rejection(k) in ("visible", "reachable")


def test_a_target_buried_in_the_floor_is_unreachable(filter_env):
    # The target sunk into the floor slab (10 cm under z = 0 in the planning world): every
    # grasp closes around it, so every hand is in the floor. (Inside a furniture board
    # would not do: boards are 2-3 cm thick and dense labels include grasps of the part
    # that sticks out.) The first smoke task whose target fits inside the slab.
    from fetchbench_ms.objects.catalog import get_object
    from fetchbench_ms.planning.world_models import FLOOR_THICKNESS

    smoke = load_suite("smoke")
    small = [t for t in map(smoke.get, smoke.ids())
             if max(get_object(t.target.object_id).record.extents) < FLOOR_THICKNESS - 0.005]
    assert small, "no smoke target fits inside the floor slab"
    task = small[0]
    k = task.target_index
    objects = list(task.objects)
    x, y, _ = objects[k].position
    objects[k] = replace(objects[k], position=(x, y, -FLOOR_THICKNESS / 2))
    filter_env.load(replace(task, objects=tuple(objects)))
    assert filter_env.reachable([k]) == {k: False}
    # ... while the same grasps reach it where it stood.
    filter_env.load(task)
    assert filter_env.reachable([k]) == {k: True}


def test_env_reset_by_suite_task_id_reproduces_the_task(normal_task):
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401

    env = gym.make("FetchBench-v0", obs_mode="state", task_suite="smoke")
    try:
        env.reset(options={"task_id": "smoke/0000"})
        u = env.unwrapped
        assert u.tasks[0] == normal_task
        for k, placement in enumerate(normal_task.objects):
            p = u.object_slots[k]._objs[0].pose.p
            assert np.allclose(p, placement.position, atol=1e-5)
        with pytest.raises(KeyError, match="unknown task id 'smoke/7777' in suite 'smoke'"):
            env.reset(options={"task_id": "smoke/7777"})
    finally:
        env.close()

