"""Expert demonstrations in ManiSkill's trajectory format (the Fetch dataset).

The tasks are those of a task suite (``train`` by default: filtered tasks of train-split
objects; the test suite, or a suite of its tasks or objects, is refused: ``tasks.splits``)
that the env id admits (its category or scene type), in the suite's order, which is
stratified, so any prefix is a fair sample. Task ``i`` of that list is episode seed ``i``:
the env is reset with ``reset(seed=i, options={"task_id": ..., "task_hash": ...})``, which
the trajectory's JSON records, so ManiSkill's replay tool resets to the same task, and
fails loudly if the suite was rebuilt since (the hash is the task's content hash).

Per task the expert (``solutions.expert``) makes up to ``per_task`` successful trajectories,
each from another annotated grasp (the paper has about 4.8 a task); failed tries are not
kept. Every step goes through ``env.step`` inside ManiSkill's ``RecordEpisode``, which writes
the env states and the ``pd_joint_pos`` actions; each ``traj_N`` group also gets

- ``stage`` (int8, one per action): 0 approach, 1 close, 2 retrieve (``STAGES``);
- ``stage_end`` (bool): the original's end-of-stage flag, True at a stage's last step;

and each episode in the JSON its ``task_id``, ``grasp_id``, ``scene_type``, ``category``,
``target_object`` and ``cspace_length``.

Files: ``<record_dir>/<env_id>/motionplanning/<name>.h5`` and ``.json`` (ManiSkill's layout,
merged with ManiSkill's ``merge_trajectories``), made from one part per task in
``<name>.parts/`` (``task_NNNNNN.h5`` + ``.json``). A part is written under a temporary
name and renamed, its JSON last, so a killed run (even ``kill -9``) leaves only whole parts
and a rerun continues with the tasks that have none. The merged file takes the parts in
task order, so its contents do not depend on the number of processes.
"""
from __future__ import annotations

import dataclasses
import json
import multiprocessing as mp
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..tasks.splits import refuse_test_env_kwargs, refuse_test_task_ids
from ..utils.io import append_jsonl_atomic, atomic_write_text
from .env_info import replayable_env_info

PART_PREFIX = "task_"
TIMING_FILE = "timing.jsonl"  # seconds each task took in its worker (benchmarks read it)
TIMES = ("wall_time", "cpu_time")  # a task's seconds: in the timing file, never in its part (same bytes)
DEFAULT_PER_TASK = 5
DEFAULT_MAX_TRIES = 8  # expert tries per task, successful or not
SOURCE_DESC = "FetchBench-MS expert: annotated grasps, oracle mesh world, RRTConnect (fetchbench_ms.solutions.expert)"


@dataclass(frozen=True)
class DemoJob:
    """What a generator run makes (everything a part's content depends on)."""

    env_id: str = "FetchBench-v0"
    task_suite: str = "train"
    obs_mode: str = "none"
    per_task: int = DEFAULT_PER_TASK
    max_tries: int = DEFAULT_MAX_TRIES
    save_video: bool = False
    method: str = "ga-mesh-rrt"
    expert: str = "fast"  # solutions.expert.EXPERTS

    @staticmethod
    def from_json(job: dict) -> dict:
        """A recorded job as this version writes it: a job recorded before experts were named
        was made by the ``reference`` expert."""
        return {"expert": "reference", **job}

    def env_kwargs(self) -> dict:
        kwargs = dict(obs_mode=self.obs_mode, control_mode="pd_joint_pos", task_suite=self.task_suite)
        if not self.save_video and self.obs_mode in ("none", "state", "state_dict"):
            kwargs["render_backend"] = "none"  # nothing to render: no renderer to start
        else:
            kwargs["render_mode"] = "rgb_array"
        return kwargs


