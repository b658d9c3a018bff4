"""Time parametrisation of a joint-space waypoint path into position targets.

Each straight segment gets a synchronised trapezoidal velocity profile that starts and
ends at rest, within per-joint velocity and acceleration limits. Why not toppra (which
is installed): it needs a smooth spline through the waypoints, and a spline leaves the
straight segments the planner checked for collisions; stopping at each (few, after
simplification) waypoint keeps the executed motion exactly on the checked path.
"""
from __future__ import annotations

import numpy as np


def segment_profile(delta: np.ndarray, v_max: np.ndarray, a_max: np.ndarray) -> tuple[float, float, float]:
    """(duration, peak path speed, path acceleration) for s in [0, 1] along ``delta``."""
    moving = np.abs(delta) > 1e-12
    if not moving.any():
        return 0.0, 0.0, 0.0
    V = float(np.min(v_max[moving] / np.abs(delta[moving])))
    A = float(np.min(a_max[moving] / np.abs(delta[moving])))
    if V * V / A >= 1.0:  # never reaches V: triangular profile
        t_acc = np.sqrt(1.0 / A)
        return 2 * t_acc, A * t_acc, A
    return 1.0 / V + V / A, V, A


def _s_at(t: np.ndarray, duration: float, V: float, A: float) -> np.ndarray:
    t_acc = V / A
    s = np.where(t < t_acc, 0.5 * A * t ** 2,
                 np.where(t <= duration - t_acc, 0.5 * A * t_acc ** 2 + V * (t - t_acc),
                          1.0 - 0.5 * A * np.clip(duration - t, 0, None) ** 2))
    return np.clip(s, 0.0, 1.0)


def time_parametrize(path: np.ndarray, dt: float, v_max: np.ndarray, a_max: np.ndarray,
                     speed_scale: float = 1.0) -> np.ndarray:
    """Joint positions sampled every ``dt`` s along ``path`` (N, D); the last sample is the goal.

    ``speed_scale`` (0, 1] scales both limits (velocity linearly, acceleration squared).
    """
    if not 0 < speed_scale <= 1:
        raise ValueError(f"speed_scale must be in (0, 1], got {speed_scale}")
    path = np.asarray(path, dtype=float)
    v_max = np.asarray(v_max, float) * speed_scale
    a_max = np.asarray(a_max, float) * speed_scale ** 2
    segments = []
    for a, b in zip(path[:-1], path[1:]):
        duration, V, A = segment_profile(b - a, v_max, a_max)
        if duration > 0:
            segments.append((a, b, duration, V, A))
    if not segments:
        return path[-1:].copy()
    ends = np.cumsum([s[2] for s in segments])
    times = np.arange(dt, ends[-1] + dt - 1e-9, dt)
    out = np.empty((len(times), path.shape[1]))
    seg_idx = np.minimum(np.searchsorted(ends, times - 1e-12), len(segments) - 1)
    for k, (a, b, duration, V, A) in enumerate(segments):
        mask = seg_idx == k
        t_local = times[mask] - (ends[k] - duration)
        out[mask] = a + _s_at(np.clip(t_local, 0, duration), duration, V, A)[:, None] * (b - a)
    out[-1] = path[-1]
    return out
