"""The env as learners meet it (issue 20): compact point clouds, suite-drawn default tasks,
CPU vector envs, observations that own their arrays, exact env-state replay, id / kwarg
conflicts."""
from __future__ import annotations

import gc
import warnings
from copy import deepcopy

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms.envs import task_source
from fetchbench_ms.envs import make_vec_env, pointcloud
from fetchbench_ms.tasks.suite import load_suite
from mani_skill.utils import common

SUITE = "train"  # the shipped default suite (filtered train-split tasks)
#: Small cameras: rendering is most of a camera test's time.
SMALL_CAMERAS = dict(sensor_configs=dict(width=80, height=60))


def _speeds(env) -> np.ndarray:
    rd = sapien.physx.PhysxRigidDynamicComponent
    return np.array([np.linalg.norm(s._objs[0].find_component_by_type(rd).linear_velocity)
                     for s in env.unwrapped.object_slots])


# ---------------------------------------------------------------------- 1. compact clouds
def test_compact_cloud_is_fixed_size_segmented_cropped_and_seeded():
    rng = np.random.default_rng(0)
    n = 30_000
    xyz = rng.uniform(-1.5, 2.0, (n, 3)).astype(np.float32)
    labels = rng.choice([pointcloud.LABEL_NONE, pointcloud.LABEL_ROBOT, pointcloud.LABEL_OBJECT,
                         pointcloud.LABEL_FURNITURE], n).astype(np.uint8)
    labels[:50] = pointcloud.LABEL_TARGET  # a barely visible target: repeats fill its block
    cloud = pointcloud.compact_cloud(xyz, labels, seed=7)
    sizes = pointcloud.COMPACT_SIZES
    total = sum(sizes.values())
    assert cloud["xyz"].shape == (total, 3) and cloud["xyz"].dtype == np.float16
    assert cloud["seg"].shape == (total,) and cloud["seg"].dtype == np.uint8
    scene, target, robot = np.split(cloud["seg"], np.cumsum([sizes["scene"], sizes["target"]]))
    assert set(scene) == {pointcloud.LABEL_FURNITURE, pointcloud.LABEL_OBJECT}
    assert set(target) == {pointcloud.LABEL_TARGET} and set(robot) == {pointcloud.LABEL_ROBOT}
    box = np.array(pointcloud.WORKSPACE_BOX)
    pts = cloud["xyz"].astype(np.float32)
    assert ((pts >= box[:, 0] - 1e-3) & (pts <= box[:, 1] + 1e-3)).all()
    inside_target = ((xyz[:50] >= box[:, 0]) & (xyz[:50] <= box[:, 1])).all(axis=1).sum()
    assert len(np.unique(pts[sizes["scene"]:sizes["scene"] + sizes["target"]], axis=0)) == inside_target
    again = pointcloud.compact_cloud(xyz, labels, seed=7)
    other = pointcloud.compact_cloud(xyz, labels, seed=8)
    assert np.array_equal(again["xyz"], cloud["xyz"]) and np.array_equal(again["seg"], cloud["seg"])
    assert not np.array_equal(other["xyz"], cloud["xyz"])
    # No target at all: its block is zeros labelled none.
    empty = pointcloud.compact_cloud(xyz[50:], labels[50:], seed=7)
    assert set(np.split(empty["seg"], [sizes["scene"], sizes["scene"] + sizes["target"]])[1]) == {pointcloud.LABEL_NONE}


def test_compact_pointcloud_obs_mode_matches_the_wrapper_on_raw_clouds():
    """obs_mode="compact_pointcloud" gives the compact cloud of each step, the same as
    ``compact_pointcloud_obs`` applied to the raw pointcloud observation (what a recorded
    trajectory holds), and the same again for the same seed."""
    kwargs = dict(task_suite=SUITE, **SMALL_CAMERAS)
    compact = gym.make("FetchBench-Desk-v0", obs_mode="compact_pointcloud", **kwargs)
    raw = gym.make("FetchBench-Desk-v0", obs_mode="pointcloud", **kwargs)
    try:
        assert compact.unwrapped.obs_mode == "compact_pointcloud"
        obs, _ = compact.reset(seed=5)
        raw_obs, _ = raw.reset(seed=5)
        assert set(obs["pointcloud"]) == {"xyz", "seg"}
        assert obs["pointcloud"]["xyz"].shape == (1, sum(pointcloud.COMPACT_SIZES.values()), 3)
        assert compact.observation_space["pointcloud"]["xyz"].dtype == np.float16
        seed = int(np.atleast_1d(compact.unwrapped._episode_seed)[0])
        converted = pointcloud.compact_pointcloud_obs(raw_obs, [pointcloud.compact_seed(seed, 0)])
        for key in ("xyz", "seg"):
            assert torch.equal(converted["pointcloud"][key], obs["pointcloud"][key]), key
        labels = set(obs["pointcloud"]["seg"][0].tolist())
        assert {pointcloud.LABEL_TARGET, pointcloud.LABEL_ROBOT, pointcloud.LABEL_FURNITURE} <= labels
        step_obs, *_ = compact.step(torch.zeros(compact.action_space.shape))
        assert not torch.equal(step_obs["pointcloud"]["xyz"], obs["pointcloud"]["xyz"])  # a new draw per step
        again, _ = compact.reset(seed=5)
        assert torch.equal(again["pointcloud"]["xyz"], obs["pointcloud"]["xyz"])
    finally:
        compact.close()
        raw.close()