def suite_task_ids(env_id: str, task_suite: str) -> list[str]:
    """The suite's task ids the env id admits, in suite order (episode seed i -> the i-th)."""
    from ..envs import ENV_IDS, ENV_KWARGS
    from ..tasks.spec import CATEGORY_LABELS
    from ..tasks.suite import load_suite

    if env_id not in ENV_IDS:
        raise ValueError(f"unknown FetchBench env id {env_id!r}; valid: {', '.join(ENV_IDS)}")
    fixed = ENV_KWARGS[env_id]
    suite = load_suite(task_suite)
    label = CATEGORY_LABELS.get(fixed.get("category"))
    ids = [tid for tid in suite.ids()
           if label in (None, suite.get(tid).target_label) and fixed.get("scene_type") in (None, suite.get(tid).scene_type)]
    if not ids:
        raise ValueError(f"suite {task_suite!r} has no task that {env_id} admits ({fixed})")
    return ids


def check_writable_dir(folder: str | Path, flag: str) -> None:
    """ValueError (one line) unless ``folder`` is, or can be made as, a folder this process
    can write to: a file in its place or a folder without write permission fails here, before
    any worker starts, rather than as a traceback from deep inside."""
    folder = Path(folder)
    existing = next((p for p in (folder, *folder.parents) if p.exists()), None)
    if existing is not None and not existing.is_dir():
        raise ValueError(f"{flag} {folder}: {existing} is a file; valid: a folder (made if missing)")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as error:
        raise ValueError(f"{flag} {folder} is not writable ({error.strerror}: {error.filename}); valid: a folder "
                         "you can write to") from None


def parts_dir(record_dir: str | Path, env_id: str, name: str) -> Path:
    return Path(record_dir) / env_id / "motionplanning" / f"{name}.parts"


def part_path(parts: Path, seed: int) -> Path:
    return parts / f"{PART_PREFIX}{seed:06d}.h5"


def done_parts(parts: Path) -> dict[int, dict]:
    """seed -> the part's summary (tries, successes, frames, ...), for every finished part
    (a part is finished once its JSON is in)."""
    out = {}
    if parts.is_dir():
        for j in parts.glob(f"{PART_PREFIX}*.json"):
            seed = int(j.stem[len(PART_PREFIX):])
            if part_path(parts, seed).exists():
                out[seed] = json.loads(j.read_text())["fetchbench"]["summary"]
    return out


# ----------------------------------------------------------------------------- one task
_ENV = None


def _worker_env(job: DemoJob):
    global _ENV
    if _ENV is None:
        import gymnasium as gym
        import torch

        import fetchbench_ms  # noqa: F401  (registers the ids)

        torch.set_num_threads(1)
        # No reward: the demos record none, and the dense reward's contact pass over every
        # resting contact costs a sixth of a control step. The physics, and so the recorded
        # states, do not read it; the files keep the job's env kwargs (conversions get the
        # env's default reward).
        _ENV = gym.make(job.env_id, **job.env_kwargs(), reward_mode="none")
    return _ENV


