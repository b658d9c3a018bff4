"""Benchmark resets to a new task (state obs, CPU): median and p95 seconds.

Two kinds of reset, each to a task other than the loaded one (a rebuild of the scene):

- ``suite``: ``reset(options={"task_id": ...})`` over the tasks of a shipped suite (``val``
  by default), alternating scene types: the cost of loading a new, pre-settled task; the
  same tasks twice: first loads (objects new to the process), then again (every reset
  still rebuilds the scene, but meshes and collision shapes are cached);
- ``seed``: ``reset(seed=s)`` with new seeds and the env's default kwargs: what an RL user
  pays per episode (with ``--task-source sampled``, or on code without suites as default,
  this includes sampling and settling the task).

    PYTHONPATH=. python scripts/bench/bench_reset.py [--resets 30] [--kinds suite seed] [--task-source sampled]
        [--task-suite val]

Run it on the code to compare (``PYTHONPATH=<checkout>``); the figures are wall-clock on
this machine, so compare runs made under the same load.
"""
from __future__ import annotations

import argparse
import inspect
import statistics
import time

import gymnasium as gym
import numpy as np
import torch

import fetchbench_ms  # noqa: F401  (FetchBench-*-v0)
from fetchbench_ms.envs.fetchbench import FetchBenchEnv
from fetchbench_ms.tasks.suite import load_suite


def summary(times: list[float]) -> str:
    return (f"median {statistics.median(times):.3f} s, p95 {float(np.percentile(times, 95)):.3f} s, "
            f"min {min(times):.3f} s, max {max(times):.3f} s (n={len(times)})")


def suite_resets(suite_name: str, n: int) -> list[float]:
    suite = load_suite(suite_name)
    by_type: dict[str, list[str]] = {}
    for task_id, task in suite.tasks.items():
        by_type.setdefault(task.scene_type, []).append(task_id)
    # Round robin over the scene types: every reset loads another scene.
    order = [ids[k] for k in range(max(map(len, by_type.values()))) for ids in by_type.values() if k < len(ids)]
    env = gym.make("FetchBench-v0", obs_mode="state", task_suite=suite_name)
    env.reset(options={"task_id": order[-1]})  # warm-up: first build, robot loading
    first, again = [], []
    tasks = (order * (1 + n // len(order)))[:n]
    for times in (first, again):  # the tasks once, then once more (each still a rebuild)
        for task_id in tasks:
            start = time.perf_counter()
            env.reset(options={"task_id": task_id})
            times.append(time.perf_counter() - start)
    env.close()
    return first, again


def seed_resets(n: int, kwargs: dict) -> list[float]:
    env = gym.make("FetchBench-v0", obs_mode="state", **kwargs)
    env.reset(seed=10_000)  # warm-up
    times = []
    for seed in range(n):
        start = time.perf_counter()
        env.reset(seed=seed)
        times.append(time.perf_counter() - start)
    env.close()
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resets", type=int, default=30)
    parser.add_argument("--suite", default="val")
    parser.add_argument("--kinds", nargs="+", default=["suite", "seed"], choices=["suite", "seed"])
    parser.add_argument("--task-source", default=None,
                        help="the env's task_source kwarg for the seed resets (code of issue 20 on)")
    parser.add_argument("--task-suite", default=None,
                        help="the env's task_suite kwarg for the seed resets (e.g. val while train is not shipped)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    kwargs = {}
    if args.task_source is not None:
        if "task_source" not in inspect.signature(FetchBenchEnv.__init__).parameters:
            raise SystemExit("this code has no task_source kwarg")
        kwargs["task_source"] = args.task_source
    if args.task_suite is not None:
        kwargs["task_suite"] = args.task_suite
    if "suite" in args.kinds:
        first, again = suite_resets(args.suite, args.resets)
        print(f"new suite task ({args.suite}, task_id option), first load in the process: {summary(first)}")
        print(f"new suite task, loaded before in the process (caches warm): {summary(again)}")
    if "seed" in args.kinds:
        print(f"new seed (default kwargs{', ' + str(kwargs) if kwargs else ''}): "
              f"{summary(seed_resets(args.resets, kwargs))}")


if __name__ == "__main__":
    main()
