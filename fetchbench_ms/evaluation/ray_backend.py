"""Ray backend: the same tasks and records as the local pool, on a Ray cluster.

``address`` joins an existing cluster (``ray.init(address=...)``, e.g. ``auto`` or
``ray://head:10001``); without it a local cluster with ``workers`` CPUs is started (and
stopped at the end). One actor per worker keeps its env between tasks, like a local
worker process (its first task's time limit includes the actor's start-up). A task
running past its limit gets its actor killed and replaced; an actor that dies takes only
its current task (an error record) with it. The driver alone writes results, so the
store is the same whatever the backend.
"""
from __future__ import annotations

import os
import sys
import time
from typing import Callable, Iterable

from .methods import RunnerSpec, WorkItem, error_record


#: How long an actor may take to start before its first task's clock runs anyway, s.
ACTOR_START_LIMIT = 300.0


def _actor_class(ray):
    @ray.remote(num_cpus=1, max_restarts=0)
    class TaskActor:
        def __init__(self, spec: RunnerSpec):
            os.environ.setdefault("OMP_NUM_THREADS", "1")
            import torch

            torch.set_num_threads(1)
            self.runner = spec.make()

        def ready(self) -> bool:
            return True

        def run(self, item: WorkItem) -> dict:
            return self.runner(item)

    return TaskActor


def run_ray(spec: RunnerSpec, items: Iterable[WorkItem], on_record: Callable[[dict], None], workers: int = 1,
            task_timeout: float = 600.0, address: str | None = None) -> None:
    try:
        import ray
    except ImportError as error:
        raise ValueError("the ray backend needs Ray: pip install 'fetchbench_ms[ray]' (or pip install ray)") from error
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    items = list(items)
    if not items:
        return
    started_here = not ray.is_initialized()
    if started_here:
        # Workers import this package (and custom module:function methods) as the driver does.
        runtime_env = {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}}
        if address is None:
            ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, runtime_env=runtime_env)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        _run(ray, _actor_class(ray), spec, items, on_record, workers, task_timeout)
    finally:
        if started_here:
            ray.shutdown()


def _run(ray, TaskActor, spec, items, on_record, workers, task_timeout) -> None:
    from ray.exceptions import GetTimeoutError, RayActorError, RayTaskError

    queue = list(reversed(items))

    def start_actors(n: int) -> list:
        # A task's time limit counts from when its actor is up: starting a process and
        # importing the env can take longer than a task on a loaded machine.
        started = [TaskActor.remote(spec) for _ in range(n)]
        for actor in started:
            try:
                ray.get(actor.ready.remote(), timeout=ACTOR_START_LIMIT)
            except (RayActorError, RayTaskError, GetTimeoutError):
                pass  # a failed or slow start shows up on the actor's first task and is recorded there
        return started

    actors = start_actors(min(workers, len(items)))
    running: dict = {}  # object ref -> (actor index, item, start time)

    def submit(i: int) -> None:
        item = queue.pop()
        running[actors[i].run.remote(item)] = (i, item, time.monotonic())

    for i in range(len(actors)):
        if queue:
            submit(i)
    def failed(item: WorkItem, start: float, kind: str, message: str, trace: str = "") -> dict:
        return {**error_record(item, kind, message, trace), "method": spec.method,
                "wall_time": round(time.monotonic() - start, 2)}

    while running:
        now = time.monotonic()
        deadline = min(start + task_timeout for _, _, start in running.values())
        ready, _ = ray.wait(list(running), num_returns=1, timeout=max(0.0, deadline - now))
        for ref in ready:
            i, item, start = running.pop(ref)
            try:
                record = ray.get(ref)
            except RayActorError as error:  # the actor's process died
                record = failed(item, start, "crash", f"the Ray actor died ({type(error).__name__})")
                actors[i] = start_actors(1)[0]
            except RayTaskError as error:  # the actor's constructor raised (the runner catches task errors)
                record = failed(item, start, "exception", str(error).splitlines()[0], str(error))
                actors[i] = start_actors(1)[0]
            on_record(record)
            if queue:
                submit(i)
        now = time.monotonic()
        for ref, (i, item, start) in list(running.items()):
            if now - start > task_timeout:
                running.pop(ref)
                ray.kill(actors[i], no_restart=True)
                on_record(failed(item, start, "timeout", f"ran past the task time limit of {task_timeout:g} s"))
                actors[i] = start_actors(1)[0]
                if queue:
                    submit(i)
