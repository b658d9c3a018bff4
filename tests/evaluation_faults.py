"""Test methods for the evaluation runner (``tests.evaluation_faults:method`` style specs).

``faulty`` behaves per task seed as ``FETCHBENCH_TEST_FAULTS`` (JSON ``{seed: behaviour}``,
inherited by the worker processes) says: ``raise``, ``hang`` (sleeps far past any limit),
``crash`` (the process dies at once, as on a segfault); other tasks return a cheap
deterministic failed record without simulating. ``FETCHBENCH_TEST_SLOW_ENV`` (seconds)
delays each task's env (``TaskRunner.env``, before the reset and the method) by that much,
as a slow env build on a loaded machine would (the workers import this module to find the
method, and so get the delay).
"""
from __future__ import annotations

import json
import os
import time

from fetchbench_ms.evaluation.methods import TaskRunner

_make_env = TaskRunner.env


def _slow_env(self, env_id: str):
    time.sleep(float(os.environ.get("FETCHBENCH_TEST_SLOW_ENV", 0)))
    return _make_env(self, env_id)


TaskRunner.env = _slow_env


def faulty(env, seed):
    behaviour = json.loads(os.environ.get("FETCHBENCH_TEST_FAULTS", "{}")).get(str(seed))
    if behaviour == "raise":
        raise RuntimeError(f"injected failure for seed {seed}")
    if behaviour == "hang":
        time.sleep(3600)
    if behaviour == "crash":
        os._exit(11)
    return {"success": False, "failure": "not_attempted", "computation_time": 0.0, "cspace_length": 0.0,
            "phases": {}}


def wiggle(env, seed):
    """Steps the arm's controller 16 times (holding its joint targets), then fails."""
    import numpy as np

    u = env.unwrapped
    q = u.agent.robot.get_qpos()[0].cpu().numpy()[:7]
    for _ in range(16):
        u._step_action(np.concatenate([q, [1.0]]).astype(np.float32))
    return {"success": False, "failure": "not_attempted", "computation_time": 0.0, "cspace_length": 0.0,
            "phases": {}}


def numpy_record(env, seed):
    """A record with numpy values (converted) and, for odd seeds, no ``success`` (an error)."""
    import numpy as np

    if seed % 2:
        return {"failure": "not_attempted"}
    return {"success": np.bool_(False), "failure": "not_attempted", "computation_time": np.float32(0.5),
            "cspace_length": np.float64(1.5), "phases": {"ik_found": np.bool_(True)}}


def slow_steps(env, seed):
    """Steps the env (holding the arm's joint targets) for 9 s of wall time, then fails: a
    long task, whose worker reports its control steps while it runs."""
    import numpy as np

    u = env.unwrapped
    q = u.agent.robot.get_qpos()[0].cpu().numpy()[:7]
    action = np.concatenate([q, [0.04]]).astype(np.float32)
    end = time.monotonic() + 9.0
    while time.monotonic() < end:
        env.step(action)
    return {"success": False, "failure": "not_attempted", "computation_time": 0.0, "cspace_length": 0.0,
            "phases": {}}
