"""Convert Fetch-dataset demos into the imitation baselines' compact training files.

Per chunk of trajectories: a chunk source file (the demos' h5 + json subset) -> ManiSkill's
replay tool (``python -m fetchbench_ms.replay_trajectory -c pd_joint_delta_pos -o
compact_pointcloud --save-traj --num-envs N``, in a subprocess) -> the policies' points
farthest-point sampled per segment + joints + TCP + arm action + the source's stage labels
(``fetchbench_ms.policies.data``) -> ``OUT/chunk_NNNNN.imit.h5``; the replay tool's
139 KB-a-frame file is deleted. Resumable: finished chunks are skipped, so the same command
continues after ``--time-limit`` or a kill. ``OUT/manifest.json`` records the source's hash,
the sizes and every chunk's hash and frames (the trainers record its hash). Demos of test
tasks or test-split objects are refused (exit 2) before anything is written; so are another
env's demos, a file the replay tool already converted and demos without stage labels (one
line naming what is valid, exit 1).

``--frame-stride K`` (K > 1) keeps every K-th converted step of each stage, its arm action the
mean over the K steps it stands for (``policies.data.select_frames``), as the original
FetchBench data kept every 6th frame and ``fetchbench eval --policy-stride K`` deploys: the
replay tool then runs state-only (``-o state``, no rendering) and the kept frames alone are
rendered from its recorded env states (``fetchbench_ms.render_env_states``, ``--num-envs``
processes), so the costly rendering is a K-th (docs/imitation.md, "Frame stride").
``--overlap-replay`` (K > 1) starts the next chunk's replay in the background while a chunk
renders (the same files).

    # a 16-core GPU node (16 cores for physics, the GPU renders): 5,000 demos, ~10 minutes a call
    python scripts/imitation/convert_demos_for_imitation.py --traj-path demos/FetchBench-v0/motionplanning/train.h5 \\
        --out data/imit --count 5000 --chunk 128 --num-envs 16 --device cuda --time-limit 540
    # one shard of a run that goes over several (docs/imitation.md): demos 1,536 .. 3,071
    python scripts/imitation/convert_demos_for_imitation.py --traj-path ... --out data/imit-s1 --start 1536 --count 1536 ...
    # a CPU check: the first 12 steps of 2 demos of the shipped sample, small clouds
    python scripts/imitation/convert_demos_for_imitation.py --traj-path assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5 \\
        --out /tmp/imit-sample --count 2 --first-steps 12 --sizes 128,64,32
    # every 3rd frame of each stage, the next chunk's replay beside each chunk's render pass
    python scripts/imitation/convert_demos_for_imitation.py --traj-path ... --out data/imit-k3 --frame-stride 3 --overlap-replay ...
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import h5py

from fetchbench_ms.envs import PLUGIN_MODULE, recorded_env_id
from fetchbench_ms.envs.pointcloud import COMPACT_OBS_MODE, COMPOSED_OBS_MODE, POINTS_OBS_MODES, POLICY_CLOUD_SIZES, POLICY_OBS_MODE
from fetchbench_ms.render_env_states import StateRenderPool, render_backends
from fetchbench_ms.policies.data import (EXPERT_STATE_LABELS, POLICY_SIZES, REPLAY_LABELS, convert_episodes,
                                         expert_state_episodes, write_training_file)
from fetchbench_ms.tasks.splits import cli_guard, refuse_test_env_kwargs, refuse_test_objects, refuse_test_task_ids
from fetchbench_ms.utils.io import atomic_write_text, sha256_file


def parse_sizes(text: str) -> dict:
    try:
        values = [int(v) for v in text.split(",")]
        if len(values) != 3 or min(values) < 1:
            raise ValueError
    except ValueError:
        raise SystemExit(f"--sizes takes SCENE,TARGET,ROBOT point counts (e.g. 1024,512,256), got {text!r}")
    return dict(zip(("scene", "target", "robot"), values))


def write_chunk_source(source_h5: Path, episodes: list[dict], env_info: dict, out_h5: Path,
                       first_steps: int | None) -> None:
    """The demos of ``episodes`` as their own trajectory file (same ids), optionally cut to
    their first steps (a test: the replay then needs --allow-failure)."""
    tmp = out_h5.with_name(out_h5.name + ".tmp")
    with h5py.File(source_h5, "r") as src, h5py.File(tmp, "w") as dst:
        for episode in episodes:
            name = f"traj_{episode['episode_id']}"
            if first_steps is None:
                src.copy(src[name], dst, name=name)
                continue
            group = dst.create_group(name)

            def cut(path, obj, group=group, n=first_steps):
                if isinstance(obj, h5py.Dataset):
                    # env_states (and obs) have one more row than the actions
                    keep = n + 1 if path.startswith(("env_states", "obs")) else n
                    group.create_dataset(path, data=obj[:keep])

            src[name].visititems(cut)
    os.replace(tmp, out_h5)
    if first_steps is not None:
        episodes = [{**e, "elapsed_steps": min(first_steps, e["elapsed_steps"])} for e in episodes]
    atomic_write_text(out_h5.with_suffix(".json"), json.dumps({"env_info": env_info, "episodes": episodes}))


@dataclass
class Replay:
    """One chunk's replay-tool subprocess, in its own process group (so that stopping it stops
    the processes it spawned); its output goes to ``replay.log`` in the chunk's work folder."""
    chunk: int
    work: Path
    process: subprocess.Popen
    converted: Path
    obs_mode: str
    background: bool
    started: float


