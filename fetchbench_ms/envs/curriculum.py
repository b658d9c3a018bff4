"""Easier FetchBench tasks for reinforcement learning: the env's ``curriculum`` option.

A full FetchBench task (15 objects, targets deep in shelves, drawers and baskets, the
robot 0.5-0.8 m away) is far beyond what PPO learns in minutes. A ``Curriculum`` makes
the tasks an env serves easier, each step optional:

- ``target_labels``: only targets on these supports (e.g. ``("on_table",)``): the pool of
  suite tasks a seed picks from is cut to them (a sampled task gets the label as its
  category);
- ``max_tasks``: only the first N of that pool (suite order is stratified, so a prefix is
  a fair sample): fewer distinct tasks, and each is prepared once per process;
- ``num_objects``: keep the target and the ``num_objects - 1`` other objects nearest to
  it (the clutter that matters); every object was settled on its own support, so the
  rest stay at rest;
- ``base_advance``: move the robot base and its table up to this far (m) toward the target
  (in the floor plane, keeping the base's yaw), stopping 0.35 m short of it, at the
  largest advance (1 cm steps) where the robot table stays clear of the furniture and the
  arm at its start configuration clear of the world;
- ``pregrasp``: start the arm at a collision-free IK solution of a pre-grasp pose:
  ``pregrasp_distance`` back along the approach axis of one of the target's annotated
  grasps (the one whose solution is closest to the default start); a task without one
  keeps the default start.

Named presets (``CURRICULA``) or a dict of the fields are accepted::

    gym.make("FetchBench-v0", curriculum="table-near")
    gym.make("FetchBench-v0", curriculum=dict(num_objects=2, target_labels=["on_table"], pregrasp=True))

The changed task is an ordinary ``TaskSpec`` (``env.unwrapped.tasks``) marked in its
``extra["curriculum"]``; applying the same curriculum again returns it unchanged, so
recorded episodes replay, with the task or with the seed and the env kwargs.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import math
import sys
from dataclasses import dataclass, replace
from typing import Optional, Union

import numpy as np

from ..tasks.spec import CATEGORY_LABELS, TaskSpec
from ..utils.canonical import canonical_lengths
from ..utils.io import canonical_json

SUPPORT_LABELS = tuple(CATEGORY_LABELS.values())
CURRICULUM_VERSION = "1"  # bump when what a curriculum does to a task changes (the disk cache follows)
MIN_TARGET_DISTANCE = 0.35  # m, base to target in the floor plane, after an advance
MAX_BASE_ADVANCE = 0.4  # m
ADVANCE_STEP = 0.01  # m
PREGRASP_GRASPS = 12  # annotated grasps tried for a pre-grasp start (those whose open hand is clear)


@dataclass(frozen=True)
class Curriculum:
    """See the module docstring. Every field's default leaves the task as it is."""

    num_objects: Optional[int] = None
    target_labels: Optional[tuple[str, ...]] = None
    max_tasks: Optional[int] = None
    base_advance: float = 0.0  # m
    pregrasp: bool = False
    pregrasp_distance: float = 0.08  # m

    def __post_init__(self):
        if self.num_objects is not None and not (isinstance(self.num_objects, int) and 1 <= self.num_objects <= 64):
            raise ValueError(f"curriculum num_objects must be an int in 1..64 or None, got {self.num_objects!r}")
        if self.target_labels is not None:
            labels = (self.target_labels,) if isinstance(self.target_labels, str) else tuple(self.target_labels)
            unknown = [label for label in labels if label not in SUPPORT_LABELS]
            if unknown or not labels:
                raise ValueError(f"curriculum target_labels {list(labels)} has unknown labels {unknown}; valid: "
                                 f"a non-empty list of {', '.join(SUPPORT_LABELS)}")
            object.__setattr__(self, "target_labels", labels)
        if self.max_tasks is not None and not (isinstance(self.max_tasks, int) and self.max_tasks >= 1):
            raise ValueError(f"curriculum max_tasks must be an int >= 1 or None, got {self.max_tasks!r}")
        if not (isinstance(self.base_advance, (int, float)) and 0.0 <= self.base_advance <= MAX_BASE_ADVANCE):
            raise ValueError(f"curriculum base_advance must be in 0..{MAX_BASE_ADVANCE} m, got {self.base_advance!r}")
        if not isinstance(self.pregrasp, bool):
            raise ValueError(f"curriculum pregrasp must be True or False, got {self.pregrasp!r}")
        if not (isinstance(self.pregrasp_distance, (int, float)) and 0.02 <= self.pregrasp_distance <= 0.2):
            raise ValueError(f"curriculum pregrasp_distance must be in 0.02..0.2 m, got {self.pregrasp_distance!r}")

    def key(self) -> str:
        """What marks a task this curriculum made (its fields, canonical JSON)."""
        return canonical_json(dataclasses.asdict(self))

    def apply(self, task: TaskSpec) -> TaskSpec:
        """The task made easier (idempotent: a task this curriculum made comes back as is).
        Remembered in memory and on disk (``$FETCHBENCH_CACHE/curriculum``): the arm checks
        and the IK take 0.5-3 s a task, and every env process would repeat them."""
        if task.extra.get("curriculum") == self.key():
            return task
        return _apply_cached(self, task.content_hash(), _TaskBox(task))


