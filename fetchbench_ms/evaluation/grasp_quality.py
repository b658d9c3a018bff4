"""Grasp quality judged by physics: a grasp model's best predictions on a task's target, each
tried by the grasp labeller (``fetchbench_ms.grasp_labels.physics``: close, gravity, shake; the same
trial as the annotations), and the coverage of the target's annotated successful grasps
(``grasp_prediction.metrics.grasp_coverage``).

- ``QualityJudge``: one env's judge, a task at a time (``scripts/bench/bench_cgn.py quality``);
- ``judge_tasks``: several models on many tasks with worker processes (an env and a judge
  each), one JSON line per (model, task) appended to ``<out>/<model>.jsonl`` as it is judged:
  a rerun judges only what is missing (``scripts/grasp_round.py``'s val stage);
- ``summarize_quality``: the precision of the top-1 and the top-``top`` grasps over the judged
  tasks (a task whose target no camera sees has nothing to judge and is left out).

Which suites may be judged is the caller's rule (choosing weights: never test tasks).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

COVERAGE_RULE = ("annotated successful grasps with a prediction of score >= {score} whose TCP is within 2 cm and "
                 "approach within 30 deg")


class QualityJudge:
    """Judges a model's grasps on tasks of the env's suite; ``model``: a grasp-model name
    (``pretrained``, ``ours``) or a loaded ``ContactGraspNet``."""

    def __init__(self, env, top: int = 10, coverage_score: float = 0.5, device: str = "cpu"):
        self.env, self.top, self.coverage_score, self.device = env, top, coverage_score, device
        self.labeller = None  # made after the env: the labeller sets PhysX's global contact settings

    def __call__(self, task_id: str, model) -> dict:
        from fetchbench_ms.envs import fetch_clouds
        from fetchbench_ms.grasp_prediction import predict_from_clouds
        from fetchbench_ms.grasp_prediction.metrics import grasp_coverage
        from fetchbench_ms.grasp_labels import load_grasps
        from fetchbench_ms.grasp_labels.physics import GraspLabeller
        from fetchbench_ms.objects.loading import load_object
        from fetchbench_ms.planning.world_models import object_poses_base

        obs, _ = self.env.reset(options={"task_id": task_id})
        task = self.env.unwrapped.tasks[0]
        clouds = fetch_clouds(obs)
        if len(clouds.target) == 0:
            return {"task_id": task_id, "predicted": 0}
        t = time.perf_counter()
        grasps = predict_from_clouds(clouds, model, np.random.default_rng(0), device=self.device)
        seconds = time.perf_counter() - t
        T_base_object = object_poses_base(self.env)[task.target_index]
        T_object_predicted = np.linalg.inv(T_base_object)[None] @ grasps.T_base_hand
        T_object_hand = T_object_predicted[: self.top]
        annotated = load_grasps(task.target.object_id).successful.T_object_hand
        coverage = grasp_coverage(T_object_predicted[grasps.scores >= self.coverage_score], annotated)
        if self.labeller is None:
            self.labeller = GraspLabeller()
        success = self.labeller.label(load_object(task.target.object_id), T_object_hand).success if len(T_object_hand) else []
        return {"task_id": task_id, "category": task.target_label, "predicted": len(grasps.scores),
                "success": [bool(s) for s in success], "coverage": round(coverage, 4), "seconds": round(seconds, 2)}


def summarize_quality(rows: list[dict], top: int) -> dict:
    """Precision of the top-1 and top-``top`` grasps over the tasks with judged grasps, the share
    of those with any success among them, the mean coverage and the median prediction time."""
    judged = [r for r in rows if r.get("success")]

    def mean(values) -> float | None:
        return round(float(np.mean(values)), 3) if judged else None

    return {"tasks_run": len(rows), "tasks_with_predictions": len(judged),
            "precision_top1": mean([r["success"][0] for r in judged]),
            f"precision_top{top}": mean([s for r in judged for s in r["success"]]),
            "any_success_in_top": mean([any(r["success"]) for r in judged]),
            "coverage": round(float(np.nanmean([r["coverage"] for r in judged])), 3) if judged else None,
            "median_predict_s": round(float(np.median([r["seconds"] for r in judged])), 2) if judged else None}


# ----------------------------------------------------------------------------- many at once
_WORKER: dict = {}


def _init_worker(suite: str, top: int, coverage_score: float, devices: list[str]) -> None:
    import multiprocessing

    import torch

    from fetchbench_ms.envs import make

    torch.set_num_threads(1)
    identity = multiprocessing.current_process()._identity  # (1,), (2,), ... in a pool; () in this process
    device = devices[(identity[0] - 1 if identity else 0) % len(devices)]
    env = make("FetchBench-v0", obs_mode="pointcloud", task_suite=suite, control_mode="pd_joint_pos")
    _WORKER.update(judge=QualityJudge(env, top, coverage_score, device), models={}, device=device)


def _model(spec: str):
    """A model spec's network, loaded once per worker: a grasp-model name or a checkpoint path."""
    from fetchbench_ms.grasp_prediction.predict import GRASP_MODELS, load_checkpoint, load_model

    if spec not in _WORKER["models"]:
        device = _WORKER["device"]
        _WORKER["models"][spec] = load_model(spec, device) if spec in GRASP_MODELS else load_checkpoint(spec, device)
    return _WORKER["models"][spec]


