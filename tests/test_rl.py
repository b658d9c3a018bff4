"""Reinforcement learning: the dense reward's stages and penalties, the curriculum option,
and the PPO baseline on CPU vector envs (docs/rl.md)."""
from __future__ import annotations

import csv
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms.demos.returns import demo_rollout, load_demos, make_env
from fetchbench_ms.envs.curriculum import (ADVANCE_STEP, CURRICULA, MIN_TARGET_DISTANCE, Curriculum,
                                           resolve_curriculum)
from fetchbench_ms.envs.fetchbench import DENSE_REWARD_MAX
from fetchbench_ms.tasks.suite import load_suite
from mani_skill.utils.structs.pose import Pose

from script_modules import load_script

ROOT = Path(__file__).resolve().parent.parent
SAMPLE = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"


@pytest.fixture(scope="module")
def demo_env():
    env_info, episodes = load_demos(SAMPLE)
    env = make_env(env_info)
    yield env, episodes
    env.close()


def test_reward_stages_rise_along_a_scripted_reach_grasp_lift(demo_env):
    """The expert's trajectory is a scripted reach (approach stage), grasp (close stage)
    and lift (retrieve stage): the dense reward and its stage terms rise through them."""
    env, episodes = demo_env
    episode = episodes[0]
    rollout = demo_rollout(env, SAMPLE, episode, horizon=0)
    with h5py.File(SAMPLE, "r") as f:
        stage = f[f"traj_{episode['episode_id']}/stage"][:]
    start = 0
    reached = int(np.flatnonzero(stage == 0)[-1])  # the TCP at the grasp pose, fingers open
    grasped = int(np.flatnonzero(stage == 1)[-1])  # fingers closed on the target
    lifted = grasped + int(np.argmax(rollout.terms["lift"][grasped:] >= 1.0))  # 5 cm up
    terms, r = rollout.terms, rollout.rewards
    assert terms["reach"][reached] > 0.9 > terms["reach"][start] and terms["grasp"][reached] == 0
    assert terms["grasp"][grasped] == 1 and terms["lift"][grasped] < 1
    assert terms["lift"][lifted] == 1 and terms["grasp"][lifted] == 1
    assert r[start] < r[reached] < 1.0 < 2.0 <= r[grasped] < r[lifted] < DENSE_REWARD_MAX
    # Whatever happens within a stage, a grasped state outranks every state of the reach stage.
    assert r[rollout.terms["grasp"] == 1].min() > r[:reached + 1].max()


def test_reward_and_success_agree_at_the_end_of_the_sample_demos(demo_env):
    env, episodes = demo_env
    for episode in episodes[:3]:
        rollout = demo_rollout(env, SAMPLE, episode, horizon=0)
        assert rollout.success_at_end and rollout.rewards[-1] == DENSE_REWARD_MAX
        assert rollout.terms["grasp"][-1] == 1 and rollout.terms["carry"][-1] > 0.9
    # A demo perturbed into a miss ends without success and below the top reward.
    noised = demo_rollout(env, SAMPLE, episodes[0], horizon=0, action_noise=0.05, rng=np.random.default_rng(0))
    assert not noised.success_at_end and noised.rewards[-1] < 2.0
    assert noised.ret < rollout.ret


def test_disturbing_others_and_furniture_contact_cost_reward(demo_env):
    env, episodes = demo_env
    rollout = demo_rollout(env, SAMPLE, episodes[0], horizon=0)
    base = env.unwrapped
    info = base.evaluate()
    clean = float(base.get_reward(obs=None, action=None, info=info))
    # Knock another object 10 cm sideways: the disturbance term saturates and the
    # success is lost (the success criterion and the penalty share the 0.10 m).
    other = next(k for k in range(len(base.tasks[0].objects)) if k != base.tasks[0].target_index)
    pose = base.object_slots[other].pose
    base.object_slots[other].set_pose(Pose.create_from_pq(p=pose.p + torch.tensor([[0.0, 0.11, 0.0]]), q=pose.q))
    info = base.evaluate()
    terms = base.reward_terms(info)
    assert clean == DENSE_REWARD_MAX and float(terms["disturb"]) == 1.0 and not bool(info["success"])
    assert float(base.get_reward(obs=None, action=None, info=info)) <= 0.5 * DENSE_REWARD_MAX + 1e-5
    # A robot link pushed into the robot table is a furniture contact.
    info["robot_furniture_force"] = torch.tensor([5.0])
    assert float(base.reward_terms(info)["contact"]) == 1.0
    assert rollout.terms["contact"].max() == 0.0  # the expert never touches furniture


def test_furniture_contact_is_measured_in_the_simulation():
    """Drive the arm down into the robot table: the env's one-pass contact walk reports a
    robot-furniture force, and the reward's contact term turns on."""
    env = gym.make("FetchBench-Table-v0", obs_mode="state", control_mode="pd_joint_delta_pos",
                   reward_mode="dense", render_backend="none")
    try:
        env.reset(seed=0)
        forces = []
        down = torch.tensor([[0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0]])  # shoulder and elbow forward and down
        for _ in range(60):
            _, _, _, _, info = env.step(down)
            forces.append(float(info["robot_furniture_force"]))
        assert forces[0] == 0.0 and max(forces) > 1.0
        assert float(env.unwrapped.reward_terms(info)["contact"]) == float(forces[-1] > 1.0)
    finally:
        env.close()