def start_replay(k: int, work: Path, chunk_h5: Path, num_envs: int, allow_failure: bool, obs_mode: str,
                 background: bool) -> Replay:
    command = [sys.executable, "-m", "fetchbench_ms.replay_trajectory", "--traj-path", str(chunk_h5),
               "-c", "pd_joint_delta_pos", "-o", obs_mode, "--save-traj", "--num-envs", str(num_envs)]
    if allow_failure:
        command.append("--allow-failure")
    # A file, not a pipe: a background replay's output is read by no one until it ends.
    with open(work / "replay.log", "w") as output:
        process = subprocess.Popen(command, stdout=output, stderr=subprocess.STDOUT, start_new_session=True)
    converted = chunk_h5.with_name(f"{chunk_h5.stem}.{obs_mode}.pd_joint_delta_pos.physx_cpu.h5")
    return Replay(k, work, process, converted, obs_mode, background, time.perf_counter())


def finish_replay(replay: Replay, log) -> Path:
    """Wait for ``replay``; its converted file."""
    t = time.perf_counter()
    code = replay.process.wait()
    if code != 0 or not replay.converted.is_file():
        output = (replay.work / "replay.log").read_text(errors="replace")
        raise RuntimeError(f"the replay tool failed on {replay.work / 'demos.h5'} (exit {code}):\n{output[-6000:]}")
    took = f"in {time.perf_counter() - replay.started:.0f} s"
    if replay.background:
        took += f" (in the background; the converter waited {time.perf_counter() - t:.1f} s for it)"
    log(f"  replayed chunk {replay.chunk} (-o {replay.obs_mode}) {took}")
    return replay.converted


def stop_replay(replay: Replay) -> None:
    """Terminate ``replay``'s process group (the replay tool and its workers) and remove its work folder."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(replay.process.pid, sig)
        except ProcessLookupError:
            break  # the group is gone
        try:
            replay.process.wait(timeout=10)
            break
        except subprocess.TimeoutExpired:
            continue
    shutil.rmtree(replay.work, ignore_errors=True)


def chunk_record(path: Path) -> dict:
    with h5py.File(path, "r") as f:
        frames = int(len(f["qpos"])) if "qpos" in f else 0
        demos = len(json.loads(f.attrs["episodes"]))
    return {"file": path.name, "sha256": sha256_file(path), "demos": demos, "frames": frames,
            "bytes": path.stat().st_size}


def refuse_test_demos(meta: dict, purpose: str) -> None:
    """Demos of test tasks or test-split objects never become training data: the generator's
    env (its task suite, its object split), every episode's task and target object."""
    env_kwargs = meta.get("env_info", {}).get("env_kwargs", {})
    episodes = meta.get("episodes", [])
    cli_guard(refuse_test_env_kwargs, env_kwargs, purpose)
    cli_guard(refuse_test_task_ids, [e.get("task_id") or e.get("reset_kwargs", {}).get("options", {}).get("task_id")
                                     for e in episodes], purpose)
    cli_guard(refuse_test_objects, [e.get("target_object") for e in episodes], purpose)