@pytest.mark.slow  # ~40 s: renders a point cloud per step
def test_converted_compact_trajectory_is_at_most_150_kb_a_step(tmp_path):
    from scripts.bench.bench_compact_cloud import GOAL_BYTES, convert, per_step, record_demo

    demo = record_demo(tmp_path, steps=4, task_suite=SUITE)
    r = per_step(convert(demo, "compact_pointcloud"))
    assert r["steps"] == 5 and r["file_per_step"] <= GOAL_BYTES
    assert r["pointcloud"]["xyz"] == ((sum(pointcloud.COMPACT_SIZES.values()), 3), "float16")


# ---------------------------------------------------------------------- 2. default tasks
def test_default_seed_resets_draw_filtered_suite_tasks(monkeypatch):
    """With default kwargs a seed picks a task of the default (filtered) suite, restricted
    to the id's category, deterministically; sampled tasks stay available."""
    monkeypatch.setattr(task_source, "DEFAULT_TASK_SUITE", SUITE)
    suite = load_suite(SUITE)
    env = gym.make("FetchBench-Shelf-v0", obs_mode="state", render_backend="none")
    try:
        base = env.unwrapped
        assert base.task_source == "suite"
        ids = []
        for seed in (0, 1, 2, 0):
            _, info = env.reset(seed=seed)
            (task_id,) = base.task_ids
            assert base.tasks[0] == suite.get(task_id) and base.tasks[0].target_label == "on_shelf"
            assert bool(info["task_filtered"][0])
            ids.append(task_id)
        assert ids[0] == ids[3] and len(set(ids)) > 1 and ids[0] == base.suite_task_id(0)
        env.reset(options={"task_id": ids[1]})  # by id, as before
        assert base.task_ids == [ids[1]]
    finally:
        env.close()
    sampled = gym.make("FetchBench-Desk-v0", obs_mode="state", render_backend="none", task_source="sampled",
                       num_objects=2)
    try:
        _, info = sampled.reset(seed=4)
        assert sampled.unwrapped.task_ids == [None] and not bool(info["task_filtered"][0])
    finally:
        sampled.close()


def test_scene_type_ids_serve_their_subset_of_a_suite():
    suite = load_suite(SUITE)
    env = gym.make("FetchBench-DrawerScene-v0", obs_mode="state", render_backend="none", task_suite=SUITE)
    try:
        pool = env.unwrapped._suite_pool
        assert pool and {suite.get(i).scene_type for i in pool} == {"Drawer"}
        env.reset(seed=11)
        assert env.unwrapped.tasks[0].scene_type == "Drawer"
    finally:
        env.close()


def test_default_suite_tasks_pass_the_filters_on_a_sample(monkeypatch):
    """A suite task passes the stable / visible / reachable filters by construction;
    checked here on the task of one seed with the filters themselves."""
    from fetchbench_ms.tasks.filters import FilterEnv

    monkeypatch.setattr(task_source, "DEFAULT_TASK_SUITE", SUITE)
    env = gym.make("FetchBench-Table-v0", obs_mode="state", render_backend="none")
    try:
        env.reset(seed=0)
        task = env.unwrapped.tasks[0]
    finally:
        env.close()
    filters = FilterEnv()
    try:
        check = filters.check(task, targets=[task.target_index])
    finally:
        filters.close()
    assert check.passes(task.target_index), check.rejection(task.target_index)