def run_task(job: DemoJob, parts: Path, seed: int, task_id: str) -> dict:
    """The expert's trajectories of one task, written as one part; returns its summary."""
    from mani_skill.utils.io_utils import dump_json
    from mani_skill.utils.wrappers.record import RecordEpisode

    from ..solutions.expert import expert_spec, solve_demo, stage_end_flags

    expert = expert_spec(job.expert)
    env = _worker_env(job)
    tmp = parts / f".tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    name = part_path(parts, seed).stem
    rec = RecordEpisode(env, output_dir=str(tmp), trajectory_name=name, save_video=job.save_video,
                        source_type="motionplanning", source_desc=SOURCE_DESC, record_reward=False,
                        save_on_reset=False, video_fps=env.unwrapped.control_freq)
    info = rec._json_data["env_info"]
    info["env_kwargs"] = {k: v for k, v in info["env_kwargs"].items() if k != "reward_mode"}  # (_worker_env's)
    task = env.unwrapped.task_suite.get(task_id)
    tried: set = set()
    summary = dict(seed=seed, task_id=task_id, scene_type=task.scene_type, category=task.target_label,
                   tries=0, successes=0, frames=0, failures={}, reasons={})
    t0, cpu0 = time.perf_counter(), time.process_time()
    failures_in_a_row = 0
    for _ in range(job.max_tries):
        n_tried = len(tried)
        demo = solve_demo(rec, seed, reset_options={"task_id": task_id, "task_hash": task.content_hash()[:16]},
                          tried=tried, method=job.method, config=expert.config(),
                          confirm_steps=expert.confirm_steps)
        summary["tries"] += 1
        if demo.success:
            if demo.steps != len(rec._trajectory_buffer.done) - 1:
                raise RuntimeError(f"{task_id}: {demo.steps} labelled steps, {len(rec._trajectory_buffer.done) - 1} recorded")
            rec.flush_trajectory()
            group = rec._h5_file[f"traj_{rec._episode_id}"]
            group.create_dataset("stage", data=demo.stages, dtype=np.int8)
            group.create_dataset("stage_end", data=stage_end_flags(demo.stages), dtype=bool)
            rec._json_data["episodes"][-1].update(
                task_id=task_id, grasp_id=demo.grasp_id, scene_type=task.scene_type, category=task.target_label,
                target_object=task.target.object_id, cspace_length=round(demo.cspace_length, 4))
            if job.save_video:
                rec.flush_video(name=f"{name}_{rec._episode_id}")
            summary["successes"] += 1
            summary["frames"] += demo.steps
            failures_in_a_row = 0
        else:
            failures_in_a_row += 1
            rec.flush_trajectory(save=False)
            if job.save_video:
                rec.flush_video(save=False)
            summary["failures"][demo.failure] = summary["failures"].get(demo.failure, 0) + 1
            summary["reasons"][demo.reason] = summary["reasons"].get(demo.reason, 0) + 1
        if summary["successes"] >= job.per_task or len(tried) == n_tried:
            break  # enough, or the try executed no new grasp: another would do the same
        if failures_in_a_row and failures_in_a_row == expert.max_failures_in_a_row:
            break
    summary["wall_time"] = round(time.perf_counter() - t0, 2)
    summary["cpu_time"] = round(time.process_time() - cpu0, 2)  # this process's CPU: unlike the wall time, not
    # stretched by other processes on the machine
    rec._json_data["fetchbench"] = {"job": dataclasses.asdict(job), "expert": expert.to_json(), "summary": {
        k: v for k, v in summary.items() if k not in TIMES}}
    dump_json(rec._json_path, rec._json_data, indent=2)
    rec._h5_file.close()
    # Whole parts only: the h5 first, then the JSON, which marks the part finished.
    for suffix in (".h5", ".json"):
        os.replace(tmp / f"{name}{suffix}", parts / f"{name}{suffix}")
    for video in tmp.glob("*.mp4"):
        os.replace(video, parts / video.name)
    shutil.rmtree(tmp, ignore_errors=True)
    return summary


def _run_task_star(args):
    return run_task(*args)


