"""ManiSkill's trajectory replay tool for FetchBench demos.

    python -m fetchbench_ms.replay_trajectory --traj-path demos/trajectory.h5 \\
        -o pointcloud -c pd_joint_delta_pos --save-traj

Takes every flag of ``python -m mani_skill.trajectory.replay_trajectory`` (run with
``--help``). ManiSkill's own entry point imports only ManiSkill's envs, so on a
FetchBench trajectory it fails with ``NameNotFound``; this module imports the plugin
first (registering FetchBench-*-v0) and then runs the same tool. Worker processes
(``--num-envs N`` on CPU) are spawned and re-import this module, so they register the
envs too.
"""
from __future__ import annotations

import multiprocessing as mp

import fetchbench_ms  # noqa: F401  (registers FetchBench-*-v0)
from mani_skill.trajectory import replay_trajectory as _maniskill_replay


def main(argv: list[str] | None = None) -> None:
    _maniskill_replay.main(_maniskill_replay.parse_args(argv))


if __name__ == "__main__":
    mp.set_start_method("spawn")  # as ManiSkill's tool does (warp does not survive fork)
    main()
