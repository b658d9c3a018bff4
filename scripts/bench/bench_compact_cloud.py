"""Bytes per step of a demo converted to compact point clouds with the replay tool.

Records a scripted ``pd_joint_pos`` demo (state obs, no renderer needed) on a suite task,
converts it with ``python -m fetchbench_ms.replay_trajectory -o compact_pointcloud
--save-traj`` (optionally also ``-o pointcloud`` for comparison) and prints the converted
file's size per step and the observation bytes per step as stored (goal <= 150 KB).

    PYTHONPATH=. python scripts/bench/bench_compact_cloud.py [--steps 20] [--raw] [--out DIR]
"""
from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import gymnasium as gym
import h5py
import torch

import fetchbench_ms  # noqa: F401  (FetchBench-*-v0)
from fetchbench_ms import replay_trajectory
from mani_skill.utils.wrappers import RecordEpisode

GOAL_BYTES = 150_000


def record_demo(out: Path, steps: int, env_id: str = "FetchBench-v0", seed: int = 3, **kwargs) -> Path:
    """A scripted episode (swing the arm, close the gripper) recorded with RecordEpisode."""
    env = gym.make(env_id, obs_mode="state", control_mode="pd_joint_pos", render_backend="none", **kwargs)
    env = RecordEpisode(env, output_dir=str(out), trajectory_name="demo", save_video=False, source_type="scripted")
    env.reset(seed=seed)
    q0 = env.unwrapped.agent.robot.get_qpos()[0, :7].clone()
    dq = torch.tensor([0.4, 0.3, 0.0, 0.3, 0.0, -0.3, 0.2])
    for t in range(steps):
        gripper = 0.04 if t < steps - 4 else -0.01
        env.step(torch.cat([q0 + dq * min(1.0, (t + 1) / max(1, steps - 4)), torch.tensor([gripper])])[None])
    env.close()
    return out / "demo.h5"


def convert(demo: Path, obs_mode: str) -> Path:
    replay_trajectory.main(["--traj-path", str(demo), "-o", obs_mode, "--save-traj", "--allow-failure"])
    return demo.parent / f"demo.{obs_mode}.pd_joint_pos.physx_cpu.h5"


def stored_bytes(group) -> int:
    """Bytes the datasets under an h5 group take in the file (after compression)."""
    total = 0

    def visit(_name, obj):
        nonlocal total
        if isinstance(obj, h5py.Dataset):
            total += obj.id.get_storage_size()

    group.visititems(visit)
    return total


def per_step(path: Path) -> dict:
    """File bytes, observation bytes and steps (observations) of a converted demo."""
    with h5py.File(path, "r") as f:
        traj = f["traj_0"]
        steps = traj["actions"].shape[0] + 1  # observations: the reset's and one per action
        obs = stored_bytes(traj["obs"])
        shapes = {k: (v.shape[1:], str(v.dtype)) for k, v in traj["obs/pointcloud"].items()}
    return {"steps": steps, "file_per_step": os.path.getsize(path) / steps, "obs_per_step": obs / steps,
            "pointcloud": shapes}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--suite", default="val", help="the task suite of the demo's task")
    parser.add_argument("--raw", action="store_true", help="also convert to the raw pointcloud mode")
    parser.add_argument("--out", default=None, help="folder for the demo and conversions (default: a temp folder)")
    args = parser.parse_args()
    out = Path(args.out or tempfile.mkdtemp(prefix="compact_cloud_"))
    out.mkdir(parents=True, exist_ok=True)
    demo = record_demo(out, args.steps, task_suite=args.suite)
    for mode in ["compact_pointcloud"] + (["pointcloud"] if args.raw else []):
        r = per_step(convert(demo, mode))
        verdict = "" if mode != "compact_pointcloud" else (
            " (goal <= 150 KB: " + ("met" if r["file_per_step"] <= GOAL_BYTES else "NOT met") + ")")
        print(f"{mode}: {r['steps']} observations, file {r['file_per_step'] / 1000:.1f} KB/step, "
              f"observations {r['obs_per_step'] / 1000:.1f} KB/step{verdict}; pointcloud {r['pointcloud']}")


if __name__ == "__main__":
    main()