OUR_DEMOS = "valid: the demos `fetchbench demos run` records (FetchBench-*-v0, -c pd_joint_pos, stage labels)"


def refuse_other_demos(source: Path, meta: dict) -> None:
    """Only FetchBench demos as ``fetchbench demos run`` writes them become training data: a
    FetchBench env's, recorded with ``pd_joint_pos`` (the replay converts from it), with the
    expert's stage labels (``refuse_unlabelled_demos``). Another env's demos or a file the
    replay tool already converted (``pd_joint_delta_pos``) end in one line naming what is valid."""
    env_info = meta.get("env_info") if isinstance(meta, dict) else None
    env_id = env_info.get("env_id") if isinstance(env_info, dict) else None
    if not isinstance(env_id, str) or not recorded_env_id(env_id).startswith(f"{PLUGIN_MODULE}:"):
        raise SystemExit(f"{source} holds demos of {env_id or 'no env'!r}, not of a FetchBench env; {OUR_DEMOS}")
    episodes = meta.get("episodes") or []
    modes = {(env_info.get("env_kwargs") or {}).get("control_mode")} | {e.get("control_mode") for e in episodes}
    modes.discard(None)
    if modes and modes != {"pd_joint_pos"}:
        obs_mode = (env_info.get("env_kwargs") or {}).get("obs_mode")
        raise SystemExit(f"{source} is a converted file (control mode {', '.join(sorted(modes))}, obs mode "
                         f"{obs_mode}), not the demos it was made from; {OUR_DEMOS}")


def refuse_unlabelled_demos(source: Path, meta: dict) -> None:
    """The source's first trajectory is in its h5 and carries the expert's stage labels."""
    episodes = meta.get("episodes") or []
    if episodes:
        with h5py.File(source, "r") as f:
            name = f"traj_{episodes[0].get('episode_id')}"
            if name not in f or "stage" not in f[name]:
                raise SystemExit(f"{source}: {name} {'carries no stage labels' if name in f else 'is missing'}; "
                                 f"{OUR_DEMOS}")


