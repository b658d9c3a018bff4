"""ManiSkill's trajectory replay tool for FetchBench demos.

    python -m fetchbench_ms.replay_trajectory --traj-path demos/trajectory.h5 \\
        -o pointcloud -c pd_joint_delta_pos --save-traj

Takes every flag of ``python -m mani_skill.trajectory.replay_trajectory`` (run with
``--help``) and runs that tool. ManiSkill's tool also runs as is on FetchBench demos: their
JSON names the env ``fetchbench_ms:FetchBench-v0``, which Gymnasium resolves by importing the
plugin (``demos.env_info``). This module imports the plugin itself, so files naming the plain
id ``FetchBench-v0`` replay too; worker processes (``--num-envs N`` on CPU) are spawned and
re-import it. What it adds to ManiSkill's tool (docs/demos.md, "Conversion"): bad input as one
line and exit 2, a recorder that drops failed replays' steps, unstepped source envs for
joint-space conversions, a renderer for demos recorded without one, and converted files that
name the plugin's id.

Converting ``pd_joint_pos`` demos to a joint-space controller (``-c pd_joint_delta_pos``,
``pd_joint_target_delta_pos``, ``pd_joint_vel``), ManiSkill's tool steps a second env with the
source actions beside the one it records, and reads nothing of it but its controller's action
layout. Here it is not stepped (``_SourceControllerOnly``): the converted file is the same to
the bit (``tests/test_envs_replay.py``), and a state-only conversion runs 1.51x as many steps
a second (``scripts/bench/bench_replay_conversion.py``). End-effector targets (``pd_ee_*``) read the stepped source
env's joint targets, so they run as ManiSkill wrote them.

A demo recorded without a renderer (``render_backend="none"`` in its env kwargs, e.g.
state-only data collection) is replayed with ManiSkill's default renderer when the replay
needs one (a camera obs mode, ``--save-video``, ``--vis``); a note says so. A replay that
renders nothing (``-o state`` without videos) runs without a renderer.

A raw point-cloud conversion (``-o pointcloud --save-traj``) writes every camera pixel of
every step (~5 MB a step at 320x240): the wrapper prints the size it will write before it
starts and refuses (exit 2) when that exceeds the free disk of the output folder, unless
``--allow-exceeding-disk``; ``-o compact_pointcloud`` (~139 KB a step) or the imitation
converter's points modes are what to store.
"""
from __future__ import annotations

import contextlib
import json
import multiprocessing as mp
import os
import shutil
import sys

import fetchbench_ms  # noqa: F401  (registers FetchBench-*-v0)
from fetchbench_ms.demos.env_info import replayable_env_info
from fetchbench_ms.demos.stats import check_trajectory_file
from fetchbench_ms.envs.fetchbench import check_obs_mode, obs_mode_needs_renderer
from mani_skill.trajectory import replay_trajectory as _maniskill_replay
from mani_skill.utils.wrappers.record import RecordEpisode


def _needs_renderer(args, env_kwargs: dict) -> bool:
    obs_mode = args.obs_mode if args.obs_mode is not None else env_kwargs.get("obs_mode")
    return obs_mode_needs_renderer(obs_mode) or bool(args.save_video) or bool(args.vis)


def _replay_env_kwargs(args, env_kwargs: dict) -> dict | None:
    """The recorded env kwargs to replay with, or None to keep them as recorded."""
    if not _needs_renderer(args, env_kwargs):
        # Nothing is rendered: no renderer either (its start costs seconds a process on a GPU
        # node, and a state-only conversion runs in many processes); the written env_info
        # leaves the backend out (replayable_env_info), as the source's did.
        return None if env_kwargs.get("render_backend") == "none" else {**env_kwargs, "render_backend": "none"}
    if env_kwargs.get("render_backend", "gpu") not in (None, "none"):
        return None
    kwargs = {k: v for k, v in env_kwargs.items() if k != "render_backend"}  # ManiSkill's default renderer
    what = f"obs mode {args.obs_mode or env_kwargs.get('obs_mode')!r}"
    what += " and videos" if args.save_video or args.vis else ""
    print(f"note: the demo was recorded with render_backend={env_kwargs['render_backend']!r}; "
          f"replaying with ManiSkill's default renderer, which {what} need(s)")
    return kwargs