#: Presets: what ``scripts/bench/bench_rl_env.py`` and ``baselines/ppo`` use (docs/rl.md).
CURRICULA = {
    # On-table targets among 3 other objects, the robot up to 15 cm closer, 32 tasks.
    "table-near": Curriculum(num_objects=4, target_labels=("on_table",), max_tasks=32, base_advance=0.15),
    # The same, the arm starting 5 cm behind a grasp of the target (the expert's
    # pre-grasp is 4 cm back), fingers open.
    "table-near-pregrasp": Curriculum(num_objects=4, target_labels=("on_table",), max_tasks=32, base_advance=0.15,
                                      pregrasp=True, pregrasp_distance=0.05),
}


def resolve_curriculum(value: Union[None, str, dict, Curriculum]) -> Optional[Curriculum]:
    """A ``Curriculum`` from the env kwarg: None, a preset name, a dict of fields or a Curriculum."""
    if value is None or isinstance(value, Curriculum):
        return value
    if isinstance(value, str):
        if value not in CURRICULA:
            raise ValueError(f"unknown curriculum {value!r}; valid: {', '.join(CURRICULA)}, or a dict of "
                             f"{', '.join(f.name for f in dataclasses.fields(Curriculum))}")
        return CURRICULA[value]
    if isinstance(value, dict):
        fields = {f.name for f in dataclasses.fields(Curriculum)}
        unknown = sorted(set(value) - fields)
        if unknown:
            raise ValueError(f"unknown curriculum fields {unknown}; valid: {', '.join(sorted(fields))}")
        return Curriculum(**value)
    raise ValueError(f"curriculum must be None, a preset name ({', '.join(CURRICULA)}) or a dict, got "
                     f"{type(value).__name__}")


class _TaskBox:
    """A task handed to the cache beside its hash (the hash is the cache key)."""

    def __init__(self, task: TaskSpec):
        self.task = task

    def __hash__(self):
        return 0

    def __eq__(self, other):
        return True


@functools.lru_cache(maxsize=512)
def _apply_cached(curriculum: Curriculum, task_hash: str, box: _TaskBox) -> TaskSpec:
    """The curriculum's task for the task of content hash ``task_hash``: from the disk
    cache, else made and stored there (written atomically: parallel workers may race)."""
    from ..objects.loading import object_source
    from ..utils.io import atomic_write_text, sha256_bytes
    from ..utils.mesh_cache import cache_dir

    key = sha256_bytes(f"{CURRICULUM_VERSION}|{curriculum.key()}|{task_hash}|{object_source()}".encode())[:32]
    path = cache_dir() / "curriculum" / f"{key}.json"
    if path.exists():
        try:
            return TaskSpec.from_dict(json.loads(path.read_text()))
        except (ValueError, KeyError, json.JSONDecodeError):  # a damaged record: make it again
            pass
    task = _make_easier(curriculum, box.task)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(task.to_dict()))
    return task


def _make_easier(curriculum: Curriculum, task: TaskSpec) -> TaskSpec:
    if curriculum.num_objects is not None:
        task = _keep_nearest_objects(task, curriculum.num_objects)
    info = {}
    if curriculum.base_advance > 0:
        task, info["base_advance"] = _advance_base(task, curriculum.base_advance)
    if curriculum.pregrasp:
        q = _pregrasp_qpos(task, curriculum.pregrasp_distance)
        info["pregrasp"] = q is not None
        if q is not None:
            task = replace(task, robot_init_qpos=tuple(float(v) for v in q) + task.robot_init_qpos[7:])
    return replace(task, extra={**task.extra, "curriculum": curriculum.key(), "curriculum_info": info})


def _keep_nearest_objects(task: TaskSpec, n: int) -> TaskSpec:
    target = np.asarray(task.target.position)
    others = [k for k in range(len(task.objects)) if k != task.target_index]
    others.sort(key=lambda k: float(np.linalg.norm(np.asarray(task.objects[k].position) - target)))
    keep = sorted([task.target_index] + others[: n - 1])
    return replace(task, objects=tuple(task.objects[k] for k in keep), target_index=keep.index(task.target_index))


def _moved(task: TaskSpec, offset_xy: np.ndarray) -> TaskSpec:
    offset = np.array([offset_xy[0], offset_xy[1], 0.0])
    return replace(task, robot_base_position=canonical_lengths(np.asarray(task.robot_base_position) + offset),
                   robot_table_center=canonical_lengths(np.asarray(task.robot_table_center) + offset))


def _arm_clear(task: TaskSpec, q7) -> bool:
    """The arm at ``q7`` (fingers open) is clear of the task's world, target included."""
    from ..planning.checker import CollisionChecker
    from ..planning.robot import panda
    from ..planning.world_models import task_mesh_world

    T_base_world = np.linalg.inv(task.T_world_base())
    world = task_mesh_world(task, T_base_world, [T_base_world @ o.transform() for o in task.objects])
    return bool(CollisionChecker(panda(), world).valid(np.asarray(q7, float)[None])[0])


