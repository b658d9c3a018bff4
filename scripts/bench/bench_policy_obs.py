"""Frames a second of the imitation policies' observation, and where a frame's time goes.

Renders recorded env states of the demo sample (as the converter's render pass does: set the
state, read the observation, make the policy's points) in three ways, frame by frame in turn so
that all see the same machine load:

- ``compact`` (the ``compact_pointcloud`` path the shipped checkpoints were trained on): two
  320x240 cameras (colour, position, segmentation) -> ManiSkill's camera cloud (153,600 points)
  -> ``add_fetch_pointcloud`` -> the compact cloud (22,528) -> ``subsample_compact`` (1,792);
- ``policy`` (``obs_mode="policy_pointcloud"``): two 160x120 cameras (position, segmentation)
  -> ``camera_points_base`` -> ``policy_cloud`` (1,792);
- ``composed`` (``obs_mode="composed_pointcloud"``): no render a frame; the scene and target
  points of the render at the episode's start, the target and the robot's link points placed by
  their poses (1,792). The start's render (two 320x240 cameras, ``camera_points_base``,
  ``policy_cloud``) is timed apart, once per episode, and counted per frame over the episode's
  frames at ``--frame-stride`` (the converter's).

Also times the state-only replay step (the physics every converted step still costs, for the
``pd_joint_delta_pos`` actions) and the writing of a training file. Prints frames a second and
the split in ms a frame.

    PYTHONPATH=. python scripts/bench/bench_policy_obs.py [--frames 40] [--threads 1] [--frame-stride 3] \
        [--json results/training/bench-policy-obs-cpu2.json]
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

SAMPLE = Path("assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5")
MODES = {"compact": "compact_pointcloud", "policy": "policy_pointcloud", "composed": "composed_pointcloud"}


class Timers:
    """Seconds spent in named functions (patched in place while active), per part."""

    def __init__(self):
        self.seconds = defaultdict(float)
        self._patches = []

    def wrap(self, owner, attr: str, part: str) -> None:
        original = getattr(owner, attr)

        def timed(*args, **kwargs):
            t = time.perf_counter()
            try:
                return original(*args, **kwargs)
            finally:
                self.seconds[part] += time.perf_counter() - t

        setattr(owner, attr, timed)
        self._patches.append((owner, attr, original))

    @contextlib.contextmanager
    def part(self, name: str):
        t = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - t

    def restore(self) -> None:
        for owner, attr, original in reversed(self._patches):
            setattr(owner, attr, original)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--traj-path", type=Path, default=SAMPLE)
    p.add_argument("--episode", type=int, default=0)
    p.add_argument("--frames", type=int, default=40, help="frames rendered per mode (every step from the first)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (a converter's worker runs 1)")
    p.add_argument("--frame-stride", type=int, default=3,
                   help="the conversion's frame stride: composed's start render is shared by the episode's frames "
                        "at this stride")
    p.add_argument("--starts", type=int, default=5, help="episode starts timed for composed's start render")
    p.add_argument("--json", type=Path, default=None, help="also write the figures here")
    p.add_argument("--repeat", type=int, default=1,
                   help="render the frames this many times over (a long timed loop: copies run at once overlap)")
    p.add_argument("--modes", default=",".join(MODES),
                   help=f"comma-separated, of {', '.join(MODES)} (many copies of one mode at once: a machine's "
                        "throughput in that mode)")
    args = p.parse_args()
    modes = [m for m in args.modes.split(",") if m]
    if not modes or set(modes) - set(MODES):
        p.error(f"--modes {args.modes!r}: comma-separated, of {', '.join(MODES)}")
    if min(args.frames, args.frame_stride, args.starts, args.repeat) < 1:
        p.error("--frames, --frame-stride, --starts and --repeat must be >= 1")
    import gymnasium as gym
    import h5py
    import torch
    from mani_skill.envs import sapien_env
    from mani_skill.envs.scene import ManiSkillScene
    from mani_skill.sensors.camera import Camera
    from mani_skill.trajectory.utils import index_dict

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.envs import composed, pointcloud
    from fetchbench_ms.policies import data

    torch.set_num_threads(args.threads)
    meta = json.loads(args.traj_path.with_suffix(".json").read_text())
    episode = meta["episodes"][args.episode]
    with h5py.File(args.traj_path, "r") as f:
        traj = f[f"traj_{episode['episode_id']}"]
        states = index_dict(traj["env_states"], slice(None))
        actions = traj["actions"][:]
    frames = min(args.frames, len(actions))
    env_id = meta["env_info"]["env_id"]
    common = dict(task_suite=meta["env_info"]["env_kwargs"].get("task_suite", "train"), control_mode="pd_joint_pos")

    timers = {name: Timers() for name in modes}
    envs = {}
    for name in modes:
        obs_mode = MODES[name]
        envs[name] = gym.make(env_id, obs_mode=obs_mode, **common)
        envs[name].reset(**episode["reset_kwargs"])
    seed = int(episode["episode_seed"])

    def render(name: str, t: int):
        env, tm = envs[name].unwrapped, timers[name]
        state = index_dict(states, slice(t, t + 1))
        with tm.part("state set"):
            env.set_state_dict(state)
        env._elapsed_steps[:] = t
        with tm.part("total"):
            obs = env.get_obs()
            if name == "compact":
                xyz, seg = obs["pointcloud"]["xyz"], obs["pointcloud"]["seg"]
                with tm.part("sampling (subsample_compact)"):
                    data.subsample_compact(xyz.numpy(), seg.numpy())
        return obs

    # Each mode's own parts, patched on the classes and modules its get_obs calls.
    def patch(tm: Timers, name: str) -> None:
        tm.wrap(ManiSkillScene, "update_render", "render: update_render")
        tm.wrap(Camera, "capture", "render: take_picture")
        tm.wrap(Camera, "get_obs", "render: get_picture (read back)")
        if name == "compact":
            tm.wrap(sapien_env, "sensor_data_to_pointcloud", "points: sensor_data_to_pointcloud")
            tm.wrap(pointcloud, "add_fetch_pointcloud", "points: add_fetch_pointcloud")
            tm.wrap(pointcloud, "compact_pointcloud_obs", "compaction (compact_pointcloud_obs)")
        elif name == "policy":
            tm.wrap(pointcloud, "camera_points_base", "points: camera_points_base")
            tm.wrap(pointcloud, "policy_cloud", "sampling (policy_cloud)")
        else:
            tm.wrap(composed.ComposedCloud, "compose", "points: compose (targets, links)")
            tm.wrap(type(envs[name].unwrapped), "_links_raw_pose", "poses: the links'")

    for name in modes:  # warm-up: first renders compile shaders and fill caches
        render(name, 0)
    t_loop = time.perf_counter()
    for t in list(range(frames)) * args.repeat:
        for name in modes:
            patch(timers[name], name)
            try:
                render(name, t)
            finally:
                timers[name].restore()
    rendered = frames * args.repeat
    loop_seconds = time.perf_counter() - t_loop  # (wall time of the timed loop: copies run at once overlap in it)

    # composed's render at an episode's start (the reset's get_obs), as a converter pays it per demo.
    start_timer = Timers()
    start_per_frame = 0.0
    start_timer.wrap(composed.ComposedCloud, "start", "start: points kept (policy_cloud, target frame)")
    start_timer.wrap(pointcloud, "camera_points_base", "start: camera_points_base")
    start_timer.wrap(ManiSkillScene, "update_render", "start: update_render")
    start_timer.wrap(Camera, "capture", "start: take_picture")
    start_timer.wrap(Camera, "get_obs", "start: get_picture (read back)")
    try:
        env = envs["composed"].unwrapped if "composed" in envs else None
        for _ in range(args.starts if env is not None else 0):
            env.obs_modes.composed.stale[:] = True
            with start_timer.part("start"):
                env.get_obs()
    finally:
        start_timer.restore()
    episode_frames = -(-len(actions) // args.frame_stride)  # the demo's kept frames (about: per stage in fact)
    if env is not None:
        start_per_frame = start_timer.seconds["start"] / args.starts / episode_frames

    # The state-only replay's physics: one pd_joint_pos step per converted step (~1 per frame).
    replay = gym.make(env_id, obs_mode="state", render_backend="none", **common)
    replay.reset(**episode["reset_kwargs"])
    t0 = time.perf_counter()
    for t in range(frames):
        replay.step(torch.as_tensor(actions[t:t + 1]))
    physics = (time.perf_counter() - t0) / frames

    # Writing: a training file of these frames' size (the policy's points, labels, joints).
    n = sum(pointcloud.POLICY_CLOUD_SIZES.values())
    fake = {"points": np.zeros((frames, n, 3), np.float16), "point_label": np.zeros((frames, n), np.uint8),
            "qpos": np.zeros((frames, 9), np.float32), "tcp": np.zeros((frames, 9), np.float32),
            "action": np.zeros((frames, 7), np.float32), "gripper": np.zeros(frames, np.float32),
            "stage": np.zeros(frames, np.int8), "stage_end": np.zeros(frames, bool),
            "episode_start": np.zeros(1, np.int64), "episode_length": np.array([frames]), "episodes": [{}],
            "sizes": dict(pointcloud.POLICY_CLOUD_SIZES)}
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        data.write_training_file(Path(tmp) / "x.imit.h5", fake)
        writing = (time.perf_counter() - t0) / frames

    print(f"machine: {platform.node()}, {os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.1f}; "
          f"torch threads {args.threads}; render device {envs[modes[0]].unwrapped.backend.render_device}")
    print(f"{frames} frames of {args.traj_path.name} episode {episode['episode_id']} ({episode['task_id']}), "
          "each mode rendered from the recorded env states, in turn")
    per_frame = {}
    for name in modes:
        s = timers[name].seconds
        per_frame[name] = (s["state set"] + s["total"]) / rendered + (start_per_frame if name == "composed" else 0.0)
        print(f"\n{name} ({MODES[name]}): {1 / per_frame[name]:.1f} frames/s, {per_frame[name] * 1e3:.1f} ms a frame")
        accounted = 0.0
        for part, sec in sorted(s.items()):
            if part == "total":
                continue
            if part != "state set":
                accounted += sec
            print(f"  {part:40s} {sec / rendered * 1e3:8.2f} ms")
        print(f"  {'the rest of get_obs (extras, params)':40s} {(s['total'] - accounted) / rendered * 1e3:8.2f} ms")
        if name == "composed":
            print(f"  {'the start render, per frame':40s} {start_per_frame * 1e3:8.2f} ms "
                  f"({start_timer.seconds['start'] / args.starts * 1e3:.0f} ms an episode over its {episode_frames} "
                  f"frames at stride {args.frame_stride}):")
            for part, sec in sorted(start_timer.seconds.items()):
                if part != "start":
                    print(f"    {part:38s} {sec / args.starts * 1e3:8.2f} ms an episode")
    print(f"\nstate-only replay step (physics, pd_joint_pos): {physics * 1e3:.2f} ms a converted step")
    print(f"writing a training file: {writing * 1e3:.3f} ms a frame")
    print()
    for name in [m for m in ("policy", "composed") if m in modes and "compact" in modes]:
        speed = per_frame["compact"] / per_frame[name]
        replay_s = args.frame_stride * physics  # the converted steps a kept frame stands for
        with_replay = (per_frame["compact"] + replay_s) / (per_frame[name] + replay_s)
        print(f"{name} vs compact: {speed:.1f}x the frames a second ({with_replay:.1f}x with the "
              f"{args.frame_stride} state-only replay steps of a frame)")
    if args.json:
        from fetchbench_ms.utils.io import atomic_write_text

        record = {"machine": platform.node(), "cpu_cores": os.cpu_count(), "threads": args.threads,
                  "render_device": str(envs[modes[0]].unwrapped.backend.render_device), "frames": frames,
                  "frame_stride": args.frame_stride, "source": str(args.traj_path), "episode": episode["episode_id"],
                  "ms_a_frame": {MODES[n]: per_frame[n] * 1e3 for n in modes},
                  "frames_a_second": {MODES[n]: 1 / per_frame[n] for n in modes},
                  "composed_start_ms_an_episode": start_timer.seconds.get("start", 0.0) / args.starts * 1e3,
                  "replay_step_ms": physics * 1e3, "write_ms_a_frame": writing * 1e3, "repeat": args.repeat,
                  "loop_seconds": loop_seconds, "loop_start_unix": time.time() - (time.perf_counter() - t_loop)}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.json, json.dumps(record, indent=1) + "\n")
    for env in [*envs.values(), replay]:
        env.close()


if __name__ == "__main__":
    main()
