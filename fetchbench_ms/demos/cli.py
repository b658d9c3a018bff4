"""`fetchbench demos run|merge|stats|show`: the Fetch dataset's generator and tools.

``fetchbench demos run`` takes the flags of ManiSkill's motion-planning generator
(``python -m mani_skill.examples.motionplanning.panda.run``), plus ``--task-suite``,
``--per-task`` and ``--backend``; ``python -m fetchbench_ms.demos.run`` is the same command.
"""
from __future__ import annotations

import argparse


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    from ..envs import ENV_IDS
    from .generate import DEFAULT_MAX_TRIES, DEFAULT_PER_TASK

    p.add_argument("-e", "--env-id", default="FetchBench-v0", help=f"one of {', '.join(ENV_IDS)}")
    p.add_argument("-o", "--obs-mode", default="none",
                   help="observation mode recorded (default none: env states and actions only; "
                        "observations are rendered when the replay tool converts the demos)")
    p.add_argument("-n", "--num-traj", type=int, default=10,
                   help="trajectories to make (with --only-count-success: successful ones; else tasks to try)")
    p.add_argument("--only-count-success", action="store_true",
                   help="count successful trajectories toward -n (failed tries are never saved)")
    p.add_argument("--record-dir", default="demos", help="where the trajectories go (default demos)")
    p.add_argument("--traj-name", default="trajectory", help="name of the .h5/.json (default trajectory)")
    p.add_argument("--num-procs", type=int, default=1, help="worker processes (default 1)")
    p.add_argument("--backend", default="local", choices=("local", "ray"),
                   help="local processes, or a Ray pool (ray.init from RAY_ADDRESS, else a local cluster)")
    p.add_argument("--save-video", action="store_true", help="an mp4 of each saved trajectory")
    p.add_argument("--task-suite", default="train", help="task suite to draw tasks from (default train; the test suite is refused)")
    p.add_argument("--per-task", type=int, default=DEFAULT_PER_TASK,
                   help=f"successful trajectories per task at most, from distinct grasps (default {DEFAULT_PER_TASK})")
    p.add_argument("--max-tries", type=int, default=DEFAULT_MAX_TRIES,
                   help=f"expert tries per task at most (default {DEFAULT_MAX_TRIES})")
    p.add_argument("--start-seed", type=int, default=0, help="first task (episode seed) of the run (default 0)")
    p.add_argument("--expert", default="fast", choices=("fast", "fast2", "fast3", "reference"),
                   help="the expert's configuration (solutions.expert.EXPERTS; default fast)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args) -> int:
    from ..envs.fetchbench import check_obs_mode
    from .generate import DemoJob, generate

    check_obs_mode(args.obs_mode, "gpu")
    if args.per_task < 1 or args.max_tries < 1:
        raise ValueError(f"--per-task and --max-tries must be positive (got {args.per_task}, {args.max_tries})")
    job = DemoJob(env_id=args.env_id, task_suite=args.task_suite, obs_mode=args.obs_mode, per_task=args.per_task,
                  max_tries=args.max_tries, save_video=args.save_video, expert=args.expert)
    out = generate(job, args.record_dir, args.traj_name, args.num_traj, args.only_count_success, args.num_procs,
                   args.backend, progress=not args.no_progress, start_seed=args.start_seed)
    from .stats import demo_stats, format_stats

    print(f"wrote {out} and {out.with_suffix('.json')}")
    print(format_stats(demo_stats(out)))
    return 0


def _stats(args) -> int:
    from .stats import demo_stats, format_stats, plot_stats, resolve

    path = resolve(args.path)
    stats = demo_stats(path)
    print(format_stats(stats))
    if args.png:
        plot_stats(path, args.png)
        print(f"wrote {args.png}")
    return 0


def _merge(args) -> int:
    from .generate import merge_runs
    from .stats import demo_stats, format_stats

    out = merge_runs(args.paths, args.out)
    print(f"wrote {out} and {out.with_suffix('.json')}")
    print(format_stats(demo_stats(out)))
    return 0


def _show(args) -> int:
    from .stats import render_trajectory, resolve

    out = render_trajectory(resolve(args.path), args.traj, args.out, camera=args.camera)
    print(f"wrote {out}")
    return 0


def add_commands(subparsers) -> None:
    demos = subparsers.add_parser("demos", help="expert demonstrations (the Fetch dataset): make, inspect, render")
    sub = demos.add_subparsers(dest="demos_command", required=True, metavar="ACTION")
    r = sub.add_parser("run", help="make expert trajectories in ManiSkill's format (resumable)")
    add_run_arguments(r)
    r.set_defaults(func=run)
    m = sub.add_parser("merge", help="one dataset from runs over consecutive task ranges (--start-seed)")
    m.add_argument("paths", nargs="+", help="the runs' merged .h5 files (any order; back to back in tasks)")
    m.add_argument("-o", "--out", required=True, help="the dataset's .h5 (its .json beside it)")
    m.set_defaults(func=_merge)
    s = sub.add_parser("stats", help="trajectories, frames, by category and scene type; histograms as a PNG")
    s.add_argument("path", help="a trajectory .h5 (or .json), or a folder holding one")
    s.add_argument("--png", default=None, help="write length and C-space-length histograms here")
    s.set_defaults(func=_stats)
    v = sub.add_parser("show", help="render one trajectory to a video (replays its env states)")
    v.add_argument("path", help="a trajectory .h5 (or .json), or a folder holding one")
    v.add_argument("--traj", type=int, default=0, help="episode id (default 0)")
    v.add_argument("--out", required=True, help="video file (.mp4 or .gif)")
    v.add_argument("--camera", default="render_camera", help="camera (default the env's overview render_camera)")
    v.set_defaults(func=_show)
