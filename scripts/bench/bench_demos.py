"""Benchmark of the Fetch dataset's generator and of its conversion by ManiSkill's replay tool.

    python scripts/bench/bench_demos.py --suite train --tasks 200 --procs 16 --convert 200 --obs-modes state pointcloud \
        --out build/bench-demos

Runs the expert on the suite's first ``--tasks`` tasks (``fetchbench demos run -n TASKS``
without --only-count-success: every task tried once, up to --per-task trajectories each),
then prints: the fraction of tasks that yield at least one trajectory, trajectories per
task, mean frames per trajectory, throughput (trajectories and frames per hour per core, from
the workers' wall seconds, and trajectories per hour of the workers' own CPU time, which
other load on the machine does not stretch) and the projected wall time of the paper's 27.5k trajectories on 16 cores. With
``--convert N`` it replays the first N trajectories with ManiSkill's replay tool (through
``python -m fetchbench_ms.replay_trajectory``) in each conversion the dataset needs and
prints each one's success rate. Results also go to OUT/bench.json. Resumable: a rerun
reuses the finished tasks (the timing then covers only the new ones). ``--profile PATH`` runs
the tasks in this process under cProfile instead and writes the statistics by cumulative time,
with each try's CPU seconds by outcome (``--tries-only``: those alone, without the profiler).
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

from fetchbench_ms.utils.io import atomic_write_text

PAPER_TRAJECTORIES = 27_500
CONVERSIONS = {  # --conversions name: (label, replay tool flags); each is run in every --obs-modes mode
    "env-states": ("env states", ["--use-env-states"]),
    "pd_joint_pos": ("pd_joint_pos actions", []),
    "pd_joint_delta_pos": ("-c pd_joint_delta_pos", ["-c", "pd_joint_delta_pos"]),
    "pd_ee_delta_pose": ("-c pd_ee_delta_pose", ["-c", "pd_ee_delta_pose"]),
}


#: Observation modes whose converted file is not written: raw ``pointcloud`` is ~5 MB a step
#: (docs/envs.md), ~200 GB for 200 trajectories, more than a machine's disk. They are replayed
#: without ``--save-traj``: the same replay, every step's observation rendered, success counted;
#: ``compact_pointcloud`` (what the imitation converter writes) is the one saved with clouds.
UNSAVED_OBS_MODES = ("pointcloud", "rgbd", "rgb", "depth")


def replay(path: Path, flags: list[str], count: int, procs: int, save: bool = True) -> tuple[int, int, float]:
    """(successes, replayed, seconds) of one conversion."""
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "fetchbench_ms.replay_trajectory", "--traj-path", str(path),
                          *(["--save-traj"] if save else []), "--count", str(count), "--num-envs", str(procs), *flags],
                         capture_output=True, text=True)
    text = (out.stdout + out.stderr).replace("\r", "\n")
    m = re.findall(r"Replayed (\d+) episodes, (\d+)/\d+=", text)
    if out.returncode != 0 or not m:
        raise RuntimeError(f"replay {flags} failed:\n{text[-3000:]}")
    return int(m[-1][1]), int(m[-1][0]), time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env-id", default="FetchBench-v0")
    ap.add_argument("--suite", default="train")
    ap.add_argument("--tasks", type=int, default=20)
    ap.add_argument("--start", type=int, default=0, help="first task (episode seed): tasks START .. START+TASKS-1")
    ap.add_argument("--procs", type=int, default=2)
    ap.add_argument("--per-task", type=int, default=5)
    ap.add_argument("--expert", default="fast", help="the expert's configuration (solutions.expert.EXPERTS)")
    ap.add_argument("--record", default=None, metavar="JSON",
                    help="also write the figures here (e.g. results/demos/bench-expert-fast.json)")
    ap.add_argument("--convert", type=int, default=0, help="replay this many trajectories in each conversion")
    ap.add_argument("--obs-modes", nargs="+", default=["state"], metavar="OBS_MODE",
                    help="observation modes each conversion is run in (e.g. state pointcloud)")
    ap.add_argument("--traj-name", default=None,
                    help="name of the demo file (default SUITE-TASKS-EXPERT); a run with more --tasks and the same "
                         "name continues the finished tasks")
    ap.add_argument("--conversions", nargs="+", default=list(CONVERSIONS), choices=list(CONVERSIONS),
                    metavar="NAME", help=f"which conversions to run (default all: {' '.join(CONVERSIONS)})")
    ap.add_argument("--convert-only", action="store_true",
                    help="convert the existing TRAJ-NAME file without running the expert")
    ap.add_argument("--out", default="build/bench-demos")
    ap.add_argument("--profile", default=None, metavar="PATH",
                    help="instead: run the tasks in this process under cProfile and write its statistics, sorted "
                         "by cumulative time, to PATH (text; the parts go to a fresh OUT/profile-* folder)")
    ap.add_argument("--tries-only", action="store_true",
                    help="with --profile: only the header (each try's CPU seconds by outcome), without cProfile")
    args = ap.parse_args(argv)
    if args.profile:
        return profile(args, argv)

    from fetchbench_ms.demos.generate import TIMING_FILE, done_parts, parts_dir
    from fetchbench_ms.demos.stats import demo_stats, format_stats

    name = args.traj_name or (f"{args.suite}-{args.tasks}-{args.expert}" if not args.start
                              else f"{args.suite}{args.start}-{args.tasks}-{args.expert}-pt{args.per_task}")
    parts = parts_dir(args.out, args.env_id, name)
    path = parts.parent / f"{name}.h5"
    result_path = Path(args.out) / f"bench-{name}{'-convert' if args.convert_only else ''}.json"
    if args.convert_only:
        # only the conversions, on a finished file (another run may still be adding to its parts)
        result = {"traj_path": str(path)}
        convert(path, args, result, result_path)
        return 0
    before = set(done_parts(parts))
    t0 = time.perf_counter()
    cmd = [sys.executable, "-m", "fetchbench_ms", "demos", "run", "-e", args.env_id, "--task-suite", args.suite,
           "-n", str(args.tasks), "--record-dir", args.out, "--traj-name", name, "--num-procs", str(args.procs),
           "--per-task", str(args.per_task), "--expert", args.expert, "--no-progress"]
    if args.start:
        cmd += ["--start-seed", str(args.start)]
    subprocess.run(cmd, check=True)
    wall = time.perf_counter() - t0
    done = done_parts(parts)
    timing = {}
    if (parts / TIMING_FILE).exists():
        for line in (parts / TIMING_FILE).read_text().splitlines():
            if line.strip():
                record = json.loads(line)
                timing[record["seed"]] = record
    new = [timing[seed] for seed in done if seed not in before and seed in timing]
    stats = demo_stats(path)
    tried = [done[s] for s in sorted(done) if args.start <= s < args.start + args.tasks]
    trajectories = sum(s["successes"] for s in tried)
    frames = sum(s["frames"] for s in tried)
    result = {
        "command": "python scripts/bench/bench_demos.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "suite": args.suite, "env_id": args.env_id, "start": args.start, "tasks": len(tried), "procs": args.procs,
        "per_task": args.per_task, "expert": args.expert,
        "tasks_with_demo": round(sum(s["successes"] > 0 for s in tried) / max(1, len(tried)), 4),
        "trajectories": trajectories, "frames": frames,
        "trajectories_per_task": round(trajectories / max(1, len(tried)), 3),
        "trajectories_per_task_with_demo": round(trajectories / max(1, sum(s["successes"] > 0 for s in tried)), 3),
        "mean_frames": round(frames / max(1, trajectories), 1),
        "mean_cspace_length": stats["mean_cspace_length"],
        "failures": {k: sum(s["failures"].get(k, 0) for s in tried) for k in
                     sorted({k for s in tried for k in s["failures"]})},
        # finer (solutions.sense_plan_act.FAILURE_REASONS), and the tasks without a trajectory by
        # their first try's reason
        "failure_reasons": {k: sum(s.get("reasons", {}).get(k, 0) for s in tried) for k in
                            sorted({k for s in tried for k in s.get("reasons", {})})},
        "tasks_without_demo_by_reason": tasks_without_demo_by_reason(tried),
    }
    if new:
        busy = sum(s["wall_time"] for s in new)  # worker-seconds of the tasks made in this run
        per_core_hour = sum(s["successes"] for s in new) / busy * 3600
        result.update(worker_seconds=round(busy, 1), wall_seconds=round(wall, 1),
                      trajectories_per_core_hour=round(per_core_hour, 1),
                      frames_per_core_hour=round(sum(s["frames"] for s in new) / busy * 3600),
                      projected_hours_27_5k_on_16_cores=round(PAPER_TRAJECTORIES / (per_core_hour * 16), 2))
        if all("cpu_time" in s for s in new):
            # The workers' own CPU seconds: what a core-hour buys on an idle machine, read on a busy one.
            cpu = sum(s["cpu_time"] for s in new)
            result.update(worker_cpu_seconds=round(cpu, 1), cpu_seconds_per_trajectory=round(
                cpu / max(1, sum(s["successes"] for s in new)), 2),
                trajectories_per_cpu_hour=round(sum(s["successes"] for s in new) / cpu * 3600, 1))
    print(format_stats(stats))
    write_result(result, result_path)
    if args.record:
        write_result(result, Path(args.record))
    convert(path, args, result, result_path)
    return 0


def profile(args, argv) -> int:
    """The tasks run one after another in this process (``generate.run_task``, what a worker
    runs) under cProfile; PATH gets a header (the command, tries, trajectories, CPU seconds)
    and the statistics sorted by cumulative time."""
    import cProfile
    import io
    import pstats
    import shutil

    from fetchbench_ms.demos.generate import DemoJob, run_task, suite_task_ids

    job = DemoJob(env_id=args.env_id, task_suite=args.suite, per_task=args.per_task, expert=args.expert)
    ids = suite_task_ids(job.env_id, job.task_suite)
    parts = Path(args.out) / f"profile-{args.suite}{args.start}-{args.tasks}-{args.expert}"
    shutil.rmtree(parts, ignore_errors=True)
    parts.mkdir(parents=True)
    summaries, tries_cpu = [], []  # (seconds, success, reason, env.step calls) of each try
    import fetchbench_ms.solutions.expert as expert

    solve_demo = expert.solve_demo

    def timed_solve_demo(*a, **kw):
        t = time.process_time()
        demo = solve_demo(*a, **kw)
        tries_cpu.append((time.process_time() - t, demo.success, demo.reason, demo.steps, a[1] if len(a) > 1 else None))
        if args.tries_only:  # as they come, with what each try did
            print(json.dumps({"seed": a[1] if len(a) > 1 else None, "cpu": round(tries_cpu[-1][0], 2),
                              "success": demo.success, "reason": demo.reason, "steps": demo.steps,
                              "checks": demo.checks, "notes": demo.notes}), flush=True)
        return demo

    expert.solve_demo = timed_solve_demo  # run_task imports it at each call
    prof = cProfile.Profile()
    cpu0 = time.process_time()
    if not args.tries_only:
        prof.enable()
    for seed in range(args.start, args.start + args.tasks):
        summaries.append(run_task(job, parts, seed, ids[seed]))
    prof.disable()
    cpu = time.process_time() - cpu0
    out = io.StringIO()
    if not args.tries_only:
        pstats.Stats(prof, stream=out).sort_stats("cumulative").print_stats(120)
    tries = sum(s["tries"] for s in summaries)
    successes = sum(s["successes"] for s in summaries)
    reasons: dict = {}
    for s in summaries:
        for k, v in s["reasons"].items():
            reasons[k] = reasons.get(k, 0) + v
    header = (f"python scripts/bench/bench_demos.py {' '.join(argv if argv is not None else sys.argv[1:])}\n"
              f"tasks {len(summaries)}, tries {tries}, trajectories {successes}, failure reasons "
              f"{dict(sorted(reasons.items()))}\nCPU seconds{'' if args.tries_only else ' (profiled, with the overhead of cProfile)'} {cpu:.1f}; "
              f"per task: " + ", ".join(f"{s['seed']}: {s['successes']}/{s['tries']} {s['cpu_time']}s"
                                        for s in summaries) + "\n\n")
    for label, rows in (("successful", [t for t in tries_cpu if t[1]]), ("failed", [t for t in tries_cpu if not t[1]])):
        header += (f"{label} tries: {len(rows)}, CPU s {sum(t[0] for t in rows):.1f} (mean "
                   f"{sum(t[0] for t in rows) / max(1, len(rows)):.2f}), env steps {sum(t[3] for t in rows)}\n")
    by_reason: dict = {}
    for t in tries_cpu:
        if not t[1]:
            n, c = by_reason.get(t[2], (0, 0.0))
            by_reason[t[2]] = (n + 1, c + t[0])
    header += "failed tries by reason (tries, CPU s): " + ", ".join(
        f"{k}: {n}, {c:.1f}" for k, (n, c) in sorted(by_reason.items())) + "\n"
    header += "tries (seed, CPU s, success, reason, steps): " + "; ".join(
        f"{t[4]} {t[0]:.2f} {int(t[1])} {t[2]} {t[3]}" for t in tries_cpu) + "\n\n"
    Path(args.profile).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(Path(args.profile), header + out.getvalue())
    print(header)
    return 0


def tasks_without_demo_by_reason(summaries: list[dict]) -> dict:
    """Tasks without a trajectory, by the furthest stage of the pipeline any of their tries
    failed at (solutions.sense_plan_act.FAILURE_REASONS, in order, then "not_retrieved"; a
    planner's status after a colon)."""
    from fetchbench_ms.solutions.sense_plan_act import FAILURE_REASONS

    order = (*FAILURE_REASONS, "not_retrieved")
    out: dict = {}
    for s in summaries:
        if s["successes"] == 0 and s.get("reasons"):
            furthest = max(s["reasons"], key=lambda r: order.index(r.split(":")[0]))
            out[furthest] = out.get(furthest, 0) + 1
    return dict(sorted(out.items()))


def write_result(result: dict, result_path: Path) -> None:
    result_path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(result_path, json.dumps(result, indent=1))
    print(json.dumps(result, indent=1), flush=True)


def convert(path: Path, args, result: dict, result_path: Path) -> None:
    """Each conversion in each obs mode on the first --convert trajectories; the result file is
    rewritten after every one, so a run cut short keeps what it measured."""
    if not args.convert:
        return
    result.setdefault("conversions", {})
    for obs_mode in args.obs_modes:
        for label, flags in (CONVERSIONS[name] for name in args.conversions):
            save = obs_mode not in UNSAVED_OBS_MODES
            ok, n, seconds = replay(path, [*flags, "-o", obs_mode], args.convert, args.procs, save)
            result["conversions"][f"{label}, -o {obs_mode}"] = {
                "success": ok, "replayed": n, "rate": round(ok / max(1, n), 4), "seconds": round(seconds, 1),
                "saved": save}
            write_result(result, result_path)


if __name__ == "__main__":
    raise SystemExit(main())
