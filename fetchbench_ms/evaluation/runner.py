"""``evaluate``: run a method on suite tasks (or env seeds) into a resumable results store."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import Optional

from ..method_spec import RunSpec
from .methods import SAMPLED_TASK_SPLIT, WorkItem, resolve_run, task_seed
from .store import VIDEO_DIR, ResultsStore

BACKENDS = ("local", "ray")


def open_suite(name_or_path: str):
    """A shipped suite by name (``test``, ``val``, ``smoke``) or a suite file; returns
    (TaskSuite, its file, the file's identity: ``suite_file_sha256``)."""
    from ..tasks.suite import load_suite, suite_file_sha256, suite_path

    path = suite_path(name_or_path)
    return load_suite(path), str(path.resolve()), suite_file_sha256(path)


def parse_range(text: Optional[str], total: int) -> range:
    """``START:END`` (either side may be empty) over a suite of ``total`` tasks."""
    if text is None:
        return range(total)
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        start = int(parts[0]) if parts[0].strip() else 0
        end = int(parts[1]) if parts[1].strip() else total
    except ValueError:
        raise ValueError(f"--tasks takes START:END (e.g. 0:600, :20, 100:), got {text!r}") from None
    if not 0 <= start < end <= total:
        raise ValueError(f"--tasks {text!r} is out of range: need 0 <= START < END <= {total} (the suite's size)")
    return range(start, end)


def suite_items(suite, selection: range) -> list[WorkItem]:
    ids = list(suite.tasks)  # suite order: any prefix is a stratified sample
    return [WorkItem(task_id=i, seed=task_seed(i), task=suite.tasks[i].to_dict()) for i in (ids[k] for k in selection)]


def seed_items(env_id: str, episodes: int, seed: int) -> list[WorkItem]:
    from ..envs import ENV_IDS

    if env_id not in ENV_IDS:
        raise ValueError(f"unknown env id {env_id!r}; valid: {', '.join(ENV_IDS)}")
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}")
    return [WorkItem(task_id=f"{env_id}/seed-{s}", seed=s, env_id=env_id) for s in range(seed, seed + episodes)]


def check_run_numbers(workers: int, retries: int, task_timeout: float, policy_stride: int = 1) -> None:
    """A run's numeric options, checked before anything is written: ValueError naming the
    valid range of the first one out of it."""
    import math

    checks = (("workers (--workers)", workers, "a whole number >= 1 (worker processes)", 1),
              ("retries (--retries)", retries, "a whole number >= 1 (tries per task)", 1),
              ("policy_stride (--policy-stride)", policy_stride, "a whole number >= 1 (control steps per observation)", 1))
    for name, value, valid, low in checks:
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"{name} must be {valid}, got {value!r}")
    if isinstance(task_timeout, bool) or not isinstance(task_timeout, (int, float)) or not (
            task_timeout > 0 and math.isfinite(task_timeout)):
        raise ValueError(f"task_timeout (--task-timeout) must be a number of seconds > 0, got {task_timeout!r}")


def evaluate(method: str, out_dir, *, suite: Optional[str] = None, tasks: Optional[str] = None,
             env_id: Optional[str] = None, episodes: int = 10, seed: int = 0, workers: int = 1,
             backend: str = "local", address: Optional[str] = None, task_timeout: float = 600.0,
             retries: int = 1, retry_errors: bool = False, videos: bool = False,
             progress: bool = True, grasp_model: str = "pretrained",
             policy_checkpoint: Optional[str] = None, policy_stride: int = 1, improvements=(),
             env_options: Optional[dict] = None, robot: str = "panda",
             grasp_labels: Optional[str] = None, planner_options: Optional[dict] = None) -> list[dict]:
    """Run ``method`` on the selected tasks not yet in ``out_dir``; returns every record of the
    selection (old and new), in task order. ``grasp_model``: the weight set of ``cgn-*`` methods;
    ``policy_checkpoint``: the imitation methods' checkpoint; ``policy_stride``: their control
    steps per observation; ``improvements``: the pipeline's (none: the paper's pipeline);
    ``env_options``: env kwargs of the ablation (``fetchbench_ms.envs.parse_env_options``);
    ``robot``: the hardware setup (``fetchbench_ms.robots``; recorded unless the Panda);
    ``grasp_labels``: the annotated grasps' store (None: the shipped Franka-hand labels);
    ``planner_options``: planner parameters of the ablation
    (``fetchbench_ms.solutions.planner_options``). Resolved once (``methods.resolve_run``)."""
    run = resolve_run(method, retries, grasp_model, policy_checkpoint, policy_stride, improvements, grasp_labels,
                      planner_options, env_options, robot)
    return evaluate_run(run, out_dir, suite=suite, tasks=tasks, env_id=env_id, episodes=episodes, seed=seed,
                        workers=workers, backend=backend, address=address, task_timeout=task_timeout,
                        retry_errors=retry_errors, videos=videos, progress=progress)


