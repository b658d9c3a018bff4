"""Benchmark the FetchBench envs on this machine (CPU).

Prints:
- env step time with state obs, and its ratio to ManiSkill's PickCube-v1 measured in the
  same process (goal <= 1.5x);
- the median time to load a new task (reset with a new seed: sampling the task, settling
  it, and rebuilding the scene), split into sampling and reconfiguring (goal <= 1 s);
- the time of one point-cloud observation at 320x240 and 640x480.

    PYTHONPATH=. python scripts/bench/bench_env.py [--steps 1000] [--tasks 15]
"""
from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import mani_skill.envs  # noqa: F401  (PickCube-v1)
import torch

import fetchbench_ms  # noqa: F401  (FetchBench-*-v0)
from fetchbench_ms.envs import fetchbench as fetchbench_env


def step_times(env_ids: list[str], steps: int, rounds: int = 10) -> dict[str, float]:
    """Median seconds per env.step (zero delta-joint actions: the arm holds still) of each
    env. The envs take turns in blocks of ``steps / rounds`` steps, so a load from other
    processes on this shared machine falls on all of them alike."""
    envs, actions = {}, {}
    for env_id in env_ids:
        envs[env_id] = gym.make(env_id, obs_mode="state", control_mode="pd_joint_delta_pos")
        envs[env_id].reset(seed=0)
        actions[env_id] = torch.zeros(envs[env_id].action_space.shape)
        for _ in range(10):
            envs[env_id].step(actions[env_id])
    block = max(1, steps // rounds)
    samples = {env_id: [] for env_id in env_ids}
    for _ in range(rounds):
        for env_id, env in envs.items():
            start = time.perf_counter()
            for _ in range(block):
                env.step(actions[env_id])
            samples[env_id].append((time.perf_counter() - start) / block)
    for env in envs.values():
        env.close()
    return {env_id: statistics.median(v) for env_id, v in samples.items()}


def new_task_times(n: int) -> tuple[list[float], list[float], list[float]]:
    """(total, sampling, reconfigure) seconds for ``n`` resets to new tasks."""
    env = gym.make("FetchBench-v0", obs_mode="state")
    env.reset(seed=1000)
    sample_s = []
    original = fetchbench_env.FetchBenchEnv._sample_task

    def timed_sample(self, seed):
        t = time.perf_counter()
        task = original(self, seed)
        sample_s.append(time.perf_counter() - t)
        return task

    fetchbench_env.FetchBenchEnv._sample_task = timed_sample
    totals = []
    try:
        for seed in range(n):
            start = time.perf_counter()
            _, info = env.reset(seed=seed)
            totals.append(time.perf_counter() - start)
            assert bool(info["reconfigure"]), "a new task must reconfigure"
    finally:
        fetchbench_env.FetchBenchEnv._sample_task = original
        env.close()
    return totals, sample_s, [t - s for t, s in zip(totals, sample_s)]


def pointcloud_time(width: int, height: int, repeats: int = 5) -> float:
    env = gym.make("FetchBench-v0", obs_mode="pointcloud", camera_width=width, camera_height=height)
    env.reset(seed=0)
    base = env.unwrapped
    base.get_obs()  # first render compiles shaders
    start = time.perf_counter()
    for _ in range(repeats):
        base.get_obs()
    elapsed = (time.perf_counter() - start) / repeats
    env.close()
    return elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=1000, help="steps per env for the step time")
    parser.add_argument("--tasks", type=int, default=15)
    args = parser.parse_args()
    torch.set_num_threads(1)

    times = step_times(["PickCube-v1", "FetchBench-v0"], args.steps)
    pick, fetch = times["PickCube-v1"], times["FetchBench-v0"]
    print(f"step time, state obs: PickCube-v1 {pick * 1e3:.2f} ms, FetchBench-v0 {fetch * 1e3:.2f} ms, "
          f"ratio {fetch / pick:.2f}x (goal <= 1.5x)")
    # Worst case: the hand near the target, where every step runs the contact-based grasp
    # test over all of the scene's contacts (skipped while the hand is far).
    reach = fetchbench_env.FINGER_REACH
    fetchbench_env.FINGER_REACH = 100.0
    try:
        times = step_times(["PickCube-v1", "FetchBench-v0"], args.steps)
    finally:
        fetchbench_env.FINGER_REACH = reach
    print(f"  with the grasp test on every step (hand near the target): FetchBench-v0 "
          f"{times['FetchBench-v0'] * 1e3:.2f} ms, ratio {times['FetchBench-v0'] / times['PickCube-v1']:.2f}x")
    totals, sampling, reconfig = new_task_times(args.tasks)
    print(f"new task (median of {args.tasks}): total {statistics.median(totals):.2f} s = sampling+settling "
          f"{statistics.median(sampling):.2f} s + reconfigure {statistics.median(reconfig):.2f} s (goal <= 1 s)")
    for width, height in ((320, 240), (640, 480)):
        print(f"point-cloud observation {width}x{height} (2 cameras): {pointcloud_time(width, height) * 1e3:.0f} ms")


if __name__ == "__main__":
    main()
