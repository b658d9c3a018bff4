"""Compact point clouds of recorded env states, rendered without physics.

``scripts/imitation/convert_demos_for_imitation.py --frame-stride K`` replays its demos state-only
(``-o state``: ManiSkill's recorder still stores every step's env state) and renders the
frames it keeps only: per trajectory, the env is reset as the replay reset it (the same task),
and for each kept step its recorded env state is set and the cameras render it.

``get_obs`` after ``set_state_dict`` is a fresh observation: ManiSkill's
``_get_obs_sensor_data`` moves the renderer's bodies to the simulation's poses
(``scene.update_render``) and captures the cameras at every call. The compact cloud's voxel
draw is seeded by the episode seed and the env's step count (``envs.pointcloud.compact_seed``),
which a state set leaves at 0; so the env renders the raw ``pointcloud`` and the cloud is made
compact here with the seed of the step it shows, as the env makes it when it has stepped there.

The clouds are those a replay renders at the same steps, but not to the bit: after a state set
the Panda's link poses come from its kinematics, ~1e-8 m from the poses the simulation's step
left, and that moves a handful of a frame's 153,600 camera points (by ~1 mm, or an edge pixel
onto another surface; measured on the demo sample, tests/test_imitation.py). Where such a
point changes a segment's number of occupied voxels, the compact cloud's draw of that segment
is another draw of the same surfaces: on the sample's first steps, 7 of 39 segments of the
kept frames (the robot's mostly); the others are the replay's to the bit.
"""
from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .envs.pointcloud import COMPACT_OBS_MODE, POINTS_OBS_MODES, compact_pointcloud_obs, compact_seed
from .utils.workers import WORKER_THREAD_VARS, one_thread_per_spawned_worker


@dataclass
class RenderJob:
    """The steps of one recorded trajectory whose clouds are wanted."""

    reset_kwargs: dict  # as the trajectory's JSON records them (seed, options: the task)
    episode_seed: int
    steps: np.ndarray  # [F] step numbers t (obs[t] of a trajectory is taken at env_states[t])
    states: dict  # those steps' env states: ManiSkill's nested dict of [F, ...] arrays


def render_env_kwargs(env_kwargs: dict, obs_mode: str = "pointcloud") -> dict:
    """The recorded env kwargs with ``obs_mode`` (the raw point-cloud one by default); a recording
    made without a renderer (``render_backend="none"``) gets ManiSkill's default one, as the
    replay tool gives it."""
    kwargs = {k: v for k, v in env_kwargs.items() if k != "render_backend" or v not in (None, "none")}
    kwargs["obs_mode"] = obs_mode
    return kwargs


class StateRenderer:
    """One env of ``env_id`` that renders recorded env states into compact clouds, or, with
    with ``obs_mode="policy_pointcloud"`` or ``"composed_pointcloud"`` (``POINTS_OBS_MODES``), into
    the policies' points by that obs mode itself (the composed one renders once, at the reset)."""

    def __init__(self, env_id: str, env_kwargs: dict, obs_mode: str = COMPACT_OBS_MODE):
        import gymnasium as gym

        import fetchbench_ms  # noqa: F401  (registers FetchBench-*-v0, also in a spawned worker)

        if obs_mode not in (COMPACT_OBS_MODE, *POINTS_OBS_MODES):
            raise ValueError(f"unknown obs mode {obs_mode!r} to render states in; valid: "
                             f"{', '.join((COMPACT_OBS_MODE, *POINTS_OBS_MODES))}")
        self.obs_mode = obs_mode
        self.seconds = {"reset": 0.0, "frames": 0.0}  # spent in render(), summed
        self.env = gym.make(env_id, **render_env_kwargs(env_kwargs, "pointcloud" if obs_mode == COMPACT_OBS_MODE
                                                        else obs_mode))

    def observation(self, state: dict, step: int = 0) -> dict:
        """The env's observation of one env state (ManiSkill's nested dict of [1, ...] arrays) of
        the task the env was last reset to, as the env makes it at control step ``step`` (its
        step counter, which seeds the point draws, is set to it: a state set leaves it alone)."""
        env = self.env.unwrapped
        env.set_state_dict(state)
        env._elapsed_steps[:] = step
        return env.get_obs()

    def render(self, job: RenderJob) -> tuple[np.ndarray, np.ndarray]:
        """(xyz [F, M, 3] float16, seg [F, M] uint8): the compact cloud of each of the job's steps;
        for the ``POINTS_OBS_MODES``, the obs mode's points and labels ([F, N, 3], [F, N]). The
        seconds of its reset and of its frames are added to ``seconds``."""
        from mani_skill.trajectory.utils import index_dict
        from mani_skill.utils import common

        t0 = time.perf_counter()
        self.env.reset(**job.reset_kwargs)  # (the same task as the last one: no new scene is built)
        t1 = time.perf_counter()
        xyz, seg = [], []
        for i, step in enumerate(job.steps):
            obs = self.observation(index_dict(job.states, slice(i, i + 1)), int(step))
            if self.obs_mode in POINTS_OBS_MODES:
                cloud = {"xyz": obs["pointcloud"]["points"], "seg": obs["pointcloud"]["point_label"]}
            else:
                cloud = compact_pointcloud_obs(obs, [compact_seed(job.episode_seed, int(step))])["pointcloud"]
            xyz.append(common.to_numpy(cloud["xyz"])[0])
            seg.append(common.to_numpy(cloud["seg"])[0])
        self.seconds["reset"] += t1 - t0
        self.seconds["frames"] += time.perf_counter() - t1
        return np.stack(xyz), np.stack(seg)

    def close(self) -> None:
        self.env.close()


