"""The other hardware setups (docs/robots.md): generated URDFs, agents in every obs and
control mode, the planner's model of each robot, plans that hold in physics, and the
robot as an evaluation option."""
from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET

import gymnasium as gym
import numpy as np
import pytest
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms.envs import control_modes
from fetchbench_ms.envs.fetchbench import MANISKILL_OBS_MODES
from fetchbench_ms.planning.checker import CollisionChecker
from fetchbench_ms.planning.ik import solve_ik
from fetchbench_ms.planning.robot import panda, robot_model
from fetchbench_ms.planning.rrt import plan_rrtconnect
from fetchbench_ms.planning.world import CollisionWorld
from fetchbench_ms.robots import ROBOT_UIDS, SETUPS, assets, robot_setup
from mani_skill.utils import common

OTHER_ROBOTS = tuple(uid for uid in ROBOT_UIDS if uid != "panda")
#: A quick, fixed task (as tests/test_envs_modes.py): a Desk with 2 objects.
GRID_ENV, GRID_SEED = "FetchBench-Desk-v0", 2022
GRID_KWARGS = dict(task_source="sampled", num_objects=2, sensor_configs=dict(width=80, height=60))
KEY_CONTROL_MODES = ("pd_joint_pos", "pd_joint_delta_pos", "pd_ee_delta_pose")


def test_setups_name_existing_links_and_joints():
    for uid in ROBOT_UIDS:
        setup = robot_setup(uid)
        path = robot_model(uid).urdf_path
        root = ET.parse(path).getroot()
        links = {l.get("name") for l in root.findall("link")}
        joints = {j.get("name"): j.get("type") for j in root.findall("joint")}
        for link in (setup.base_link, setup.hand_link, setup.tcp_link, setup.wrist_link, *setup.finger_links,
                     *setup.hand_links, *setup.proximal_links, *setup.world_links):
            assert link in links, (uid, link)
        for joint in setup.arm_joints + setup.gripper_joints:
            assert joints.get(joint) in ("revolute", "prismatic"), (uid, joint)
    with pytest.raises(ValueError, match="unknown robot 'ur5'; valid: panda, kinova_gen3_panda_hand, kinova_gen3_robotiq"):
        robot_setup("ur5")


def test_generated_urdfs_come_from_installed_packages():
    for uid in OTHER_ROBOTS:
        path = assets.urdf_path(uid)
        root = ET.parse(path).getroot()
        files = [m.get("filename") for m in root.iter("mesh")]
        assert files and all(f.startswith("/") for f in files)
        import os

        assert all(os.path.exists(f) for f in files)
        # Same sources, same file: the name hashes the text.
        assert assets.build_urdf(uid)[0] in open(path).read()


def test_robotiq_four_bar_anchors_match_its_kinematics():
    """The inner knuckle's far pivot (anchor in its frame) and the inner finger's anchor
    coincide at every opening of the coupled joints: the drive closes a real loop."""
    model = robot_model("kinova_gen3_robotiq")
    anchors = assets.urdf_extra("kinova_gen3_robotiq")["anchors"]
    for finger in np.linspace(0.0, model.finger_open, 5):
        poses = model.link_poses(np.asarray(model.q_home), finger)
        for side in ("left", "right"):
            a = poses[f"{side}_inner_knuckle"][0].numpy() @ np.r_[anchors[side]["knuckle"], 1.0]
            b = poses[f"{side}_inner_finger"][0].numpy() @ np.r_[anchors[side]["finger"], 1.0]
            assert np.linalg.norm(a - b) < 1e-6


