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

from .methods import RunnerSpec, WorkItem, error_record

READY = "ready"
STARTUP_TIMEOUT = 300.0  # s for a worker to import everything and say it is ready


def _die_with_parent() -> None:
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except OSError:  # not Linux: orphans exit when they read the closed pipe
        pass


def worker_main(conn, spec: RunnerSpec, parent_pid: int) -> None:
    _die_with_parent()
    if os.getppid() != parent_pid:  # the parent died before the death signal was armed
        return
    # One core per worker: many workers share the machine, threads would fight.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    runner = spec.make()
    conn.send(READY)
    while True:
        try:
            item = conn.recv()
        except (EOFError, OSError):
            break
        if item is None:
            break
        conn.send(runner(item))
    runner.close()


class _Worker:
    def __init__(self, ctx, spec: RunnerSpec):
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=worker_main, args=(child, spec, os.getpid()), daemon=True)
        self.proc.start()
        child.close()
        self.ready = False
        self.started = time.monotonic()
        self.item: WorkItem | None = None

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        self.conn.close()


def _deadline(worker: _Worker, task_timeout: float) -> float:
    return worker.started + (task_timeout if worker.ready else STARTUP_TIMEOUT)


def run_local(spec: RunnerSpec, items: Iterable[WorkItem], on_record: Callable[[dict], None], workers: int = 1,
              task_timeout: float = 600.0) -> None:
    """Run every item; ``on_record`` gets each task's record (in the parent) as it finishes."""
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
                    w.item, w.started = queue.popleft(), now
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
                        record = error_record(w.item, "timeout", f"ran past the task time limit of {task_timeout:g} s")
                    else:
                        w.proc.join(5)  # its pipe closes a moment before it can be reaped
                        record = error_record(w.item, "crash", f"the worker process died "
                                                                f"(exit code {w.proc.exitcode})")
                    record.update(method=spec.method, wall_time=round(time.monotonic() - w.started, 2))
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