_worker_renderer: StateRenderer | None = None  # a worker process's env


def render_backends(gpus: int) -> list[str] | None:
    """The render backends workers take in turn: ``cuda:0`` .. ``cuda:{gpus - 1}`` for
    ``gpus`` > 1 (a machine's GPUs share the render workers), None for ManiSkill's default."""
    if gpus < 1:
        raise ValueError(f"render GPUs must be >= 1, got {gpus}")
    return [f"cuda:{i}" for i in range(gpus)] if gpus > 1 else None


def _with_backend(env_kwargs: dict, backend: str | None) -> dict:
    return env_kwargs if backend is None else {**env_kwargs, "render_backend": backend}


def _start_worker(env_id: str, env_kwargs: dict, obs_mode: str, backends: list[str] | None, slots) -> None:
    global _worker_renderer
    import torch

    torch.set_num_threads(1)  # (see WORKER_THREAD_VARS)
    backend = None if backends is None else backends[slots.get() % len(backends)]
    _worker_renderer = StateRenderer(env_id, _with_backend(env_kwargs, backend), obs_mode)


def _render_group(renderer: StateRenderer, jobs: list[RenderJob]) -> tuple[list, dict]:
    """The clouds of jobs of one task, one after the other in one env, and the seconds spent."""
    before = dict(renderer.seconds)
    clouds = [renderer.render(job) for job in jobs]
    return clouds, {k: renderer.seconds[k] - before[k] for k in before}


def _render_group_in_worker(jobs: list[RenderJob]) -> tuple[list, dict]:
    return _render_group(_worker_renderer, jobs)


def task_groups(jobs: list[RenderJob]) -> list[list[RenderJob]]:
    """Consecutive jobs of the same reset (one task's demos, as demo files hold them) as one group:
    a worker renders a group in one env, which then builds the task's scene once."""
    groups: list[list[RenderJob]] = []
    for job in jobs:
        if groups and groups[-1][0].reset_kwargs == job.reset_kwargs:
            groups[-1].append(job)
        else:
            groups.append([job])
    return groups


class StateRenderPool:
    """``workers`` processes with an env each that render ``RenderJob``s, started once and kept
    for every batch of jobs given to ``imap`` (a conversion of many chunks pays each worker's
    start, ~5 s of imports, suite and renderer, once); 1 renders in this process.
    ``backends`` (``render_backends``): worker i renders on backends[i % n]. Use as a context
    manager: the workers end with it."""

    def __init__(self, env_id: str, env_kwargs: dict, workers: int = 1, obs_mode: str = COMPACT_OBS_MODE,
                 backends: list[str] | None = None):
        self.renderer, self.pool, self.workers = None, None, max(workers, 1)
        self.seconds = {"reset": 0.0, "frames": 0.0}  # the workers' time in render(), summed
        if workers <= 1:
            self.renderer = StateRenderer(env_id, _with_backend(env_kwargs, backends and backends[0]), obs_mode)
            return
        # Spawned, as ManiSkill's replay tool starts its workers (warp does not survive a fork).
        context = mp.get_context("spawn")
        slots = context.Queue()  # each worker takes its index, and with it its render backend
        for i in range(workers):
            slots.put(i)
        with one_thread_per_spawned_worker():
            self.pool = context.Pool(workers, _start_worker, (env_id, env_kwargs, obs_mode, backends, slots))

    def imap(self, jobs: list[RenderJob]) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """The clouds of every job, job by job in order; the jobs of one task (``task_groups``) go
        to one worker, whichever is free. The workers' seconds add up in ``seconds``."""
        groups = task_groups(jobs)
        results = (_render_group(self.renderer, group) for group in groups) if self.pool is None \
            else self.pool.imap(_render_group_in_worker, groups)
        for clouds, seconds in results:
            for key, value in seconds.items():
                self.seconds[key] += value
            yield from clouds

    def close(self) -> None:
        if self.pool is not None:
            self.pool.terminate()
            self.pool.join()
        if self.renderer is not None:
            self.renderer.close()

    def __enter__(self) -> "StateRenderPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def render_compact_clouds(env_id: str, env_kwargs: dict, jobs: list[RenderJob], workers: int = 1,
                          obs_mode: str = COMPACT_OBS_MODE,
                          backends: list[str] | None = None) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """The clouds of every job (``StateRenderer.render`` in ``obs_mode``), job by job in order,
    from a ``StateRenderPool`` of ``min(workers, len(jobs))`` processes started for them."""
    with StateRenderPool(env_id, env_kwargs, min(workers, len(jobs)), obs_mode, backends) as pool:
        yield from pool.imap(jobs)