# ---------------------------------------------------------------------- 4. vector envs
def test_make_vec_env_runs_two_cpu_envs():
    envs = make_vec_env("FetchBench-Desk-v0", 2, obs_mode="state", render_backend="none", task_suite=SUITE,
                        control_mode="pd_joint_delta_pos")
    try:
        obs, _ = envs.reset(seed=0)
        assert obs.shape[0] == 2 and not np.array_equal(obs[0], obs[1])  # seeds 0 and 1: two tasks
        obs, reward, terminated, truncated, _ = envs.step(np.zeros((2, 8), dtype=np.float32))
        assert obs.shape[0] == 2 and reward.shape == (2,) and np.isfinite(obs).all()
    finally:
        envs.close()


@pytest.mark.parametrize("kwargs", [{}, {"sim_backend": "cpu"}])
def test_several_sub_scenes_without_cuda_name_both_ways(kwargs, monkeypatch):
    # As on a machine without CUDA (on a CUDA machine the default backend would be the GPU's).
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ValueError, match="physx_cuda.*make_vec_env"):
        gym.make("FetchBench-v0", num_envs=2, **kwargs)


# ---------------------------------------------------------------------- 5. observations
def _leaves(obs, prefix=""):
    if isinstance(obs, dict):
        for k, v in obs.items():
            yield from _leaves(v, f"{prefix}/{k}")
    else:
        yield prefix, obs


@pytest.mark.parametrize("obs_mode", ["state", "state_dict", "pointcloud", "rgbd", "compact_pointcloud"])
def test_no_array_is_shared_between_two_observations(obs_mode):
    from gymnasium.utils.env_checker import data_equivalence
    from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

    env = CPUGymWrapper(gym.make("FetchBench-Desk-v0", obs_mode=obs_mode, task_suite=SUITE, **SMALL_CAMERAS))
    try:
        first, _ = env.reset(seed=1)
        kept = common.to_numpy(first)
        copy = deepcopy(kept)
        second, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        third, _ = env.reset(seed=1)
        for name, a in _leaves(kept):
            for later in (second, third):
                b = dict(_leaves(later))[name]
                assert not np.shares_memory(a, b), f"{obs_mode}: {name} is the same buffer in two observations"
        assert data_equivalence(copy, kept)  # the kept observation did not change
    finally:
        env.close()


# ---------------------------------------------------------------------- 6. replay, conflicts
def test_env_state_replay_keeps_resting_objects_at_rest():
    """As the replay tool with --use-env-states does: step, then set the recorded state.
    The state comes back exactly, and objects the recording had asleep stay still."""
    env = gym.make("FetchBench-v0", obs_mode="state", control_mode="pd_joint_pos", task_suite=SUITE,
                   render_backend="none")
    try:
        base = env.unwrapped
        env.reset(seed=2)
        hold = torch.tensor(list(base.tasks[0].robot_init_qpos[:7]) + [0.04], dtype=torch.float32)[None]
        states, speeds = [base.get_state_dict()], []
        for _ in range(30):
            env.step(hold)
            states.append(base.get_state_dict())
            speeds.append(_speeds(env))
        assert speeds[-1].max() == 0.0  # the recording ends with every object asleep
        env.reset(seed=2)
        base.set_state_dict(states[0])
        replayed = []
        for t in range(30):
            env.step(hold)
            base.set_state_dict(states[t + 1])
            back = base.get_state_dict()
            for name, value in states[t + 1]["actors"].items():
                assert torch.equal(back["actors"][name], value), name  # poses and velocities exactly
            replayed.append(_speeds(env))
        assert max(s.max() for s in replayed) <= max(s.max() for s in speeds) + 1e-6
        # One more step from a resting state: objects asleep in the recording stay still.
        env.step(hold)
        assert _speeds(env).max() == 0.0
    finally:
        env.close()


@pytest.mark.parametrize("env_id, kwargs, message", [
    ("FetchBench-Shelf-v0", {"category": "Table"}, "FetchBench-Shelf-v0 is the env for category='Shelf'.*FetchBench-Table-v0"),
    ("FetchBench-LargeShelf-v0", {"scene_type": "Desk"}, "scene_type='LargeShelf'.*FetchBench-Desk-v0"),
    ("FetchBench-v0", {"task_source": "procedural"}, "valid: suite, sampled"),
    ("FetchBench-v0", {"task_source": "suite", "object_split": "test"}, "task_suite='test'"),
    ("FetchBench-Desk-v0", {"task_suite": SUITE, "category": "Drawer"}, "no task for scene type 'Desk' and category"),
])
def test_id_and_kwarg_conflicts_raise_naming_valid_choices(env_id, kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make(env_id, obs_mode="state", **kwargs)


def test_the_robots_model_closes_its_files():
    from fetchbench_ms.planning.robot import panda

    robot = panda()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        robot._input_bytes()
        gc.collect()
    assert not [w for w in caught if issubclass(w.category, ResourceWarning)]