# ----------------------------------------------------------------------------- a run
def generate(job: DemoJob, record_dir: str | Path, name: str, num_traj: int, only_count_success: bool = True,
             num_procs: int = 1, backend: str = "local", progress: bool = True, start_seed: int = 0) -> Path:
    """Runs the expert over the suite's tasks until ``num_traj`` successful trajectories
    (``only_count_success``) or ``num_traj`` tasks are done, resuming from finished parts;
    then merges them. Returns the merged .h5 path."""
    from tqdm import tqdm

    refuse_test_env_kwargs(job.env_kwargs(), "demonstration generation")  # before anything is written
    if backend not in ("local", "ray"):
        raise ValueError(f"unknown backend {backend!r}; valid: local, ray")
    if num_traj < 1 or num_procs < 1:
        raise ValueError(f"num_traj and num_procs must be positive (got {num_traj}, {num_procs})")
    ids = suite_task_ids(job.env_id, job.task_suite)
    # Episode seed i is task i of the suite's list, whatever --start-seed is: a run from
    # --start-seed K continues one from 0 with the tasks it did not reach, and the same
    # command regenerates any part of the dataset. (Before 2026-11-24 a run from K gave seed
    # K + i to task i: the same tasks again under other seeds.)
    if not 0 <= start_seed < len(ids):
        raise ValueError(f"start_seed {start_seed} is outside the {len(ids)} tasks of suite {job.task_suite!r} "
                         f"that {job.env_id} admits (valid: 0 .. {len(ids) - 1})")
    parts = parts_dir(record_dir, job.env_id, name)
    check_writable_dir(record_dir, "--record-dir")
    parts.mkdir(parents=True, exist_ok=True)
    job_file = parts / "job.json"
    from ..solutions.expert import expert_spec

    expert_spec(job.expert)  # an unknown name fails here, before any worker starts
    if job_file.exists() and DemoJob.from_json(json.loads(job_file.read_text())) != dataclasses.asdict(job):
        raise ValueError(f"{parts} holds parts of another job {job_file.read_text()}; this one is "
                         f"{dataclasses.asdict(job)}: use another --traj-name or --record-dir")
    atomic_write_text(job_file, json.dumps(dataclasses.asdict(job), indent=1))
    finished = done_parts(parts)

    def enough(done: dict) -> int | None:
        """The number of leading tasks that make the run (None: not yet)."""
        total = 0
        for k, seed in enumerate(range(start_seed, len(ids))):
            if seed not in done:
                return None
            total += done[seed]["successes"] if only_count_success else 1
            if total >= num_traj:
                return k + 1
        return len(ids)  # the suite ran out

    bar = tqdm(total=num_traj, desc=f"{job.env_id} {name}", disable=not progress, unit="traj")

    def count(done):
        return sum(s["successes"] if only_count_success else 1 for s in done.values())

    bar.update(min(num_traj, count(finished)))
    seeds = (s for s in range(start_seed, len(ids)) if s not in finished)
    if enough(finished) is None:
        pool = _pool(backend, num_procs)
        try:
            pending = []
            while True:
                while len(pending) < 2 * num_procs:
                    seed = next(seeds, None)
                    if seed is None:
                        break
                    pending.append(pool.apply_async(_run_task_star, ((job, parts, seed, ids[seed]),)))
                if not pending:
                    break
                # wait for any task, not the oldest: one long task (eight failed tries) must not
                # keep the other workers idle once the queue behind it has drained
                while not any(p.ready() for p in pending):
                    time.sleep(0.05)
                done_now = [p for p in pending if p.ready()]
                pending = [p for p in pending if not p.ready()]
                for p in done_now:
                    s = p.get()
                    finished[s["seed"]] = s
                    # Timings vary from run to run, so they stay out of the parts (same bytes).
                    append_jsonl_atomic(parts / TIMING_FILE, {"seed": s["seed"], **{t: s[t] for t in TIMES},
                                                              "successes": s["successes"], "frames": s["frames"]})
                    bar.update(min(s["successes"] if only_count_success else 1, max(0, num_traj - bar.n)))
                    bar.set_postfix(tasks=len(finished), success_rate=f"{_yield(finished):.2f}")
                if enough(finished) is not None:
                    break
        finally:
            pool.terminate()  # tasks still running are dropped: their parts were never renamed in
            pool.join()
    for tmp in parts.glob(".tmp-*"):
        shutil.rmtree(tmp, ignore_errors=True)
    bar.close()
    return merge(record_dir, job.env_id, name, num_traj, only_count_success, start_seed)


def _yield(done: dict) -> float:
    return float(np.mean([d["successes"] > 0 for d in done.values()])) if done else 0.0


def _pool(backend: str, num_procs: int):
    if backend == "ray":
        from ray.util.multiprocessing import Pool

        return Pool(num_procs)
    return mp.get_context("spawn").Pool(num_procs)


