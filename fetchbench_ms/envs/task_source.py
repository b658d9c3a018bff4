"""Where an env's tasks come from: the task source a set of env kwargs resolves to, and the
per-process caches of sampled tasks and of the furniture of loaded tasks.

``resolve_task_source`` turns the env's ``task_source`` / ``task_suite`` / ``object_split``
/ ``scene_type`` / ``category`` (and a curriculum's target labels and task count) into
the source, the loaded suite and the ids of the suite tasks a seed may pick, refusing
contradictions and empty subsets with a ``ValueError`` that names what is valid.
"""
from __future__ import annotations

import functools
import warnings
from typing import Optional

from ..tasks.sampler import SamplerConfig, sample_task
from ..tasks.spec import CATEGORY_LABELS, TaskSpec
from ..utils.io import canonical_json

#: Where seed-sampled tasks take their objects from. "train" by default, so an env made
#: for learning never shows a policy a test object; evaluation asks for "test" explicitly
#: (the eval runner does) or loads suite tasks, which carry their own objects.
OBJECT_SPLITS = ("train", "test")
DEFAULT_OBJECT_SPLIT = "train"
#: Where a seed's task comes from: "suite", a task of a filtered task suite (every one
#: passes the stable, visible and reachable filters), picked by the seed; "sampled", a
#: task sampled procedurally from the seed (unlimited, unfiltered).
TASK_SOURCES = ("suite", "sampled")
#: The suite seed resets draw from by default: the filtered train-split tasks.
DEFAULT_TASK_SUITE = "train"


def resolve_task_source(task_source: Optional[str], task_suite, object_split: str, scene_type: Optional[str],
                        category: Optional[str], curriculum=None):
    """(task source, loaded suite or None, ids of the suite tasks a seed may pick) for the
    env's kwargs; ValueErrors naming what is valid for contradictions and empty subsets.
    A ``curriculum`` (``envs.curriculum``) narrows the pool to its target labels and its
    first ``max_tasks``."""
    from ..tasks.suite import load_suite, shipped_suite_file, suites_dir

    defaulted = task_source is None and task_suite is None  # nothing asked for: the default suite
    if task_source is None:
        if task_suite is not None:
            task_source = "suite"
        elif object_split != DEFAULT_OBJECT_SPLIT:
            # Test objects: the default suite holds train objects only (evaluation on
            # test objects samples them, or names the test suite).
            task_source = "sampled"
        elif shipped_suite_file(DEFAULT_TASK_SUITE) is None:
            warnings.warn(f"the default task suite {DEFAULT_TASK_SUITE!r} is not shipped with this install "
                          f"({suites_dir()}); seed resets sample raw, unfiltered tasks (task_source='sampled'). "
                          "Give task_suite=NAME_OR_PATH for filtered tasks.", stacklevel=3)
            task_source = "sampled"
        else:
            task_source = "suite"
    if task_source == "sampled":
        if curriculum is not None and curriculum.max_tasks is not None:
            raise ValueError("curriculum max_tasks cuts a suite's task pool, but task_source='sampled'; valid: "
                             "task_source='suite', or leave max_tasks out")
        return task_source, (load_suite(task_suite) if task_suite is not None else None), None
    if task_suite is None:
        if object_split != DEFAULT_OBJECT_SPLIT:
            raise ValueError(f"object_split={object_split!r} with task_source='suite': the default suite "
                             f"{DEFAULT_TASK_SUITE!r} has {DEFAULT_OBJECT_SPLIT} objects only; valid: "
                             "task_suite='test' (filtered test tasks) or task_source='sampled'")
        task_suite = DEFAULT_TASK_SUITE
        if shipped_suite_file(DEFAULT_TASK_SUITE) is None:
            from ..tasks.suite import shipped_suites

            raise ValueError(f"task_source='suite' draws from the default task suite {DEFAULT_TASK_SUITE!r}, which is "
                             f"not shipped with this install ({suites_dir()}); valid: task_suite=one of "
                             f"{', '.join(shipped_suites()) or '(none shipped)'} or a suite file's path, "
                             "or task_source='sampled'")
    suite = load_suite(task_suite)
    labels = {CATEGORY_LABELS[category]} if category is not None else None
    if curriculum is not None and curriculum.target_labels is not None:
        labels = set(curriculum.target_labels) & labels if labels is not None else set(curriculum.target_labels)
    pool = [i for i, t in suite.tasks.items()
            if (scene_type is None or t.scene_type == scene_type) and (labels is None or t.target_label in labels)]
    if curriculum is not None and curriculum.max_tasks is not None:
        pool = pool[: curriculum.max_tasks]
    if not pool and defaulted and not suite.info.get("complete"):
        # A partial default suite (docs/suite.md, "State"): an id it does not cover yet
        # samples, as it would without the suite, and says so. A complete suite without the
        # subset raises below: no task of it exists.
        warnings.warn(f"the default task suite {suite.name!r} has no task yet for "
                      f"{scene_type or 'any scene type'}/{category or 'any category'} (it is partial: "
                      f"{suite.info.get('complete_scenes')} of {suite.info.get('planned_scenes')} scenes); seed resets "
                      "sample raw, unfiltered tasks (task_source='sampled')", stacklevel=3)
        return "sampled", None, None
    if not pool:
        curriculum_labels = sorted(labels or ()) if curriculum is not None and curriculum.target_labels else None
        what = " and ".join(f"{k} {v!r}" for k, v in (("scene type", scene_type), ("category", category),
                                                        ("target labels", curriculum_labels)) if v)
        types = sorted({t.scene_type for t in suite.tasks.values() if labels is None or t.target_label in labels})
        raise ValueError(f"task suite {suite.name!r} has no task for {what}; its tasks cover scene types "
                         f"{', '.join(types) or '(none)'}" + (f" for category {category!r}" if category else "")
                         + "; valid: another env id / suite, or task_source='sampled'")
    return task_source, suite, pool


