"""Train tasks -> expert demos -> imitation training files, in one resumable command.

    python scripts/imitation/build_imitation_data.py --root ROOT --tasks 0:4000 --procs 64 --device cuda --render-gpus 4 \
        [--obs-mode policy_pointcloud] [--frame-stride 1] [--chunk 128] [--per-task 5] [--demos N] \
        [--labels expert-states]

1. ``fetchbench_ms.demos.generate``: the expert on ``train`` tasks START..END-1 (episode seed i
   = task i of the suite, up to --per-task trajectories each, --procs processes), one part per
   task in ``ROOT/demos/FetchBench-v0/motionplanning/train-START-END.parts/``, merged into
   ``train-START-END.h5``;
2. ``scripts/imitation/convert_demos_for_imitation.py``: those demos to training files in ``ROOT/data``
   (``chunk_NNNNN.imit.h5`` + ``manifest.json``; --procs replay processes and render workers),
   in ``--obs-mode`` (default ``policy_pointcloud``: the policies' points made by the env from
   160x120 cameras, what a policy trained on them reads at deployment); ``--demos N`` converts
   the merged file's first N demos only (its first chunks: the same bytes as those of the whole);
3. prints the throughput: trajectories a core-hour of the expert (from each task's time in its
   worker), converted frames a second, and the projected hours of the paper's 27.5k
   trajectories on --procs cores at these rates; writes the same figures to ``ROOT/build.json``.

Every stage resumes (finished parts and chunks are kept), so the same command goes on after an
interruption; a root that is complete is reported so and left as it is. The same tasks and
settings give the same bytes on any number of processes: each part depends on its task's seed
only, each chunk on its demos only. ``--first-steps N`` keeps each demo's first N steps in the
conversion (tests). Test-suite tasks cannot be asked for: the suite is ``train``.
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import time
from pathlib import Path

PAPER_TRAJECTORIES = 27_500
ENV_ID = "FetchBench-v0"


def parse_tasks(text: str) -> tuple[int, int]:
    try:
        start, end = (int(v) for v in text.split(":"))
    except ValueError:
        raise SystemExit(f"--tasks takes START:END (train task indices, END exclusive), got {text!r}") from None
    if not 0 <= start < end:
        raise SystemExit(f"--tasks START:END needs 0 <= START < END, got {text!r}")
    return start, end


def _converter():
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    try:
        return importlib.import_module("convert_demos_for_imitation")
    finally:
        sys.path.pop(0)


def _manifest_totals(path: Path) -> dict:
    if not path.is_file():
        return {"frames": 0, "demos": 0, "complete": False}
    manifest = json.loads(path.read_text())
    return {**manifest["totals"], "complete": bool(manifest["complete"])}


def converter_args(args, merged: Path, data: Path) -> list[str]:
    """``scripts/imitation/convert_demos_for_imitation.py``'s arguments for the merged demos."""
    out = ["--traj-path", str(merged), "--out", str(data), "--chunk", str(args.chunk), "--num-envs", str(args.procs),
           "--device", args.device, "--obs-mode", args.obs_mode, "--frame-stride", str(args.frame_stride),
           "--render-gpus", str(args.render_gpus), "--labels", args.labels]
    if args.demos is not None:
        out += ["--count", str(args.demos)]
    if args.first_steps is not None:
        out += ["--first-steps", str(args.first_steps)]
    return out