def _judge_job(job: tuple[str, str, str]) -> tuple[str, dict]:
    name, spec, task_id = job
    try:
        return name, _WORKER["judge"](task_id, _model(spec))
    except Exception as error:  # name the task: a rerun would stop at it again
        raise RuntimeError(f"{name} on {task_id}: {type(error).__name__}: {error}") from error


def read_rows(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def judge_tasks(suite: str, task_ids: list[str], models: dict[str, str], out: Path, workers: int, top: int = 10,
                coverage_score: float = 0.5, devices: list[str] | None = None, log=print) -> dict[str, list[dict]]:
    """Every model (name -> ``pretrained`` | ``ours`` | checkpoint path) on every task, resumable:
    the rows of ``<out>/<name>.jsonl`` (one per task, in the order judged); returns them per model."""
    out.mkdir(parents=True, exist_ok=True)
    done = {name: {r["task_id"] for r in read_rows(out / f"{name}.jsonl")} for name in models}
    jobs = [(name, spec, task_id) for task_id in task_ids for name, spec in models.items()
            if task_id not in done[name]]
    setup = (suite, top, coverage_score, devices or ["cpu"])
    if jobs:
        log(f"grasp quality: {len(jobs)} (model, task) pairs to judge of {len(task_ids) * len(models)}, "
            f"{min(workers, len(jobs))} workers")
        files = {name: open(out / f"{name}.jsonl", "a") for name in models}
        t = time.perf_counter()
        try:
            if min(workers, len(jobs)) <= 1:
                _init_worker(*setup)
                results = map(_judge_job, jobs)
                for name, row in results:
                    files[name].write(json.dumps(row) + "\n")
                    files[name].flush()
            else:
                import multiprocessing

                from fetchbench_ms.utils.workers import one_thread_per_spawned_worker

                with one_thread_per_spawned_worker(), multiprocessing.get_context("spawn").Pool(
                        min(workers, len(jobs)), _init_worker, setup) as pool:
                    for name, row in pool.imap_unordered(_judge_job, jobs):
                        files[name].write(json.dumps(row) + "\n")
                        files[name].flush()
        finally:
            for f in files.values():
                f.close()
        log(f"grasp quality: {len(jobs)} judged in {time.perf_counter() - t:.0f} s")
    rows = {name: read_rows(out / f"{name}.jsonl") for name in models}
    wanted = set(task_ids)
    return {name: [r for r in rows[name] if r["task_id"] in wanted] for name in models}