def evaluate_run(run: RunSpec, out_dir, *, suite: Optional[str] = None, tasks: Optional[str] = None,
                 env_id: Optional[str] = None, episodes: int = 10, seed: int = 0, workers: int = 1,
                 backend: str = "local", address: Optional[str] = None, task_timeout: float = 600.0,
                 retry_errors: bool = False, videos: bool = False, progress: bool = True) -> list[dict]:
    """``evaluate`` for a resolved run (``methods.resolve_run``): ``run.json`` records it
    (``method_options``, ``method_spec``: its parts) and every worker receives it."""
    from .metrics import summarize

    check_run_numbers(workers, run.retries, task_timeout, run.policy_stride)  # before anything is written
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; valid: {', '.join(BACKENDS)}")
    if suite is not None:
        task_suite, source, source_sha = open_suite(suite)
        items = suite_items(task_suite, parse_range(tasks, len(task_suite.tasks)))
        selection = {"suite": task_suite.name, "tasks": tasks}
    else:
        env_id = env_id or "FetchBench-v0"
        items = seed_items(env_id, episodes, seed)
        # (the split is recorded for the reader; resuming compares method and source only)
        source, source_sha = f"env:{env_id}", None
        selection = {"env_id": env_id, "episodes": episodes, "seed": seed, "object_split": SAMPLED_TASK_SPLIT}
    store = ResultsStore(Path(out_dir))
    store.open_run({"method": run.name, "source": source, "source_sha256": source_sha,
                    "method_options": run.method_options(), "method_spec": run.method.to_json(),
                    "selection": selection})
    done = {r["task_id"]: r for r in store.records()}
    todo = [it for it in items if it.task_id not in done or (retry_errors and done[it.task_id].get("error"))]
    bar = _progress(len(items), len(items) - len(todo), run.name, progress)

    todo_ids = {t.task_id for t in todo}
    kept = [done[i.task_id] for i in items if i.task_id in done and i.task_id not in todo_ids]
    successes, finished = sum(bool(r["success"]) for r in kept), len(kept)

    running: dict = {}  # task id -> "N steps, T s" of the tasks that run long

    def on_record(record: dict) -> None:
        nonlocal successes, finished
        store.append(record)
        done[record["task_id"]] = record
        successes, finished = successes + bool(record["success"]), finished + 1
        running.pop(record["task_id"], None)
        bar.update(1)
        _postfix()

    def on_progress(task_id: str, steps: int, seconds: float) -> None:
        running[task_id] = f"{steps} steps, {seconds:.0f} s"
        _postfix()

    def _postfix() -> None:
        bar.set_postfix_str(f"success {successes}/{finished}"
                            + "".join(f"; {t}: {news}" for t, news in sorted(running.items())))

    spec = dataclasses.replace(run, video_dir=str((store.root / VIDEO_DIR).resolve()) if videos else None)
    if todo and run.robot != "panda":
        from ..planning.robot import robot_model

        robot_model(run.robot)  # fit and cache its collision spheres once here, not in every worker at once
    if todo:
        if backend == "local":
            from .local import run_local

            run_local(spec, todo, on_record, workers=workers, task_timeout=task_timeout, on_progress=on_progress)
        else:
            from .ray_backend import run_ray

            run_ray(spec, todo, on_record, workers=workers, task_timeout=task_timeout, address=address)
    bar.close()
    records = [done[i.task_id] for i in items if i.task_id in done]
    store.write_summary(summarize(store.records()))
    return records


def _progress(total: int, initial: int, method: str, enabled: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=method, unit="task", disable=not enabled, file=sys.stderr)