# ---------------------------------------------------------------------------- curriculum
def test_curriculum_validation_names_the_valid_choices():
    with pytest.raises(ValueError, match="unknown curriculum 'easy'; valid: table-near, table-near-pregrasp"):
        resolve_curriculum("easy")
    with pytest.raises(ValueError, match=r"unknown curriculum fields \['objects'\]; valid: base_advance"):
        resolve_curriculum({"objects": 3})
    with pytest.raises(ValueError, match="target_labels .* valid: a non-empty list of on_table"):
        Curriculum(target_labels=("on_floor",))
    with pytest.raises(ValueError, match="base_advance must be in 0..0.4"):
        Curriculum(base_advance=1.0)
    with pytest.raises(ValueError, match="num_objects must be an int in 1..64"):
        Curriculum(num_objects=0)
    with pytest.raises(ValueError, match="category 'Shelf' .* not among the curriculum's target_labels"):
        gym.make("FetchBench-Shelf-v0", curriculum="table-near", render_backend="none")
    with pytest.raises(ValueError, match="max_tasks cuts a suite's task pool, but task_source='sampled'"):
        gym.make("FetchBench-v0", curriculum="table-near", task_source="sampled", render_backend="none")


def _floor_distance(task) -> float:
    """Base to target in the floor plane (m)."""
    return float(np.linalg.norm(np.subtract(task.target.position[:2], task.robot_base_position[:2])))


def test_curriculum_makes_tasks_easier_and_is_idempotent():
    # The first on-table task whose target is far enough for the base to advance at all
    # (the curriculum stops MIN_TARGET_DISTANCE short of the target; closer ones stay put).
    on_table = [t for t in load_suite("train").tasks.values() if t.target_label == "on_table"]
    task = next(t for t in on_table if _floor_distance(t) > MIN_TARGET_DISTANCE + ADVANCE_STEP)
    curriculum = Curriculum(num_objects=3, base_advance=0.15)
    easy = curriculum.apply(task)
    assert len(easy.objects) == 3 and easy.target.object_id == task.target.object_id
    assert easy.target.position == task.target.position
    kept = [o.object_id for o in easy.objects if o is not easy.target]
    dist = sorted((np.linalg.norm(np.subtract(o.position, task.target.position)), o.object_id)
                  for k, o in enumerate(task.objects) if k != task.target_index)
    assert sorted(kept) == sorted(i for _, i in dist[:2])  # the two nearest others
    before = np.linalg.norm(np.subtract(task.target.position[:2], task.robot_base_position[:2]))
    after = np.linalg.norm(np.subtract(easy.target.position[:2], easy.robot_base_position[:2]))
    advance = easy.extra["curriculum_info"]["base_advance"]
    assert 0 < advance <= 0.15 and after == pytest.approx(before - advance, abs=1e-5)
    assert after >= MIN_TARGET_DISTANCE - 1e-5
    table_shift = np.subtract(easy.robot_table_center, task.robot_table_center)
    np.testing.assert_allclose(table_shift, np.subtract(easy.robot_base_position, task.robot_base_position), atol=1e-5)
    assert curriculum.apply(easy) is easy
    # A target already within MIN_TARGET_DISTANCE: objects cut, the robot not moved.
    near = next(t for t in on_table if _floor_distance(t) <= MIN_TARGET_DISTANCE)
    easy_near = curriculum.apply(near)
    assert len(easy_near.objects) == 3 and easy_near.extra["curriculum_info"]["base_advance"] == 0.0
    assert easy_near.robot_base_position == near.robot_base_position
    assert easy_near.robot_table_center == near.robot_table_center


def test_curriculum_env_serves_on_table_tasks_with_fewer_objects():
    env = gym.make("FetchBench-v0", curriculum=dict(num_objects=2, target_labels=["on_table"], max_tasks=3),
                   obs_mode="state", render_backend="none")
    try:
        base = env.unwrapped
        assert len(base._suite_pool) == 3
        for seed in (0, 1):
            env.reset(seed=seed)
            task = base.tasks[0]
            assert task.target_label == "on_table" and len(task.objects) == 2
            assert int(base.built.valid.sum()) == 2
        # The loaded task replays as given (already made easier: unchanged).
        env.reset(options={"task": task.to_dict()})
        assert base.tasks[0] == task
    finally:
        env.close()


