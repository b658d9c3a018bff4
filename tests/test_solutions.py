"""The sense-plan-act pipeline: the runner's bookkeeping (fast) and end-to-end episodes
on an easy task, an object alone on an open table (slow: builds the env)."""
import json

import numpy as np
import pytest
import trimesh

from fetchbench_ms.solutions import FAILURE_CLASSES, PHASES, summarize
from fetchbench_ms.solutions import runner


def _record(seed, category, success, failure=None, time=1.0):
    return {"seed": seed, "category": category, "success": success, "failure": failure,
            "computation_time": time, "cspace_length": 2.0 * seed, "method": "ga-mesh-rrt",
            "env_id": "FetchBench-v0", "retries": 1, "phases": {p: success for p in PHASES}}


def test_summary_by_category():
    records = [_record(0, "on_table", True, time=1.0), _record(1, "on_table", False, "grasp_failure", time=3.0),
               _record(2, "on_shelf", False, "motion_planning_failure", time=5.0)]
    s = summarize(records)
    assert s["on_table"]["success_rate"] == 0.5
    assert s["on_table"]["median_computation_time"] == 2.0
    assert s["on_shelf"]["failures"]["motion_planning_failure"] == 1
    assert s["all"]["episodes"] == 3 and s["all"]["success_rate"] == pytest.approx(1 / 3, abs=1e-4)
    assert set(s["all"]["failures"]) == set(FAILURE_CLASSES)
    table = runner.format_summary(s)
    assert "on_table" in table and "grasp_failure 1" in table


def test_runner_appends_and_resumes(tmp_path, monkeypatch):
    solved = []

    def fake_solve(env, seed, method, retries, reset):
        assert not reset  # the runner resets (and may filter) first
        solved.append(seed)
        return _record(seed, "on_table", seed % 2 == 0)

    class FakeEnv:
        def reset(self, seed):
            if seed == 15:
                raise ValueError("robot_table_size must be positive")

        def close(self):
            pass

    monkeypatch.setattr(runner, "solve", fake_solve)
    monkeypatch.setattr(runner, "make_env", lambda method, env_id: FakeEnv())
    runner.run_episodes("ga-mesh-rrt", "FetchBench-v0", 3, 10, str(tmp_path), progress=False)
    records = runner.run_episodes("ga-mesh-rrt", "FetchBench-v0", 6, 10, str(tmp_path), progress=False)
    assert solved == [10, 11, 12, 13, 14]  # the second run only did the missing seeds
    assert [r["seed"] for r in records] == [10, 11, 12, 13, 14, 15]
    assert "reset failed" in records[-1]["skipped"]  # a task that cannot be built is skipped, not fatal
    lines = (tmp_path / runner.RESULTS_FILE).read_text().splitlines()
    assert len(lines) == 6 and all(json.loads(l)["env_id"] == "FetchBench-v0" for l in lines)
    summary = json.loads((tmp_path / runner.SUMMARY_FILE).read_text())
    assert summary["all"]["episodes"] == 5 and summary["all"]["success_rate"] == 0.6
    with open(tmp_path / runner.RESULTS_FILE, "a") as f:
        f.write("{not json\n")
    with pytest.raises(ValueError, match="not a JSON line"):
        runner.run_episodes("ga-mesh-rrt", "FetchBench-v0", 7, 10, str(tmp_path), progress=False)


def test_bad_method_is_a_clear_error(capsys):
    from fetchbench_ms.cli import main
    from fetchbench_ms.solutions import solve

    with pytest.raises(ValueError, match="valid: ga-mesh-rrt, ga-ptd-rrt"):
        solve(None, seed=0, method="ga-mesh-rrtx")
    assert main(["eval", "--method", "cgn-rrt", "--episodes", "1"]) == 2
    assert "valid: ga-mesh-rrt, ga-ptd-rrt" in capsys.readouterr().err


def easy_table_task(env, seed: int = 5) -> dict:
    """A sampled on-table task with every object but the target removed."""
    env.reset(seed=seed)
    task = env.unwrapped.tasks[0].to_dict()
    task["objects"] = [task["objects"][task["target_index"]]]
    task["target_index"] = 0
    return task


@pytest.mark.slow
@pytest.mark.parametrize("method,obs_mode", [("ga-mesh-rrt", "none"), ("ga-ptd-rrt", "pointcloud")])
def test_easy_table_task_succeeds_end_to_end(method, obs_mode, tmp_path, monkeypatch):
    from fetchbench_ms.envs import make
    from fetchbench_ms.solutions import solve
    from fetchbench_ms.solutions.grasp_source import object_grasps

    # Grasps: the antipodal stand-in (an empty grasp store), so this tests the pipeline
    # whatever the state of the shipped labels (a stale store fails loudly by design).
    monkeypatch.setenv("FETCHBENCH_GRASPS_DIR", str(tmp_path))
    object_grasps.cache_clear()

    env = make("FetchBench-Table-v0", obs_mode=obs_mode, control_mode="pd_joint_pos")
    task = easy_table_task(env)
    env.reset(options={"task": task})
    result = solve(env, seed=5, method=method, reset=False)
    json.dumps(result)  # one JSON line per episode
    assert result["success"], result["notes"]
    assert result["failure"] is None and all(result["phases"].values())
    assert 0 < result["computation_time"] < 60 and result["cspace_length"] > 1.0
    # The target ended up held in free space, in the base frame's success region.
    info = env.unwrapped.evaluate()
    assert bool(info["is_lifted"][0]) and bool(info["is_retrieved"][0])
    env.close()


def test_robot_points_are_removed_from_the_scene_cloud():
    import torch

    from fetchbench_ms.planning.robot import Q_DEFAULT, panda
    from fetchbench_ms.solutions.worlds import remove_robot_points

    robot = panda()
    q_full = np.r_[Q_DEFAULT, 0.04]
    poses = robot.link_poses(torch.as_tensor(Q_DEFAULT)[None], 0.04)
    rng = np.random.default_rng(0)
    on_robot = []
    for link in ("panda_link3", "panda_link5", "panda_hand"):  # surface points of the arm as a camera sees it
        points, _ = trimesh.sample.sample_surface(robot.collision_meshes[link], 200, seed=rng)
        T = poses[link][0].numpy()
        on_robot.append(points @ T[:3, :3].T + T[:3, 3])
    elsewhere = rng.uniform([0.6, -0.5, 0.0], [1.0, 0.5, 0.3], (300, 3))  # furniture in front of the robot
    kept = remove_robot_points(np.concatenate(on_robot + [elsewhere]), q_full)
    assert len(kept) == len(elsewhere) and np.allclose(kept, elsewhere)