def test_finger_opening_maps_to_gripper_joints_and_back():
    model = robot_model("kinova_gen3_robotiq")
    openings = np.linspace(0.005, model.finger_open, 7)
    angles = model.gripper_q(openings)[:, 0].numpy()
    assert np.all(np.diff(angles) < 0)  # wider opening, smaller knuckle angle
    back = [model.finger_from_gripper_q([a]) for a in angles]
    assert np.allclose(back, openings, atol=2e-4)
    # The pads stand where the opening says (pad centre minus half a pad).
    poses = model.link_poses(np.asarray(model.q_home), 0.03)
    T = torch.linalg.inv(poses["robotiq_hand"][0]) @ poses["right_inner_finger_pad"][0]
    assert abs(float(T[1, 3].abs()) - 0.00635 / 2 - 0.03) < 2e-4
    # The Franka hand takes the opening as it is.
    assert robot_model("kinova_gen3_panda_hand").gripper_q(0.03).tolist() == [[0.03, 0.03]]


def test_start_configurations_put_the_tcp_where_the_pandas_is():
    """``RobotSetup.q_home`` (scripts/maint/robot_home.py): the Panda's start TCP pose, or with
    the Robotiq the highest pose straight below it the arm reaches; free of self-collision."""
    T_panda = panda().tcp_pose(np.asarray(SETUPS["panda"].q_home)).numpy()[0]
    for uid in OTHER_ROBOTS:
        model = robot_model(uid)
        T = model.tcp_pose(model.q_home).numpy()[0]
        assert np.allclose(T[:3, :3], T_panda[:3, :3], atol=0.02)
        assert np.allclose(T[:2, 3], T_panda[:2, 3], atol=0.002)
        assert -0.2 <= T[2, 3] - T_panda[2, 3] <= 0.002
        assert CollisionChecker(model, CollisionWorld()).valid(model.q_home[None])[0]


def test_sphere_models_cover_the_collision_meshes():
    """The fitted spheres (generated from the URDF's meshes) contain every mesh vertex."""
    for uid in OTHER_ROBOTS:
        model = robot_model(uid)
        sp = model.spheres
        for k, link in enumerate(sp.links):
            vertices = model.collision_meshes[link].vertices
            if len(vertices) > 4000:
                vertices = vertices[np.random.default_rng(0).choice(len(vertices), 4000, replace=False)]
            centers, radii = sp.centers_link[sp.link_index == k], sp.radii[sp.link_index == k]
            d = np.linalg.norm(vertices[:, None] - centers[None], axis=2) - radii[None]
            assert d.min(axis=1).max() <= 1e-9, (uid, link)


def test_ik_reaches_the_pose_exactly_or_not_at_all():
    for uid in OTHER_ROBOTS:
        model = robot_model(uid)
        T = model.tcp_pose(model.q_home).numpy()[0]
        T[0, 3] += 0.25
        result = solve_ik(model, T, n_seeds=16, rng=np.random.default_rng(0))
        assert result.found
        reached = model.tcp_pose(result.q).numpy()
        assert np.abs(reached[:, :3, 3] - T[:3, 3]).max() <= 0.002
        far = T.copy()
        far[0, 3] += 2.0  # beyond any reach
        assert not solve_ik(model, far, n_seeds=8, rng=np.random.default_rng(0)).found


@pytest.mark.parametrize("uid", OTHER_ROBOTS)
@pytest.mark.parametrize("obs_mode", MANISKILL_OBS_MODES)
def test_every_obs_mode_with_the_key_control_modes(uid, obs_mode):
    for control_mode in KEY_CONTROL_MODES:
        _make_reset_step(uid, obs_mode, control_mode)


@pytest.mark.parametrize("uid", OTHER_ROBOTS)
def test_every_control_mode(uid):
    for control_mode in control_modes():
        _make_reset_step(uid, "state", control_mode)


@pytest.mark.slow
@pytest.mark.parametrize("uid", OTHER_ROBOTS)
@pytest.mark.parametrize("obs_mode", MANISKILL_OBS_MODES)
def test_every_obs_mode_with_every_control_mode(uid, obs_mode):
    for control_mode in control_modes():
        _make_reset_step(uid, obs_mode, control_mode)