def merge(record_dir, env_id: str, name: str, num_traj: int, only_count_success: bool = True,
          start_seed: int = 0) -> Path:
    """``<name>.h5`` + ``.json`` from the leading finished parts (task order), cut at
    ``num_traj`` trajectories, with ManiSkill's ``merge_trajectories`` (written beside and
    renamed: a reader never sees half a file)."""
    import h5py
    from mani_skill.utils.io_utils import dump_json, load_json

    parts = parts_dir(record_dir, env_id, name)
    finished = done_parts(parts)
    chosen, total, seed = [], 0, start_seed
    while seed in finished and total < num_traj:
        n = finished[seed]["successes"] if only_count_success else 1
        if finished[seed]["successes"]:
            chosen.append(part_path(parts, seed))
        total += n
        seed += 1
    out = parts.parent / f"{name}.h5"
    tmp = parts.parent / f".{name}.merging.h5"
    _merge_quietly(tmp, chosen) if chosen else _empty(tmp)
    data = load_json(str(tmp).replace(".h5", ".json"))
    keep = min(len(data["episodes"]), num_traj) if only_count_success else len(data["episodes"])
    if keep < len(data["episodes"]):
        with h5py.File(tmp, "a") as f:
            for ep in data["episodes"][keep:]:
                del f[f"traj_{ep['episode_id']}"]
        data["episodes"] = data["episodes"][:keep]
    data.pop("fetchbench", None)
    data["env_info"] = replayable_env_info(data["env_info"])  # ManiSkill's replay tool makes the env from it
    data["fetchbench"] = {"tasks": seed - start_seed, "first_seed": start_seed, "trajectories": len(data["episodes"]),
                          "expert": _recorded_expert(parts)}
    dump_json(str(tmp).replace(".h5", ".json"), data, indent=2)
    compressed = tmp.with_name(f".{name}.compressing.h5")
    compress_h5(tmp, compressed, pair_json=tmp.with_suffix(".json"))
    tmp.unlink()
    _replace_pair(compressed, tmp.with_suffix(".json"), out)
    return out


def _recorded_expert(parts: Path) -> dict:
    """The expert configuration (``ExpertSpec.to_json``) the parts folder's job names."""
    from ..solutions.expert import expert_spec

    job = DemoJob.from_json(json.loads((parts / "job.json").read_text())) if (parts / "job.json").exists() else {}
    return expert_spec(job.get("expert", DemoJob.expert)).to_json()


def _replace_pair(h5: Path, json_path: Path, out: Path) -> None:
    """Moves ``h5`` and ``json_path`` to ``out`` and its .json. Two renames, so a kill between
    them leaves a new .h5 beside the old .json: the .h5 carries its .json's sha256
    (``stats.PAIR_ATTR``), readers (``stats.check_trajectory_file``) refuse a pair that does
    not match, and a rerun writes both again."""
    os.replace(h5, out)
    os.replace(json_path, out.with_suffix(".json"))


def _merge_quietly(tmp: Path, files: list) -> None:
    """ManiSkill's ``merge_trajectories`` of ``files`` into ``tmp`` (+ .json). The inputs' own
    ``fetchbench`` summaries differ, about which it would warn once per file."""
    from mani_skill.trajectory.merge_trajectory import merge_trajectories
    from mani_skill.utils.logging_utils import logger

    level = logger.level
    logger.setLevel("ERROR")
    try:
        merge_trajectories(str(tmp), [str(p) for p in files])
    finally:
        logger.setLevel(level)


