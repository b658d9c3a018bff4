"""Ray backend: the same tasks and records as the local pool, on a Ray cluster.

``address`` joins an existing cluster (``ray.init(address=...)``, e.g. ``auto`` or
``ray://head:10001``); without it a local cluster with ``workers`` CPUs is started (and
stopped at the end). One actor per worker keeps its env between tasks, like a local
worker process. A task's time limit counts from its method's start in the actor, as the
local pool's does (the driver asks the actor, ``method_elapsed``, while a task's env is
still being made: an actor's start-up and env build on a loaded machine are not the
method's time). A task running past its limit gets its actor killed and replaced; an
actor that dies takes only its current task (an error record) with it. The driver alone writes results, so the
store is the same whatever the backend.
"""
from __future__ import annotations

import os
import sys
import time
from typing import Callable, Iterable

from ..method_spec import RunSpec
from .methods import TaskRunner, WorkItem, error_record, setup_limit, timeout_message


#: How long an actor may take to start before its first task's clock runs anyway, s.
ACTOR_START_LIMIT = 300.0
#: s between two questions to an actor whose task's method has not started yet.
POLL_EVERY = 2.0


def _actor_class(ray):
    # Two threads: ``method_elapsed`` answers while ``run`` works.
    @ray.remote(num_cpus=1, max_restarts=0, max_concurrency=2)
    class TaskActor:
        def __init__(self, spec: RunSpec):
            os.environ.setdefault("OMP_NUM_THREADS", "1")
            import torch

            torch.set_num_threads(1)
            self.runner = TaskRunner(spec)

        def ready(self) -> bool:
            return True

        def run(self, item: WorkItem) -> dict:
            return self.runner(item)

        def method_elapsed(self, task_id: str):
            """s since ``task_id``'s method started here; None before (or after) it."""
            item = getattr(self.runner, "current_item", None)
            return self.runner.method_elapsed() if item is not None and item.task_id == task_id else None

    return TaskActor


def run_ray(spec: RunSpec, items: Iterable[WorkItem], on_record: Callable[[dict], None], workers: int = 1,
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
    from ray.exceptions import GetTimeoutError, RayActorError, RayError, RayTaskError

    queue = list(reversed(items))

    def start_actors(n: int) -> list:
        # Tasks go to an actor once it is up (starting a process and importing the env can
        # take long on a loaded machine); their limits count from their methods' starts.
        started = [TaskActor.remote(spec) for _ in range(n)]
        for actor in started:
            try:
                ray.get(actor.ready.remote(), timeout=ACTOR_START_LIMIT)
            except (RayActorError, RayTaskError, GetTimeoutError):
                pass  # a failed or slow start shows up on the actor's first task and is recorded there
        return started

    actors = start_actors(min(workers, len(items)))

    class Running:  # one task in an actor
        def __init__(self, i: int, item: WorkItem):
            self.i, self.item, self.start = i, item, time.monotonic()  # start: its dispatch
            self.method_started = None  # the driver's clock when its method started, once known
            self.poll, self.polled = None, 0.0  # the pending method_elapsed question, when asked

        def deadline(self) -> float:
            if self.method_started is not None:
                return self.method_started + task_timeout
            return self.start + setup_limit(task_timeout)

    running: dict = {}  # object ref -> Running

    def submit(i: int) -> None:
        item = queue.pop()
        running[actors[i].run.remote(item)] = Running(i, item)

    for i in range(len(actors)):
        if queue:
            submit(i)

    def failed(item: WorkItem, start: float, kind: str, message: str, trace: str = "") -> dict:
        return {**error_record(item, kind, message, trace), "method": spec.name,
                "wall_time": round(time.monotonic() - start, 2)}

    def learn_method_starts() -> None:
        """Ask the actors whose task's method has not started yet (at most every POLL_EVERY s
        each) and take in their answers; never waits."""
        now = time.monotonic()
        asked = {task.poll: task for task in running.values() if task.poll is not None}
        if asked:
            answered, _ = ray.wait(list(asked), num_returns=len(asked), timeout=0)
            for ref in answered:
                task = asked[ref]
                task.poll = None
                try:
                    elapsed = ray.get(ref)
                except RayError:
                    continue  # unanswered (a dead actor: its task's own ref says so)
                if elapsed is not None:
                    task.method_started = time.monotonic() - elapsed
        for task in running.values():
            if task.method_started is None and task.poll is None and now - task.polled >= POLL_EVERY:
                task.poll, task.polled = actors[task.i].method_elapsed.remote(task.item.task_id), now

    while running:
        learn_method_starts()
        now = time.monotonic()
        wake = min(task.deadline() for task in running.values())
        if any(task.method_started is None for task in running.values()):
            wake = min(wake, now + POLL_EVERY)
        ready, _ = ray.wait(list(running), num_returns=1, timeout=max(0.0, wake - now))
        for ref in ready:
            task = running.pop(ref)
            i, item, start = task.i, task.item, task.start
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
        learn_method_starts()
        now = time.monotonic()
        for ref, task in list(running.items()):
            if now > task.deadline():
                running.pop(ref)
                ray.kill(actors[task.i], no_restart=True)
                on_record(failed(task.item, task.start, "timeout",
                                 timeout_message(task.method_started is not None, task_timeout)))
                actors[task.i] = start_actors(1)[0]
                if queue:
                    submit(task.i)
