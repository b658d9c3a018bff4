"""Environment throughput for RL on the CPU: steps per second with state observations.

- ``single``: one env in this process (what one core gives), random pd_joint_delta_pos
  actions, episodes of ``--max-episode-steps`` with a reset (to the next seed's task) at
  each end, so the rate includes resets as training sees them; also the step alone;
- ``vector``: ``fetchbench_ms.envs.make_vec_env`` with N worker processes (gymnasium
  AsyncVectorEnv of CPUGymWrapper envs, same-step autoreset, as ``baselines/ppo`` runs
  them), for each N of ``--num-envs``: total and per-env steps per second.

The first episodes of a process load new tasks (and, with a curriculum, make them easier);
``--warmup`` steps are run before timing.

    PYTHONPATH=. python scripts/bench/bench_rl_env.py --env-id FetchBench-Table-v0 --num-envs 16 32 \\
        --steps 3000 --out build/bench-rl-env.json [--curriculum table-near-pregrasp]
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch

import fetchbench_ms  # noqa: F401
from fetchbench_ms.envs import make_vec_env
from fetchbench_ms.envs.curriculum import prepare
from fetchbench_ms.utils.io import atomic_write_text


def env_kwargs(args) -> dict:
    kwargs = dict(obs_mode="state", control_mode="pd_joint_delta_pos", reward_mode="normalized_dense",
                  render_backend="none", max_episode_steps=args.max_episode_steps)
    if args.curriculum:
        kwargs["curriculum"] = args.curriculum
    return kwargs


def single(args) -> dict:
    torch.set_num_threads(1)
    env = gym.make(args.env_id, **env_kwargs(args))
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    seed = 1

    def run(n: int) -> tuple[float, float, int]:
        nonlocal seed
        stepping, resets = 0.0, 0
        start = time.perf_counter()
        for _ in range(n):
            t = time.perf_counter()
            _, _, terminated, truncated, _ = env.step(torch.as_tensor(rng.uniform(-1, 1, (1, 8)), dtype=torch.float32))
            stepping += time.perf_counter() - t
            if bool(terminated | truncated):
                env.reset(seed=seed)
                seed, resets = seed + 1, resets + 1
        return time.perf_counter() - start, stepping, resets

    run(args.warmup)
    total, stepping, resets = run(args.steps)
    env.close()
    return {"steps": args.steps, "steps_per_s": round(args.steps / total, 1),
            "steps_per_s_without_resets": round(args.steps / stepping, 1), "resets": resets,
            "ms_per_step": round(1000 * stepping / args.steps, 3),
            "s_per_reset": round((total - stepping) / max(resets, 1), 3)}


def vector(args, num_envs: int) -> dict:
    start = time.perf_counter()
    envs = make_vec_env(args.env_id, num_envs, autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, **env_kwargs(args))
    envs.reset(seed=0)
    started = time.perf_counter() - start
    rng = np.random.default_rng(0)
    for _ in range(max(1, args.warmup // num_envs)):
        envs.step(rng.uniform(-1, 1, (num_envs, 8)).astype(np.float32))
    rounds = max(1, args.steps // num_envs)
    episodes = 0
    start = time.perf_counter()
    for _ in range(rounds):
        _, _, terminated, truncated, _ = envs.step(rng.uniform(-1, 1, (num_envs, 8)).astype(np.float32))
        episodes += int(np.sum(terminated | truncated))
    elapsed = time.perf_counter() - start
    envs.close()
    return {"num_envs": num_envs, "steps": rounds * num_envs, "steps_per_s": round(rounds * num_envs / elapsed, 1),
            "steps_per_s_per_env": round(rounds / elapsed, 1), "episodes": episodes,
            "startup_s": round(started, 1)}


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env-id", default="FetchBench-Table-v0")
    p.add_argument("--curriculum", default=None)
    p.add_argument("--num-envs", type=int, nargs="*", default=[16, 32])
    p.add_argument("--steps", type=int, default=3000, help="timed steps (over all envs)")
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--max-episode-steps", type=int, default=100)
    p.add_argument("--skip-single", action="store_true")
    p.add_argument("--out", type=Path, default=None)
    args = p.parse_args(argv)
    result = {"env_id": args.env_id, "curriculum": args.curriculum, "max_episode_steps": args.max_episode_steps,
              "cpu_count": os.cpu_count(), "torch": torch.__version__}
    if args.curriculum:
        t = time.perf_counter()
        result["curriculum_tasks"] = prepare(args.env_id, args.curriculum, processes=os.cpu_count())
        result["curriculum_prepare_s"] = round(time.perf_counter() - t, 1)
    if not args.skip_single:
        result["single"] = single(args)
        print(json.dumps(result["single"]), flush=True)
    result["vector"] = []
    for n in args.num_envs:
        result["vector"].append(vector(args, n))
        print(json.dumps(result["vector"][-1]), flush=True)
    print(json.dumps(result, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