def merge_runs(paths: list, out) -> Path:
    """One dataset from runs over consecutive task ranges (``--start-seed``, e.g. one per
    machine or per scheduled job): ``<out>.h5`` + ``.json``, with ManiSkill's ``merge_trajectories``
    (episode ids renumbered in order), as one run over all their tasks would have made it.
    Refused, with the reason, when the runs are not back to back (a gap or an overlap of
    tasks) or came from other env ids / settings. Transport copies stay marked as such."""
    from mani_skill.utils.io_utils import dump_json, load_json

    runs = []  # (first seed, tasks, path, meta), in task order
    for p in map(Path, paths):
        meta = load_json(str(p.with_suffix(".json")))
        if "first_seed" not in meta.get("fetchbench", {}):
            raise ValueError(f"{p} is not a merged generator run (no fetchbench.first_seed in its JSON)")
        runs.append((meta["fetchbench"]["first_seed"], meta["fetchbench"]["tasks"], p, meta))
    runs.sort(key=lambda r: r[0])
    for _, _, _, meta in runs:  # demonstrations of test tasks are never training data
        refuse_test_env_kwargs(meta["env_info"].get("env_kwargs", {}), "merging demonstrations")
        refuse_test_task_ids((e.get("task_id") for e in meta.get("episodes", [])), "merging demonstrations")
    for (seed_a, tasks_a, path_a, meta_a), (seed_b, _, path_b, meta_b) in zip(runs, runs[1:]):
        if seed_a + tasks_a != seed_b:
            raise ValueError(f"{path_a} covers tasks {seed_a} .. {seed_a + tasks_a - 1} and {path_b} starts at "
                             f"{seed_b}: runs must be back to back (no gap, no overlap)")
        if replayable_env_info(meta_a["env_info"]) != replayable_env_info(meta_b["env_info"]):
            raise ValueError(f"{path_a} and {path_b} come from other envs or settings: "
                             f"{meta_a['env_info']} != {meta_b['env_info']}")
        expert_a, expert_b = (m["fetchbench"].get("expert", {"name": "reference"}) for m in (meta_a, meta_b))
        if expert_a != expert_b:
            raise ValueError(f"{path_a} and {path_b} were made by other expert configurations: "
                             f"{expert_a} != {expert_b}")
    out = Path(out).with_suffix(".h5")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.merging.h5")
    _merge_quietly(tmp, [path for _, _, path, _ in runs])
    data = load_json(str(tmp.with_suffix(".json")))
    data["env_info"] = replayable_env_info(data["env_info"])
    (first_seed, _, _, _), (last_seed, last_tasks, _, _) = runs[0], runs[-1]
    data["fetchbench"] = {"tasks": last_seed + last_tasks - first_seed, "first_seed": first_seed,
                          "trajectories": len(data["episodes"]), "runs": [str(path) for _, _, path, _ in runs],
                          "expert": runs[0][3]["fetchbench"].get("expert", {"name": "reference"})}
    transport = [meta["fetchbench_transport"] for _, _, _, meta in runs if "fetchbench_transport" in meta]
    if transport:
        data["fetchbench_transport"] = {**transport[0], "source": [t["source"] for t in transport]}
    dump_json(str(tmp.with_suffix(".json")), data, indent=2)
    _set_pair_attr(tmp, tmp.with_suffix(".json"))
    _replace_pair(tmp, tmp.with_suffix(".json"), out)
    return out


def _set_pair_attr(h5: Path, json_path: Path) -> None:
    import h5py

    from ..utils.io import sha256_file
    from .stats import PAIR_ATTR

    with h5py.File(h5, "a") as f:
        f.attrs[PAIR_ATTR] = sha256_file(json_path)


def compress_h5(src: Path, dst: Path, level: int = 4, pair_json: Path | None = None) -> None:
    """A copy of a trajectory file with every array gzip-compressed (byte shuffle first):
    env states change smoothly, so this about halves the file. h5py reads it transparently,
    ManiSkill's tools included; groups keep their order. ``pair_json``: the .json that goes
    with it, whose sha256 the copy records (``stats.PAIR_ATTR``)."""
    import h5py

    from ..utils.io import sha256_file
    from .stats import PAIR_ATTR

    def copy(a, b):
        for key, item in a.items():
            if isinstance(item, h5py.Group):
                copy(item, b.create_group(key, track_order=True))
            else:
                data = item[()]
                big = getattr(data, "size", 1) > 16
                b.create_dataset(key, data=data, dtype=item.dtype, compression="gzip" if big else None,
                                 compression_opts=level if big else None, shuffle=big)

    with h5py.File(src, "r") as a, h5py.File(dst, "w", track_order=True) as b:
        copy(a, b)
        if pair_json is not None:
            b.attrs[PAIR_ATTR] = sha256_file(pair_json)


def _empty(tmp: Path) -> None:
    import h5py

    h5py.File(tmp, "w").close()
    tmp.with_suffix(".json").write_text(json.dumps({"env_info": None, "episodes": []}))