def _advance_base(task: TaskSpec, advance: float) -> tuple[TaskSpec, float]:
    """(the task with base and robot table moved toward the target, the advance in m)."""
    from ..tasks.sampler import _BoxWorld, _rot_z

    base = np.asarray(task.robot_base_position)
    to_target = np.asarray(task.target.position)[:2] - base[:2]
    distance = float(np.linalg.norm(to_target))
    most = min(advance, distance - MIN_TARGET_DISTANCE)
    if most <= 0:
        return task, 0.0
    direction = to_target / distance
    furniture = _BoxWorld(task.scene())
    q = task.robot_init_qpos
    yaw = 2 * math.atan2(task.robot_base_quat_wxyz[3], task.robot_base_quat_wxyz[0])
    for d in np.arange(round(most / ADVANCE_STEP), 0, -1) * ADVANCE_STEP:
        moved = _moved(task, direction * d)
        table = _BoxWorld.box(moved.robot_table_size, _rot_z(yaw), moved.robot_table_center)
        if not furniture.hits(table) and _arm_clear(moved, q[:7]):
            return moved, round(float(d), 3)
    return task, 0.0


def _pregrasp_qpos(task: TaskSpec, distance: float) -> Optional[np.ndarray]:
    """A collision-free arm configuration (7,) with the TCP ``distance`` back from one of
    the target's annotated grasps, closest to the task's start configuration; None if none."""
    from ..grasp_labels.candidates import object_grasps, retreat, tcp_from_hand
    from ..planning.checker import CollisionChecker
    from ..planning.ik import solve_ik
    from ..planning.robot import panda
    from ..planning.world_models import task_mesh_world

    T_base_world = np.linalg.inv(task.T_world_base())
    T_base_objects = [T_base_world @ o.transform() for o in task.objects]
    checker = CollisionChecker(panda(), task_mesh_world(task, T_base_world, T_base_objects))
    T_tcp = retreat(tcp_from_hand(T_base_objects[task.target_index][None] @ object_grasps(task.target.object_id).T_object_hand),
                    distance)
    free = np.flatnonzero(checker.hand_clearance(T_tcp @ np.linalg.inv(tcp_from_hand(np.eye(4)))) > 0)[:PREGRASP_GRASPS]
    if len(free) == 0:
        return None
    q_start = np.asarray(task.robot_init_qpos[:7], float)
    result = solve_ik(panda(), T_tcp[free], checker=checker, q_seed=q_start, n_seeds=2,
                      rng=np.random.default_rng(int(task.content_hash()[:8], 16)))
    if not result.found:
        return None
    return result.q[int(np.argmin(np.linalg.norm(result.q - q_start, axis=1)))]


def curriculum_pool(env_id: str, curriculum, task_suite: Optional[str] = None) -> list[TaskSpec]:
    """The suite tasks an env ``env_id`` with this curriculum serves (before the curriculum
    is applied to them)."""
    from .env_ids import ENV_KWARGS
    from .task_source import resolve_task_source

    fixed = ENV_KWARGS[env_id]
    _, suite, pool = resolve_task_source("suite", task_suite, "train", fixed.get("scene_type"),
                                         fixed.get("category"), resolve_curriculum(curriculum))
    return [suite.get(i) for i in pool]


def _apply_one(args) -> str:
    curriculum, task = args
    return curriculum.apply(task).content_hash()


def _one_thread() -> None:
    import torch

    torch.set_num_threads(1)  # one process per core: torch's pool would oversubscribe them


def prepare(env_id: str, curriculum, task_suite: Optional[str] = None, processes: int = 1,
            progress: bool = True) -> int:
    """Make (into the disk cache) the curriculum's version of every task its env serves,
    on ``processes`` processes: run before starting many env workers, which then read
    them instead of each making them. Returns the number of tasks. ``progress``: a bar on
    stderr (minutes of IK on a small machine the first time; cached tasks pass at once)."""
    import multiprocessing

    from tqdm import tqdm

    curriculum = resolve_curriculum(curriculum)
    jobs = [(curriculum, t) for t in curriculum_pool(env_id, curriculum, task_suite)]
    bar = tqdm(total=len(jobs), desc=f"curriculum tasks of suite {task_suite or 'train'}",
               unit="task", disable=not progress, file=sys.stderr)
    try:
        if processes <= 1:
            for job in jobs:
                _apply_one(job)
                bar.update()
        else:
            with multiprocessing.get_context("spawn").Pool(processes, initializer=_one_thread) as pool:
                for _ in pool.imap_unordered(_apply_one, jobs, chunksize=1):
                    bar.update()
    finally:
        bar.close()
    return len(jobs)


__all__ = ["CURRICULA", "Curriculum", "curriculum_pool", "prepare", "resolve_curriculum"]