class _JsonOverride:
    """Stands in for ``mani_skill.utils.io_utils`` inside the replay module while it reads
    the demo's JSON, giving it other env kwargs. ManiSkill's ``main`` reads the env kwargs
    from that file itself and offers no flag for the render backend; rewriting the
    user's file (or a copy next to it, whose name would change the output names) is worse."""

    def __init__(self, io_utils, json_path: str, env_kwargs: dict):
        self._io_utils, self._json_path, self._env_kwargs = io_utils, os.path.abspath(json_path), env_kwargs

    def load_json(self, path, *args, **kwargs):
        data = self._io_utils.load_json(path, *args, **kwargs)
        if os.path.abspath(str(path)) == self._json_path:
            data = {**data, "env_info": {**data["env_info"], "env_kwargs": dict(self._env_kwargs)}}
        return data

    def __getattr__(self, name):
        return getattr(self._io_utils, name)


class RecordEpisodeWithoutFailedReplays(RecordEpisode):
    """ManiSkill's recorder as its replay tool uses it, less a failed replay's steps.

    The replay tool records with ``save_on_reset=False`` and flushes a trajectory only when
    its replay succeeded. A failed replay's steps stay in the recorder's buffer, and when the
    next episode does not rebuild the scene (another demo of the same task) they are saved at
    the front of the next successful trajectory: measured on the dataset's first 128 demos,
    3 failed replays turned 2 saved trajectories into 558 and 629 steps for sources of 210
    and 204. Dropping the unflushed steps at every reset keeps each saved trajectory its own
    episode; a successful replay is flushed before the next reset, so it is untouched.

    The converted file's ``env_info`` is written as ``fetchbench demos run`` writes it
    (``demos.env_info.replayable_env_info``: the id ``fetchbench_ms:FetchBench-v0``), so
    ManiSkill's own tool replays it too."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.save_trajectory:
            self._json_data["env_info"] = replayable_env_info(self._json_data["env_info"])

    def reset(self, *args, **kwargs):
        if not self.save_on_reset and self.save_trajectory and self._trajectory_buffer is not None:
            self.flush_trajectory(save=False)  # nothing to drop: ManiSkill skips it
        return super().reset(*args, **kwargs)


class _WrappersOverride:
    """Stands in for ``mani_skill.utils.wrappers`` inside the replay module, giving it
    ``RecordEpisodeWithoutFailedReplays`` as ``RecordEpisode`` (the module builds its
    recorder as ``wrappers.RecordEpisode(...)``)."""

    RecordEpisode = RecordEpisodeWithoutFailedReplays

    def __init__(self, wrappers):
        self._wrappers = wrappers

    def __getattr__(self, name):
        return getattr(self._wrappers, name)


class _SourceControllerOnly:
    """The source env of a ``pd_joint_pos`` -> joint-space conversion, unstepped.

    ``action_conversion.from_pd_joint_pos`` steps the source env every step but, for a
    joint-space target, reads only its controller (``to_action_dict``: how an action vector
    splits into arm and gripper), which the steps never change. ManiSkill gives no switch for
    this, hence the stand-in: ``step`` does nothing and everything else is the real env's."""

    def __init__(self, env):
        self._env = env

    def step(self, action):
        return None

    def __getattr__(self, name):
        return getattr(self._env, name)


class _ActionConversionOverride:
    """Stands in for ``mani_skill.trajectory.utils.actions.conversion`` inside the replay
    module: ``from_pd_joint_pos`` to a joint-space target gets the unstepped source env."""

    def __init__(self, conversion):
        self._conversion = conversion

    def from_pd_joint_pos(self, output_mode, ori_actions, ori_env, env, **kwargs):
        if "ee" not in output_mode:  # the ee conversion reads the stepped source's joint targets
            ori_env = _SourceControllerOnly(ori_env)
        return self._conversion.from_pd_joint_pos(output_mode, ori_actions, ori_env, env, **kwargs)

    def __getattr__(self, name):
        return getattr(self._conversion, name)


# At import, not in ``main``: the replay tool's worker processes are spawned and import this
# module again (see the module docstring), and each builds its own recorder.
if _maniskill_replay.wrappers.RecordEpisode.__name__ != RecordEpisodeWithoutFailedReplays.__name__:
    _maniskill_replay.wrappers = _WrappersOverride(_maniskill_replay.wrappers)
if not isinstance(_maniskill_replay.action_conversion, _ActionConversionOverride):
    _maniskill_replay.action_conversion = _ActionConversionOverride(_maniskill_replay.action_conversion)