def _make_reset_step(uid, obs_mode, control_mode):
    env = gym.make(GRID_ENV, robot_uids=uid, obs_mode=obs_mode, control_mode=control_mode, **GRID_KWARGS)
    try:
        obs, _ = env.reset(seed=GRID_SEED)
        assert env.observation_space.contains(common.to_numpy(obs)), (uid, obs_mode, control_mode)
        env.action_space.seed(0)
        obs, reward, *_ = env.step(env.action_space.sample())
        assert env.observation_space.contains(common.to_numpy(obs)), (uid, obs_mode, control_mode)
        assert torch.isfinite(reward).all()
        assert env.unwrapped.agent.uid == uid
    finally:
        env.close()


def test_robot_uids_is_checked_at_make():
    with pytest.raises(ValueError, match="unknown robot 'ur10e'; valid: panda, kinova_gen3_panda_hand"):
        gym.make(GRID_ENV, robot_uids="ur10e", **GRID_KWARGS)


@pytest.mark.parametrize("uid", OTHER_ROBOTS)
def test_a_planned_motion_is_collision_free_in_physics(uid):
    """RRTConnect on the env's mesh world from the start configuration to an IK solution
    in front of the furniture; executed with pd_joint_pos, no link touches the furniture
    or the robot table (contact force) and no object moves."""
    from fetchbench_ms.solutions.sense_plan_act import EpisodeState, Executor, SolveConfig
    from fetchbench_ms.planning.world_models import mesh_world

    env = gym.make("FetchBench-v0", robot_uids=uid, obs_mode="none", control_mode="pd_joint_pos",
                   task_suite="smoke", reward_mode="dense")
    try:
        env.reset(seed=0, options={"task_id": "smoke/0002"})
        u = env.unwrapped
        model = robot_model(uid)
        checker = CollisionChecker(model, mesh_world(env))
        q_start = u.start_arm_qpos(0)
        assert checker.valid(q_start[None])[0]
        T = model.tcp_pose(q_start).numpy()[0]
        goals = None
        for dx, dz in ((0.2, 0.0), (0.15, -0.1), (0.1, 0.1), (0.25, -0.05)):
            T_goal = T.copy()
            T_goal[0, 3] += dx
            T_goal[2, 3] += dz
            result = solve_ik(model, T_goal, checker=checker, n_seeds=16, rng=np.random.default_rng(1))
            if result.found:
                goals = result.q[:4]
                break
        assert goals is not None
        plan = plan_rrtconnect(checker, q_start, goals, seed=0, max_checks=20000)
        assert plan.success
        state = EpisodeState(SolveConfig())
        ex = Executor(env, state)
        before = u.evaluate()
        worst = 0.0
        for q in plan.path:
            ex.follow(np.stack([ex.q, q]), speed_scale=0.4, settle_steps=2)
            info = u.evaluate()
            worst = max(worst, float(u._contact_forces_cpu()["robot_furniture_force"][0]))
        assert worst < 1.0, f"robot pushed the furniture with {worst:.2f} N"
        assert float(u.evaluate()["max_others_moved"][0]) < 0.01
        assert np.abs(ex.q - plan.path[-1]).max() < 0.05
        del before, info
    finally:
        env.close()


@pytest.mark.parametrize("uid", OTHER_ROBOTS)
def test_gripper_closes_and_squeezes(uid):
    """The gripper action closes the fingers (the Robotiq's runs the other way: +1 closes),
    and settle_and_hold drives them past closed."""
    from fetchbench_ms.envs import settle_and_hold

    env = gym.make(GRID_ENV, robot_uids=uid, obs_mode="none", control_mode="pd_joint_pos", **GRID_KWARGS)
    try:
        env.reset(seed=GRID_SEED)
        u = env.unwrapped
        model = robot_model(uid)
        q = u.start_arm_qpos(0)
        sign = u.agent.gripper_action_sign
        for _ in range(20):
            env.step(np.r_[q, -sign].astype(np.float32))
        closed = model.finger_from_gripper_q(u.agent.robot.get_qpos()[0, 7:8].numpy())
        for _ in range(20):
            env.step(np.r_[q, sign].astype(np.float32))
        opened = model.finger_from_gripper_q(u.agent.robot.get_qpos()[0, 7:8].numpy())
        assert closed < 0.005 and opened > model.finger_open - 0.005, (closed, opened)
        settle_and_hold(env, seconds=0.5)
        assert model.finger_from_gripper_q(u.agent.robot.get_qpos()[0, 7:8].numpy()) < 0.005
    finally:
        env.close()