def test_curriculum_pregrasp_start_is_near_the_target_and_prepared_once(tmp_path, monkeypatch):
    from fetchbench_ms.envs import curriculum as curriculum_module

    monkeypatch.setenv("FETCHBENCH_CACHE", str(tmp_path))
    curriculum_module._apply_cached.cache_clear()
    spec = dict(num_objects=2, target_labels=["on_table"], max_tasks=1, pregrasp=True)
    assert curriculum_module.prepare("FetchBench-v0", spec) == 1
    assert len(list((tmp_path / "curriculum").glob("*.json"))) == 1  # made once, on disk
    plain = gym.make("FetchBench-v0", obs_mode="state", render_backend="none",
                     curriculum=dict(num_objects=2, target_labels=["on_table"], max_tasks=1))
    env = gym.make("FetchBench-v0", obs_mode="state", render_backend="none", curriculum=spec)
    try:
        plain.reset(seed=0)
        env.reset(seed=0)
        task = env.unwrapped.tasks[0]
        assert task.extra["curriculum_info"]["pregrasp"] and task.robot_init_qpos != plain.unwrapped.tasks[0].robot_init_qpos
        start = plain.unwrapped.target_surface_distance()
        near = env.unwrapped.target_surface_distance()
        # 8 cm behind a grasp (the TCP sits between the pads at the grasp): within ~12 cm
        # of the surface, and much nearer than the default start.
        assert float(near) < 0.12 < float(start)
        _, _, _, _, info = env.step(torch.zeros(env.action_space.shape))
        assert float(info["robot_furniture_force"]) == 0.0 and float(info["max_others_moved"]) < 0.01
    finally:
        env.close()
        plain.close()
        curriculum_module._apply_cached.cache_clear()


# ---------------------------------------------------------------------------- PPO
def _ppo():
    return load_script(ROOT / "baselines/ppo/ppo.py", "ppo")


def _rows(path):
    with open(path) as f:
        return list(csv.DictReader(f))


def test_ppo_runs_on_cpu_vector_envs_checkpoints_and_resumes(tmp_path):
    ppo = _ppo()
    args = ppo.Args(out_dir=str(tmp_path), num_envs=2, num_eval_envs=1, num_eval_episodes=1, num_steps=8,
                    num_minibatches=2, update_epochs=2, total_timesteps=32, eval_freq=2, max_episode_steps=6,
                    cuda=False, hidden=32)
    result = ppo.main(args)
    assert result["state"]["global_step"] == 32 and (tmp_path / "checkpoint.pt").exists()
    train, evals = _rows(tmp_path / "train.csv"), _rows(tmp_path / "eval.csv")
    assert [int(r["global_step"]) for r in train] == [16, 32]
    # 8 steps of 6-step episodes: each env ends one per iteration, counted once it ends.
    assert [int(r["episodes"]) for r in train] == [2, 2]
    assert all(0.0 <= float(r["success_once"]) <= 1.0 for r in evals) and len(evals) == 2  # 1 periodic + final
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert ckpt["state"]["iteration"] == 2 and float(ckpt["agent"]["obs_rms.count"]) > 30
    # The same command with a larger budget resumes from the checkpoint.
    args.total_timesteps = 48
    result = ppo.main(args)
    assert result["state"]["iteration"] == 3
    assert [int(r["global_step"]) for r in _rows(tmp_path / "train.csv")] == [16, 32, 48]


def test_ppo_maniskill_vector_env_path_runs_on_cpu(tmp_path):
    """The GPU path (ManiSkillVectorEnv around one batched env), on the CPU backend with
    one sub-scene: same loop, same logs."""
    ppo = _ppo()
    args = ppo.Args(out_dir=str(tmp_path), vector_env="maniskill", sim_backend="physx_cpu", num_envs=1,
                    num_eval_envs=1, num_eval_episodes=1, num_steps=8, num_minibatches=2, update_epochs=1,
                    total_timesteps=8, eval_freq=0, max_episode_steps=5, cuda=False, hidden=32, time_limit=600)
    result = ppo.main(args)
    assert result["state"]["global_step"] == 8 and result["final_eval"]["episodes"] == 1
    train = _rows(tmp_path / "train.csv")
    assert len(train) == 1 and int(train[0]["episodes"]) == 1


def test_pointcloud_observation_wrapper_feeds_the_pointnet_agent():
    from fetchbench_ms.envs.pointcloud import LABEL_TARGET
    from fetchbench_ms.envs.wrappers import PointCloudStateObs

    ppo = _ppo()
    env = PointCloudStateObs(gym.make("FetchBench-Table-v0", obs_mode="compact_pointcloud",
                                      control_mode="pd_joint_delta_pos"), points=64)
    try:
        obs, _ = env.reset(seed=1)
        assert obs.shape == (1, env.state_dim + 4 * 64) == (1, env.unwrapped.single_observation_space.shape[0])
        cloud = obs[:, env.state_dim:].reshape(1, 64, 4)
        # The last quarter comes from the target's block: every point labelled target.
        assert torch.all(cloud[0, 48:, 3] == LABEL_TARGET / 4.0) and torch.isfinite(obs).all()
        agent = ppo.Agent(obs.shape[1], 8, hidden=32, points=64)
        action, logprob, _, value = agent.get_action_and_value(obs)
        assert action.shape == (1, 8) and value.shape == (1, 1) and torch.isfinite(logprob).all()
        obs, *_ = env.step(action)
        assert obs.shape == (1, env.state_dim + 4 * 64)
    finally:
        env.close()