@contextlib.contextmanager
def stock_action_conversion():
    """Within it, the replay tool converts as ManiSkill ships it (the source env stepped):
    the reference that the unstepped conversion is tested and timed against."""
    override = _maniskill_replay.action_conversion
    _maniskill_replay.action_conversion = override._conversion
    try:
        yield
    finally:
        _maniskill_replay.action_conversion = override


#: Bytes a saved raw ``pointcloud`` step takes per camera pixel (ManiSkill's xyzw float32, colour
#: and segmentation, plus ``xyz_base`` and ``fetch_label``, gzip on the labels): 1.24 GB for the
#: demo sample's first demo (258 steps, two 320x240 cameras) is ~31 bytes a pixel.
RAW_POINTCLOUD_BYTES_PER_PIXEL = 32
ALLOW_EXCEEDING_DISK = "--allow-exceeding-disk"


def raw_pointcloud_bytes(meta: dict, count: int | None) -> tuple[int, int]:
    """(steps, estimated bytes) a ``-o pointcloud --save-traj`` replay of the demos' first ``count``
    episodes (all for None) writes."""
    env_kwargs = meta["env_info"]["env_kwargs"]
    pixels = 2 * int(env_kwargs.get("camera_width") or 320) * int(env_kwargs.get("camera_height") or 240)
    episodes = meta["episodes"][:count] if count is not None else meta["episodes"]
    steps = sum(int(e.get("elapsed_steps", 0)) + 1 for e in episodes)  # (+1: the reset's observation)
    return steps, steps * pixels * RAW_POINTCLOUD_BYTES_PER_PIXEL


def check_raw_size(args, meta: dict, allow: bool) -> str | None:
    """None, or the one-line refusal of a raw point-cloud conversion larger than the free disk;
    prints the estimate of any raw point-cloud conversion that saves its trajectories."""
    if args.obs_mode != "pointcloud" or not args.save_traj:
        return None
    steps, size = raw_pointcloud_bytes(meta, args.count)
    folder = os.path.dirname(os.path.abspath(args.traj_path))
    free = shutil.disk_usage(folder).free
    print(f"note: -o pointcloud --save-traj writes every camera pixel of every step: ~{size / 1e9:.1f} GB for "
          f"{steps:,} steps ({size / max(steps, 1) / 1e6:.1f} MB a step; {free / 1e9:.1f} GB free in {folder}); "
          "-o compact_pointcloud writes ~139 KB a step")
    if size > free and not allow:
        return (f"the raw point clouds would take ~{size / 1e9:.1f} GB, more than the {free / 1e9:.1f} GB free in "
                f"{folder}: convert with -o compact_pointcloud, fewer demos (--count), or add {ALLOW_EXCEEDING_DISK}")
    return None


def main(argv: list[str] | None = None) -> int:
    """ManiSkill's replay tool; bad input (an unknown obs mode, a missing, truncated or
    mismatched trajectory file, raw point clouds larger than the free disk) is one line on
    stderr and exit status 2."""
    argv = list(sys.argv[1:] if argv is None else argv)
    allow_large = ALLOW_EXCEEDING_DISK in argv
    argv = [a for a in argv if a != ALLOW_EXCEEDING_DISK]
    args = _maniskill_replay.parse_args(argv)
    try:
        check_obs_mode(args.obs_mode)  # a typo: the valid choices, before anything is built
        check_trajectory_file(args.traj_path)  # a truncated or half-written file: before any worker starts
    except (ValueError, FileNotFoundError) as error:
        print(f"replay_trajectory: error: {error}", file=sys.stderr)
        return 2
    json_path = args.traj_path.replace(".h5", ".json")  # as ManiSkill's tool finds it
    with open(json_path) as f:
        meta = json.load(f)
    env_kwargs = meta["env_info"]["env_kwargs"]
    refusal = check_raw_size(args, meta, allow_large)
    if refusal is not None:
        print(f"replay_trajectory: error: {refusal}", file=sys.stderr)
        return 2
    override = _replay_env_kwargs(args, env_kwargs)
    if override is None:
        _maniskill_replay.main(args)
        return 0
    io_utils = _maniskill_replay.io_utils
    _maniskill_replay.io_utils = _JsonOverride(io_utils, json_path, override)
    try:
        # Only ``main`` reads the env kwargs (and passes them to its workers as arguments).
        _maniskill_replay.main(args)
    finally:
        _maniskill_replay.io_utils = io_utils
    return 0


if __name__ == "__main__":
    # as ManiSkill's tool does (warp does not survive fork); force: a host that ran that tool
    # in this process (runpy) has set it already
    mp.set_start_method("spawn", force=True)
    sys.exit(main())