@functools.lru_cache(maxsize=64)
def sample_task_cached(seed: int, scene_type: Optional[str], category: Optional[str],
                       config: SamplerConfig) -> TaskSpec:
    """``sample_task``, remembered: a seeded reset samples the task only to compare it with
    the loaded one, ``gym.make`` samples ManiSkill's start seed (2022) every time, and
    sampling (scene, placement, camera ray casts, settling) takes 0.1-4 s. The same
    arguments give the same task."""
    return sample_task(seed, scene_type=scene_type, category=category, config=config)


_SCENES: dict = {}  # (type, seed, params, hash) -> SceneSpec, the furniture of recently loaded tasks
_SCENES_KEPT = 64


def scene_of(task: TaskSpec):
    """``task.scene()``, remembered: the tasks of a suite share scenes, and regenerating
    one takes 10-100 ms. The key is everything ``task.scene()`` reads and checks (the
    generator's inputs and the stored content hash), so a cached scene was checked."""
    key = (task.scene_type, task.scene_seed, canonical_json(task.scene_params), task.scene_hash)
    spec = _SCENES.get(key)
    if spec is None:
        spec = task.scene()
        if len(_SCENES) >= _SCENES_KEPT:
            del _SCENES[next(iter(_SCENES))]
        _SCENES[key] = spec
    return spec


def curriculum_category(curriculum, category: Optional[str], task_source: Optional[str]) -> Optional[str]:
    """The category seed-sampled tasks are drawn with: the env's, or the curriculum's one
    target label; ValueError where the two contradict (``task_source``: the env's kwarg)."""
    labels = curriculum.target_labels if curriculum is not None else None
    if labels is None:
        return category
    if category is not None:
        if CATEGORY_LABELS[category] not in labels:
            raise ValueError(f"the env's category {category!r} ({CATEGORY_LABELS[category]}) is not among the "
                             f"curriculum's target_labels {list(labels)}; valid: target_labels including "
                             f"{CATEGORY_LABELS[category]!r}, or an env id of one of "
                             + ", ".join(c for c, lab in CATEGORY_LABELS.items() if lab in labels))
        return category
    if len(labels) == 1:
        return next(c for c, lab in CATEGORY_LABELS.items() if lab == labels[0])
    if task_source == "sampled":
        raise ValueError(f"a sampled task is drawn for one category, but the curriculum's target_labels are "
                         f"{list(labels)}; valid: one target label with task_source='sampled', or "
                         "task_source='suite'")
    return None


def tasks_from_options(options: dict, task_suite, num_envs: int) -> Optional[list[TaskSpec]]:
    """The tasks a reset's ``options`` give, one per sub-scene (``task``, ``tasks``, or
    ``task_id`` of ``task_suite`` with an optional ``task_hash``); None when they give none."""
    given = [k for k in ("task", "tasks", "task_id") if k in options]
    if len(given) > 1:
        raise ValueError(f"reset options give {', '.join(given)}; give only one of task, tasks, task_id")
    if not given:
        return None
    if "task_id" in options:
        if task_suite is None:
            raise ValueError("reset option task_id needs a task suite: make the env with task_suite=PATH")
        task = task_suite.get(options["task_id"])
        # Recorded demos name their task by id and content hash: a suite rebuilt since
        # (ids are positions in its stratified order) must not replay another task.
        if "task_hash" in options and task.content_hash()[: len(options["task_hash"])] != options["task_hash"]:
            raise ValueError(f"task {options['task_id']!r} of suite {task_suite.name!r} is not the task "
                             f"recorded (content hash {task.content_hash()[:16]} != {options['task_hash']}): the "
                             "suite changed since; regenerate the trajectories (docs/demos.md)")
        return [task] * num_envs
    if "task_hash" in options:
        raise ValueError("reset option task_hash goes with task_id (it checks the suite's task); valid: "
                         "task_id with an optional task_hash, task, or tasks")
    if "task" in options:
        task = options["task"]
        return [task if isinstance(task, TaskSpec) else TaskSpec.from_dict(task)] * num_envs
    tasks = options["tasks"]
    if not isinstance(tasks, (list, tuple)) or len(tasks) != num_envs:
        raise ValueError(f"reset option tasks must be a list of {num_envs} task dicts")
    return [t if isinstance(t, TaskSpec) else TaskSpec.from_dict(t) for t in tasks]