def main(argv=None) -> int:
    from fetchbench_ms.envs.pointcloud import COMPACT_OBS_MODE, POINTS_OBS_MODES, POLICY_OBS_MODE

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--root", required=True, help="work folder: ROOT/demos, ROOT/data (re-running resumes)")
    p.add_argument("--tasks", required=True, help="START:END, train task indices (END exclusive)")
    p.add_argument("--procs", type=int, default=os.cpu_count(), help="expert processes, replay processes, render workers")
    p.add_argument("--per-task", type=int, default=5, help="successful trajectories per task at most")
    p.add_argument("--expert", default="fast", choices=("fast", "fast2", "fast3", "reference"),
                   help="the expert's configuration (solutions.expert.EXPERTS)")
    p.add_argument("--obs-mode", default=POLICY_OBS_MODE, choices=(*POINTS_OBS_MODES, COMPACT_OBS_MODE))
    p.add_argument("--frame-stride", type=int, default=1, help="keep every K-th step of each stage (the converter's)")
    p.add_argument("--chunk", type=int, default=128, help="demos per training file")
    p.add_argument("--labels", default="replay", choices=("replay", "expert-states"),
                   help="the converter's --labels: the replay tool's converted states, or (points obs modes) the "
                        "demos' own states without a replay")
    p.add_argument("--device", default="cpu", help="the converter's --device (cuda on a GPU machine)")
    p.add_argument("--render-gpus", type=int, default=1, help="the converter's --render-gpus (4 on a 4-GPU machine)")
    p.add_argument("--demos", type=int, default=None,
                   help="convert only the first N demos of the merged file (default: all)")
    p.add_argument("--first-steps", type=int, default=None, help="convert only each demo's first steps (tests)")
    args = p.parse_args(argv)
    start, end = parse_tasks(args.tasks)
    if args.procs < 1 or args.per_task < 1 or args.chunk < 1 or args.frame_stride < 1 or \
            (args.demos is not None and args.demos < 1):
        raise SystemExit("--procs, --per-task, --chunk, --frame-stride and --demos must be >= 1")
    from fetchbench_ms.demos.generate import (TIMING_FILE, DemoJob, done_parts, generate, parts_dir,
                                              suite_task_ids)

    n_suite = len(suite_task_ids(ENV_ID, "train"))
    if end > n_suite:
        raise SystemExit(f"--tasks {args.tasks}: the train suite has {n_suite} tasks (valid END <= {n_suite})")
    root = Path(args.root)
    name = f"train-{start}-{end}"
    job = DemoJob(env_id=ENV_ID, task_suite="train", per_task=args.per_task, expert=args.expert)

    # 1. demos (resumes from finished parts; merging is redone, its bytes the same)
    parts = parts_dir(root / "demos", ENV_ID, name)
    tasks_before = len(set(done_parts(parts)) & set(range(start, end)))
    t0 = time.perf_counter()
    merged = generate(job, root / "demos", name, end - start, only_count_success=False, num_procs=args.procs,
                      start_seed=start, progress=False)
    t_generate = time.perf_counter() - t0
    meta = json.loads(merged.with_suffix(".json").read_text())
    trajectories = len(meta["episodes"])
    timing_file = parts / TIMING_FILE
    timing = [json.loads(line) for line in timing_file.read_text().splitlines() if line.strip()] \
        if timing_file.is_file() else []
    timed = {t["seed"]: t for t in timing if start <= t["seed"] < end}  # (a resumed task's last timing)
    core_hours = sum(t["wall_time"] for t in timed.values()) / 3600
    timed_trajectories = sum(t["successes"] for t in timed.values())
    print(f"demos: {end - start} train tasks -> {trajectories} trajectories in {merged} "
          f"({t_generate:.0f} s this run on {args.procs} processes)", flush=True)
    if trajectories == 0:
        print("no task gave a trajectory: nothing to convert", file=sys.stderr)
        return 1

    # 2. training files (resumes from finished chunks)
    manifest = root / "data" / "manifest.json"
    before = _manifest_totals(manifest)
    convert_args = converter_args(args, merged, root / "data")
    t0 = time.perf_counter()
    code = _converter().main(convert_args)
    t_convert = time.perf_counter() - t0
    after = _manifest_totals(manifest)
    if code != 0 or not after["complete"]:
        print(f"the conversion stopped before its end (exit {code}): run the same command again", file=sys.stderr)
        return code or 1
    new_frames = after["frames"] - before["frames"]

    # 3. throughput
    print(f"training files: {after['demos']} demos, {after['frames']} frames in {root / 'data'}")
    tasks_with_one = sum(1 for t in timed.values() if t["successes"] > 0)
    summary = {"tasks": [start, end], "per_task": args.per_task, "expert": args.expert, "procs": args.procs,
               "trajectories": trajectories,
               "tasks_timed": len(timed), "tasks_with_a_trajectory": tasks_with_one,
               "yield": round(tasks_with_one / len(timed), 4) if timed else None,
               "expert_core_hours": round(core_hours, 4),
               "trajectories_per_core_hour": round(timed_trajectories / core_hours, 1) if core_hours > 0 else None,
               "demos": after["demos"], "frames": after["frames"], "obs_mode": args.obs_mode,
               "frame_stride": args.frame_stride, "labels": args.labels,
               "conversion_frames_per_second": round(new_frames / t_convert, 1) if new_frames else None}
    from fetchbench_ms.utils.io import atomic_write_text

    atomic_write_text(root / "build.json", json.dumps(summary, indent=1) + "\n")
    if before["complete"] and tasks_before == end - start:
        print("nothing left to do: the demos and training files were already complete")
    if timed_trajectories and core_hours > 0:
        rate = timed_trajectories / core_hours
        print(f"expert: {rate:.1f} trajectories a core-hour ({timed_trajectories} trajectories in "
              f"{core_hours:.2f} core-hours of its workers); the paper's {PAPER_TRAJECTORIES:,} on {args.procs} "
              f"cores: {PAPER_TRAJECTORIES / rate / args.procs:.2f} h")
    if new_frames:
        fps = new_frames / t_convert
        frames_per_trajectory = after["frames"] / max(after["demos"], 1)
        print(f"conversion: {fps:.1f} frames a second ({new_frames} frames in {t_convert:.0f} s on {args.procs} "
              f"processes, device {args.device}); the paper's {PAPER_TRAJECTORIES:,} trajectories "
              f"(~{frames_per_trajectory:.0f} frames each) at this rate: "
              f"{PAPER_TRAJECTORIES * frames_per_trajectory / fps / 3600:.2f} h")
    return 0


if __name__ == "__main__":
    sys.exit(main())