def write_manifest(path: Path, settings: dict, records: dict, n_chunks: int) -> dict:
    chunks = [records[name] for name in sorted(records)]
    frames, nbytes = sum(r["frames"] for r in chunks), sum(r["bytes"] for r in chunks)
    totals = {"demos": sum(r["demos"] for r in chunks), "frames": frames, "bytes": nbytes,
              "bytes_per_frame": round(nbytes / max(frames, 1), 1)}
    atomic_write_text(path, json.dumps({"settings": settings, "complete": len(chunks) == n_chunks,
                                        "chunks": chunks, "totals": totals}, indent=1))
    return totals


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--traj-path", required=True, help="the demos' h5 (ManiSkill trajectory format + stage labels)")
    p.add_argument("--out", required=True, help="folder of the training files (re-running resumes)")
    p.add_argument("--count", type=int, default=None, help="N demos from --start (default: all)")
    p.add_argument("--start", type=int, default=0,
                   help="first demo (a multiple of --chunk): one shard of a dataset converted in several "
                        "runs; its chunks keep their numbers in the whole dataset")
    p.add_argument("--chunk", type=int, default=128, help="demos per replay call / training file")
    p.add_argument("--num-envs", type=int, default=1, help="replay processes (one core each)")
    p.add_argument("--sizes", default=",".join(str(v) for v in POLICY_SIZES.values()),
                   help="points kept per segment: SCENE,TARGET,ROBOT")
    p.add_argument("--device", default="cpu", help="farthest-point sampling on this torch device (cuda on a GPU node)")
    p.add_argument("--time-limit", type=float, default=0.0,
                   help="s; > 0: start no chunk that would end after this, judged by the slowest so far (re-run to resume)")
    p.add_argument("--first-steps", type=int, default=None, help="keep only each demo's first steps (tests)")
    p.add_argument("--frame-stride", type=int, default=1,
                   help="K: keep every K-th converted step of each stage, its arm action the mean over its K steps "
                        "(a replay without rendering, then the kept frames rendered from its env states)")
    p.add_argument("--obs-mode", default=COMPACT_OBS_MODE, choices=(COMPACT_OBS_MODE, *POINTS_OBS_MODES),
                   help=f"the env obs mode the frames are made with: {COMPACT_OBS_MODE} (320x240 cameras, the compact "
                        f"cloud, then --sizes; the shipped checkpoints'), {POLICY_OBS_MODE} (160x120 cameras, the "
                        "policies' 1,792 points made by the env itself: what a policy trained on it reads at "
                        f"deployment) or {COMPOSED_OBS_MODE} (the same points composed from one render at the "
                        "episode's start, the target and robot placed by their poses; ~40x cheaper a frame); the "
                        "points modes are always made from the state-only replay's env states")
    p.add_argument("--render-gpus", type=int, default=1,
                   help="render workers spread over GPUs cuda:0 .. N-1 (a machine of several GPUs; the frames are "
                        "the same on GPUs of one model); 1: ManiSkill's default device")
    p.add_argument("--labels", default="replay", choices=("replay", "expert-states"),
                   help="replay: ManiSkill's replay tool converts the actions by stepping the physics (frames at its "
                        "states); expert-states (points obs modes): no replay, the frames are the demos' own recorded "
                        "states and their actions those that set the expert's arm targets there "
                        "(policies.data.expert_state_episodes), rendered by one pool of --num-envs processes kept "
                        "for all chunks")
    p.add_argument("--overlap-replay", action="store_true",
                   help="K > 1: run the next chunk's state-only replay in the background while this chunk's "
                        "kept frames are rendered (the same output)")
    args = p.parse_args(argv)
    if args.frame_stride < 1:
        raise SystemExit(f"--frame-stride takes an integer >= 1 (converted steps per frame kept), "
                         f"got {args.frame_stride}")
    if args.render_gpus < 1:
        raise SystemExit(f"--render-gpus must be >= 1, got {args.render_gpus}")
    backends = render_backends(args.render_gpus)
    policy_obs = args.obs_mode in POINTS_OBS_MODES
    if policy_obs and args.sizes != ",".join(str(v) for v in POLICY_SIZES.values()):
        raise SystemExit(f"--sizes is the compact cloud's subsampling; {args.obs_mode} makes its own "
                         f"{','.join(str(v) for v in POLICY_CLOUD_SIZES.values())} points: leave --sizes out")
    if args.overlap_replay and args.frame_stride == 1 and not policy_obs:
        raise SystemExit("--overlap-replay overlaps a state-only replay with the render pass of --frame-stride K > 1; "
                         "at stride 1 the replay renders and there is no separate render pass to overlap")
    expert_states = args.labels == "expert-states"
    if expert_states and (not policy_obs or args.overlap_replay):
        raise SystemExit(f"--labels expert-states renders the points obs modes ({', '.join(POINTS_OBS_MODES)}) "
                         f"without a replay: give one as --obs-mode (got {args.obs_mode}) and leave --overlap-replay out")
    sizes = parse_sizes(args.sizes)
    source = Path(args.traj_path)
    if not source.is_file() or not source.with_suffix(".json").is_file():
        raise SystemExit(f"no demos at {source} (+ .json); make them with `fetchbench demos run` (docs/demos.md)")
    meta = json.loads(source.with_suffix(".json").read_text())
    refuse_other_demos(source, meta)  # before anything is written
    refuse_test_demos(meta, "demo conversion for imitation")
    refuse_unlabelled_demos(source, meta)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log_file = open(out / "convert.log", "a")

    def log(message: str) -> None:
        print(message, flush=True)
        log_file.write(message + "\n")
        log_file.flush()

    if args.start < 0 or args.start % args.chunk or args.start >= len(meta["episodes"]):
        raise SystemExit(f"--start must be a multiple of --chunk ({args.chunk}) below the {len(meta['episodes'])} "
                         f"demos of {source}, got {args.start}")
    stop = None if args.count is None else args.start + args.count
    episodes = meta["episodes"][args.start:stop]
    source_sha = sha256_file(source)
    settings = {"source": str(source.resolve()), "source_sha256": source_sha, "sizes": sizes,
                "chunk": args.chunk, "start": args.start, "count": len(episodes), "first_steps": args.first_steps}
    # Stride-1 conversions write no stride (their manifest stays as it was): absent means 1.
    if args.frame_stride != 1:
        settings["frame_stride"] = args.frame_stride
    if policy_obs:  # (absent: compact_pointcloud, as every conversion made before the policy obs mode)
        settings["obs_mode"] = args.obs_mode
    if expert_states:  # (absent: the replay's labels)
        settings["labels"] = EXPERT_STATE_LABELS
    manifest_path = out / "manifest.json"
    if manifest_path.is_file():
        absent = {"frame_stride": 1, "obs_mode": COMPACT_OBS_MODE, "labels": REPLAY_LABELS}  # a setting left out
        old = {**absent, **json.loads(manifest_path.read_text())["settings"]}
        differ = {k: (old.get(k), v) for k, v in {**absent, **settings}.items()
                  if old.get(k) != v and k != "source"}
        if differ:
            raise SystemExit(f"{out} holds a conversion with other settings {differ} (old, new): use another --out")
    chunks = [episodes[i:i + args.chunk] for i in range(0, len(episodes), args.chunk)]
    # The manifest is rewritten after every chunk, so trainers reading the folder while the
    # conversion goes on (docs/imitation.md, "Shards") see which chunks are finished.
    records = {path.name: chunk_record(path) for path in sorted(out.glob("chunk_*.imit.h5"))}
    totals = write_manifest(manifest_path, settings, records, len(chunks))
    t_start, longest = time.perf_counter(), 0.0
    log(f"{len(episodes)} demos of {source} in {len(chunks)} chunks of {args.chunk} -> {out}")
    # Stride 1 renders every step in the replay; a larger stride replays without rendering
    # and renders the kept frames from the recorded env states (convert_episodes).
    obs_mode = "compact_pointcloud" if args.frame_stride == 1 and not policy_obs else "state"
    todo = [(k, chunk) for k, chunk in enumerate(chunks, start=args.start // args.chunk)
            if not (out / f"chunk_{k:05d}.imit.h5").is_file()]

    def start_chunk(k: int, chunk: list, background: bool) -> Replay:
        work = out / "work" / f"chunk_{k:05d}"
        shutil.rmtree(work, ignore_errors=True)  # a killed run's leftovers
        work.mkdir(parents=True)
        chunk_h5 = work / "demos.h5"
        write_chunk_source(source, chunk, meta["env_info"], chunk_h5, args.first_steps)
        return start_replay(k, work, chunk_h5, min(args.num_envs, len(chunk)), args.first_steps is not None,
                            obs_mode, background)

    if expert_states:
        totals, records = convert_at_expert_states(args, source, meta, todo, out, manifest_path, settings, records,
                                                   len(chunks), backends, log)
        return finish(out, records, chunks, totals, log)
    running: dict[int, Replay] = {}  # replays started and not waited for, by chunk
    try:
        for i, (k, chunk) in enumerate(todo):
            target = out / f"chunk_{k:05d}.imit.h5"
            # Stop before a chunk that would not finish in time (as long as the slowest so far).
            if args.time_limit and time.perf_counter() - t_start + longest > args.time_limit:
                log(f"time limit: stopped before chunk {k}; run the same command again to resume")
                break
            t_chunk = time.perf_counter()
            replay = running.get(k)  # started in the background during the previous chunk
            if replay is None:
                replay = running[k] = start_chunk(k, chunk, background=False)
            converted = finish_replay(replay, log)
            del running[k]
            if args.overlap_replay and i + 1 < len(todo):
                # The next chunk's state-only replay (CPU) runs while this chunk renders (GPU).
                running[todo[i + 1][0]] = start_chunk(*todo[i + 1], background=True)
                log(f"  chunk {todo[i + 1][0]}: its replay runs in the background during chunk {k}'s render")
            t = time.perf_counter()
            data = convert_episodes(converted, replay.work / "demos.h5", sizes, device=args.device, log=log,
                                    frame_stride=args.frame_stride, render_workers=min(args.num_envs, len(chunk)),
                                    render_obs_mode=args.obs_mode, render_backends=backends)
            for e in data["episodes"]:
                e["source"] = source.name  # the chunk file is a temporary copy
            size = write_training_file(target, data)
            frames = int(len(data.get("qpos", [])))
            log(f"  chunk {k}: {len(data['episodes'])}/{len(chunk)} demos, {frames} frames, {size / 1e6:.1f} MB "
                f"({size / max(frames, 1) / 1e3:.1f} KB a frame; replay output "
                f"{converted.stat().st_size / max(frames, 1) / 1e3:.0f} KB a frame), points and labels in "
                f"{time.perf_counter() - t:.0f} s; the chunk in {time.perf_counter() - t_chunk:.1f} s")
            shutil.rmtree(replay.work)
            records[target.name] = chunk_record(target)
            totals = write_manifest(manifest_path, settings, records, len(chunks))
            longest = max(longest, time.perf_counter() - t_chunk)
    finally:
        # A background replay of a chunk that will not be done now (the time limit, an error).
        for k, replay in running.items():
            stop_replay(replay)
            log(f"  stopped the replay of chunk {k} (it is redone on resuming)")
    return finish(out, records, chunks, totals, log)


def finish(out: Path, records: dict, chunks: list, totals: dict, log) -> int:
    shutil.rmtree(out / "work", ignore_errors=True)
    log(f"{len(records)}/{len(chunks)} chunks done, {totals['frames']} frames, {totals['bytes'] / 1e9:.2f} GB"
        + ("" if len(records) == len(chunks) else " (incomplete: run again)"))
    return 0


def convert_at_expert_states(args, source: Path, meta: dict, todo: list, out: Path, manifest_path: Path,
                             settings: dict, records: dict, n_chunks: int, backends, log) -> tuple[dict, dict]:
    """``--labels expert-states``: every chunk's frames rendered at its demos' recorded states by
    one pool of render processes (no replay); returns the manifest's totals and the records."""
    totals = write_manifest(manifest_path, settings, records, n_chunks)
    if not todo:
        return totals, records
    t_start, longest = time.perf_counter(), 0.0
    env_id, env_kwargs = meta["env_info"]["env_id"], meta["env_info"]["env_kwargs"]
    workers = min(args.num_envs, max(len(chunk) for _, chunk in todo))
    with StateRenderPool(env_id, env_kwargs, workers, args.obs_mode, backends) as pool:
        for k, chunk in todo:
            if args.time_limit and time.perf_counter() - t_start + longest > args.time_limit:
                log(f"time limit: stopped before chunk {k}; run the same command again to resume")
                break
            t_chunk, before = time.perf_counter(), dict(pool.seconds)
            target = out / f"chunk_{k:05d}.imit.h5"
            data = expert_state_episodes(source, chunk, pool, args.obs_mode, args.frame_stride, log, args.first_steps)
            size = write_training_file(target, data)
            frames = int(len(data.get("qpos", [])))
            spent = {key: pool.seconds[key] - before[key] for key in before}
            log(f"  chunk {k}: {len(data['episodes'])}/{len(chunk)} demos at their recorded states, {frames} frames, "
                f"{size / 1e6:.1f} MB, in {time.perf_counter() - t_chunk:.1f} s (its {workers} workers: resets "
                f"{spent['reset']:.0f} s, frames {spent['frames']:.0f} s, i.e. {spent['frames'] / max(frames, 1) * 1e3:.1f} "
                f"ms a frame and {spent['reset'] / max(len(chunk), 1):.2f} s a demo's reset)")
            records[target.name] = chunk_record(target)
            totals = write_manifest(manifest_path, settings, records, n_chunks)
            longest = max(longest, time.perf_counter() - t_chunk)
    return totals, records


if __name__ == "__main__":
    # A stop (SIGTERM: a shell's kill, a job scheduler) runs main's `finally`, which
    # stops the replays: they run in process groups of their own, which the signal misses.
    signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum))
    sys.exit(main())