def test_eval_records_the_robot(tmp_path):
    out = tmp_path / "eval"
    cmd = [sys.executable, "-m", "fetchbench_ms", "eval", "--method", "ga-mesh-rrt", "--robot", "kinova_gen3_panda_hand",
           "--suite", "smoke", "--tasks", "2:3", "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    run = json.loads((out / "run.json").read_text())
    assert run["method_options"]["robot"] == "kinova_gen3_panda_hand"
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    assert len(records) == 1 and records[0]["robot"] == "kinova_gen3_panda_hand" and not records[0].get("error")
    bad = subprocess.run(cmd[:-2] + ["--robot", "ur5", "--out", str(tmp_path / "bad")], capture_output=True, text=True)
    assert bad.returncode == 2 and "invalid choice: 'ur5'" in bad.stderr
    learned = subprocess.run([sys.executable, "-m", "fetchbench_ms", "eval", "--method", "e2e-mlp", "--robot",
                              "kinova_gen3_robotiq", "--suite", "smoke", "--tasks", "0:1", "--out", str(tmp_path / "l")],
                             capture_output=True, text=True)
    assert learned.returncode == 2 and "runs on the Panda only" in learned.stderr


def test_robotiq_labeller_tries_franka_candidates_in_physics():
    """The Robotiq re-tries the shipped Franka-hand candidates (grasp_labels.robotiq): poses where
    its open hand cuts the object are dropped, the rest get physics verdicts, and some of
    the Franka hand's successes hold in the Robotiq too."""
    from fetchbench_ms.grasp_labels.robotiq import RobotiqLabeller, collision_free, franka_candidates
    from fetchbench_ms.grasp_labels.store import load_grasps
    from fetchbench_ms.objects.catalog import get_object

    object_id = "blob/233"
    asset = get_object(object_id)
    franka = load_grasps(object_id)
    poses = franka_candidates(object_id)[franka.success][:16]
    free = collision_free(asset, poses)
    assert free.any()
    # A pose sunk 5 cm further along its approach puts the palm into the object.
    sunk = poses[free][:1].copy()
    sunk[0, :3, 3] += 0.05 * sunk[0, :3, 2]
    assert not collision_free(asset, sunk)[0]
    labeller = RobotiqLabeller(slots=8)
    result = labeller.label(asset, poses[free][:8])
    assert result.success.any()
    held = result.width[result.success]
    assert np.all((held > 0.005) & (held < 0.085))


def test_grasp_labels_option_is_checked(tmp_path):
    cmd = [sys.executable, "-m", "fetchbench_ms", "eval", "--method", "ga-mesh-rrt", "--robot", "kinova_gen3_robotiq",
           "--grasp-labels", str(tmp_path / "none"), "--suite", "smoke", "--tasks", "0:1", "--out", str(tmp_path / "o")]
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 2 and "no grasp manifest" in done.stderr
    cmd[5] = "cgn-ptd-rrt"
    done = subprocess.run(cmd, capture_output=True, text=True)
    assert done.returncode == 2 and "--grasp-labels applies to the annotated-grasp methods" in done.stderr


@pytest.mark.parametrize("uid", OTHER_ROBOTS)
def test_expert_fetches_with_every_robot(uid):
    """The expert (annotated grasps, oracle mesh world; every step through env.step, so
    recordable) carries the target out on a smoke task both Kinova setups solve."""
    from fetchbench_ms.solutions.expert import solve_demo

    env = gym.make("FetchBench-v0", robot_uids=uid, obs_mode="none", control_mode="pd_joint_pos", task_suite="smoke")
    try:
        demo = solve_demo(env, seed=0, reset_options={"task_id": "smoke/0005"})
        assert demo.success, demo.failure
        assert env.unwrapped.agent.uid == uid
    finally:
        env.close()
