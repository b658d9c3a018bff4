"""Local backend: a pool of long-lived worker processes (spawn start), one task at a time each.

Each worker keeps its env between tasks (building ManiSkill and the renderer takes
seconds). The parent alone writes results. A task that raises is recorded by its worker
with the traceback; a worker that dies (segfault, out of memory) or runs past the task's
time limit is killed, the task recorded as an error, and a fresh worker takes its place.
Workers die with the parent (Linux: PR_SET_PDEATHSIG), so a killed run leaves none behind.
"""
from __future__ import annotations

import collections
import multiprocessing as mp
import os
import signal
import time
from multiprocessing.connection import wait
from typing import Callable, Iterable

from ..method_spec import RunSpec
from .methods import TaskRunner, WorkItem, error_record, setup_limit, timeout_message

READY = "ready"
STARTED = "started"  # ("started", task id): the task's env is made and reset, its method runs (its limit starts)
PROGRESS = "progress"  # ("progress", task id, control steps of its episode, seconds): a task still running
PROGRESS_AFTER = 5.0  # s a task runs before its worker reports its control steps
PROGRESS_EVERY = 2.0  # s between two such reports
STARTUP_TIMEOUT = 300.0  # s for a worker to import everything and say it is ready


def _die_with_parent() -> None:
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except OSError:  # not Linux: orphans exit when they read the closed pipe
        pass


def worker_main(conn, spec: RunSpec, parent_pid: int) -> None:
    _die_with_parent()
    if os.getppid() != parent_pid:  # the parent died before the death signal was armed
        return
    # One core per worker: many workers share the machine, threads would fight.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import threading

    import torch

    torch.set_num_threads(1)
    runner = TaskRunner(spec)
    send_lock, running = threading.Lock(), {}

    def method_started(item: WorkItem) -> None:
        with send_lock:
            conn.send((STARTED, item.task_id))

    runner.on_method_start = method_started
    threading.Thread(target=_report_progress, args=(conn, send_lock, runner, running), daemon=True).start()
    with send_lock:
        conn.send(READY)
    while True:
        try:
            item = conn.recv()
        except (EOFError, OSError):
            break
        if item is None:
            break
        running.update(item=item, started=time.monotonic())
        record = runner(item)
        with send_lock:
            running.clear()
            conn.send(record)
    runner.close()


def _report_progress(conn, send_lock, runner, running: dict) -> None:
    """Worker thread: while a task runs longer than ``PROGRESS_AFTER``, send its episode's
    control steps every ``PROGRESS_EVERY`` s, so a long task shows it is moving (read-only:
    the env's step counter)."""
    while True:
        time.sleep(PROGRESS_EVERY)
        with send_lock:
            item, started = running.get("item"), running.get("started")
            if item is None or time.monotonic() - started < PROGRESS_AFTER:
                continue
            env = getattr(runner, "current_env", None)
            try:
                steps = int(env.unwrapped.elapsed_steps.reshape(-1)[0]) if env is not None else 0
            except (AttributeError, RuntimeError, TypeError):
                steps = 0
            try:
                conn.send((PROGRESS, item.task_id, steps, round(time.monotonic() - started, 1)))
            except (OSError, ValueError):
                return


class _Worker:
    def __init__(self, ctx, spec: RunSpec):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=worker_main, args=(child, spec, os.getpid()), daemon=True)
        self.proc.start()
        child.close()
        self.ready = False
        self.started = time.monotonic()  # the process's start, then each task's dispatch
        self.method_started: float | None = None  # when the current task's method started
        self.item: WorkItem | None = None

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        self.conn.close()


def _deadline(worker: _Worker, task_timeout: float) -> float:
    """The start-up's limit, then a task's: ``task_timeout`` from its method's start in the
    worker (not from its dispatch: a loaded machine's slow env build is not the method's
    time), and ``setup_limit`` for making and resetting its env before that."""
    if not worker.ready:
        return worker.started + STARTUP_TIMEOUT
    if worker.method_started is not None:
        return worker.method_started + task_timeout
    return worker.started + setup_limit(task_timeout)


def run_local(spec: RunSpec, items: Iterable[WorkItem], on_record: Callable[[dict], None], workers: int = 1,
              task_timeout: float = 600.0, on_progress: Callable[[str, int, float], None] | None = None) -> None:
    """Run every item; ``on_record`` gets each task's record (in the parent) as it finishes,
    ``on_progress`` (task id, control steps, seconds) the news of a task that runs long."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    queue = collections.deque(items)
    if not queue:
        return
    ctx = mp.get_context("spawn")
    from ..utils.quiet import announce_render_device

    announce_render_device()  # once here, not once a worker
    pool = [_Worker(ctx, spec) for _ in range(min(workers, len(queue)))]
    failed_starts = 0
    try:
        while pool:
            now = time.monotonic()
            for w in pool:
                if w.ready and w.item is None and queue:
                    w.item, w.started, w.method_started = queue.popleft(), now, None
                    w.conn.send(w.item)
            if not queue and all(w.item is None for w in pool):
                break
            deadlines = [_deadline(w, task_timeout) for w in pool if w.item is not None or not w.ready]
            wait([w.conn for w in pool] + [w.proc.sentinel for w in pool],
                 max(0.0, min(deadlines) - now) if deadlines else None)
            for i, w in enumerate(pool):
                message, died = None, False
                if w.conn.poll():
                    try:
                        message = w.conn.recv()
                    except (EOFError, OSError):
                        died = True
                elif not w.proc.is_alive():
                    died = True
                if message == READY:
                    w.ready, failed_starts = True, 0
                elif isinstance(message, tuple) and message[0] == STARTED:
                    if w.item is not None and message[1] == w.item.task_id:
                        w.method_started = time.monotonic()
                elif isinstance(message, tuple) and message[0] == PROGRESS:
                    if on_progress is not None and w.item is not None and message[1] == w.item.task_id:
                        on_progress(*message[1:])  # (then on to the deadline check: news is no reprieve)
                elif message is not None:
                    w.item = None
                    on_record(message)
                    continue
                busy = w.item is not None or not w.ready  # an idle worker has no deadline
                timed_out = not died and busy and time.monotonic() > _deadline(w, task_timeout)
                if not (died or timed_out):
                    continue
                if w.item is not None:
                    if timed_out:
                        record = error_record(w.item, "timeout",
                                              timeout_message(w.method_started is not None, task_timeout))
                    else:
                        w.proc.join(5)  # its pipe closes a moment before it can be reaped
                        record = error_record(w.item, "crash", f"the worker process died "
                                                                f"(exit code {w.proc.exitcode})")
                    record.update(method=spec.name, wall_time=round(time.monotonic() - w.started, 2))
                    on_record(record)
                else:
                    failed_starts += 1
                    if failed_starts >= 3:
                        raise RuntimeError(f"worker processes fail to start (exit code {w.proc.exitcode})")
                w.kill()
                # A fresh worker only if there is work left for it.
                pool[i] = _Worker(ctx, spec) if queue else None
            pool = [w for w in pool if w is not None]
    finally:
        for w in pool:
            try:
                w.conn.send(None)
            except (OSError, ValueError):
                pass
        for w in pool:
            w.proc.join(5)
            w.kill()
