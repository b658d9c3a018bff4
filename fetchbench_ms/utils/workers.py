"""Worker processes that share the cores, each with one-thread OpenMP / BLAS pools."""
from __future__ import annotations

import os
from contextlib import contextmanager

# The thread pools (OpenMP, BLAS) a worker may start: each worker is one of ``workers``
# processes that already share the cores, so one thread each. Without this, 16 render workers
# on a 16-core node (torch 2.11) ran 69 threads each, the load rose to 195 and a 64-demo chunk
# had not rendered after 5 minutes; with it, 47 s.
WORKER_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


@contextmanager
def one_thread_per_spawned_worker():
    """Processes spawned inside get one-thread pools (the variables are read at their import of
    numpy / torch, so they must be in the environment they inherit); this process's own
    environment is restored on exit. A variable the caller set is kept."""
    saved = {k: os.environ.get(k) for k in WORKER_THREAD_VARS}
    for k in WORKER_THREAD_VARS:
        os.environ.setdefault(k, "1")
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
