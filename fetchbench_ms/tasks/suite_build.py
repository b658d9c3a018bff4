"""Generate FetchBench task suites: scenes -> object arrangements -> filtered tasks.

The ``test`` suite follows the paper's appendix table: 100 scenes with the paper's
per-type counts, 60 tasks each, and per scene type the paper's per-category task counts
(``PAPER_TABLE``), split over the type's scenes by largest remainder. ``val`` is the
same recipe at a smaller size on *train* objects; unlimited train tasks come from
``sample_task(seed, config=SamplerConfig(object_split="train"))``.

Per scene (seeded by (suite seed, scene index) alone, so a scene's result does not
depend on which worker made it or in which order):
1. the furniture from its scene seed;
2. arrangement after arrangement (``sampler`` places ~15 objects, robot, cameras,
   settles them), each judged by the three filters (``tasks.filters``); an object that
   passes becomes a task if its category still has quota in this scene. This is how the
   category mix is met: the per-scene quotas decide which passing objects become tasks,
   and the placement's label weights (the original's, plus extra weight on the
   categories still short, ``placement_weights``) put more objects where tasks are
   still needed, so a DrawerShelf fills its in-drawer quota without hundreds of
   arrangements;
3. a scene stops at its quota or after ``max_arrangements``; a category that still lacks
   tasks then is filled from the other categories' passing objects (recorded in the
   scene result as ``shortfall``);
4. a scene that by then has fewer passing objects than tasks goes on (the *fill*
   phase, up to ``fill_arrangements``): arrangements are sampled as the original does
   (its label weights; no lean to the missing categories, no fitting, cameras unweighted:
   in a LayerShelf whose baskets the lean could not fill in 160 arrangements, leaning on
   found 8 tasks in 136 more, the original's weights 4 in 20), every stable, visible
   object is IK-checked and every passing one counts, until the scene has its task
   count. Scenes that met their count within ``max_arrangements`` are untouched by it,
   so raising the fill budget continues only the short scenes, from their results.
Per-scene results are written atomically to a work directory and skipped on re-run
(resumable); the suite file is assembled from them in a fixed order, so it is
byte-identical for the same seed whatever the worker count.

Suite order: tasks are grouped in strata (scene type x category); the j-th of n_s tasks
of stratum s sits at position (j + 1/2) / n_s, and the suite is sorted by position
(ties by stratum), so every prefix holds each stratum in proportion to its size.
"""
from __future__ import annotations

import json
import os
import time
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..utils.io import atomic_write_text, canonical_json
from .spec import TaskSpec
from .suite import TaskSuite

BUILD_VERSION = "6"  # 6: catalog v2 + sampler v4 (machine-independent poses); 5: CellShelfDesk boxes pulled out of bottom-row cells; 160 arrangements; 4: sampler v3
CATEGORY_ORDER = ("on_table", "on_shelf", "in_drawer", "in_basket")
#: The paper's appendix table (test tasks): scenes, then tasks per category, per scene type.
#: (The paper's Total row swaps the drawer and basket columns; the rows add up to
#: in-drawer 859 and in-basket 891, as its text says.)
PAPER_TABLE = {
    "CellShelfDesk": (10, {"on_table": 265, "on_shelf": 235, "in_drawer": 0, "in_basket": 100}),
    "Desk": (6, {"on_table": 360, "on_shelf": 0, "in_drawer": 0, "in_basket": 0}),
    "DeskWall": (7, {"on_table": 255, "on_shelf": 165, "in_drawer": 0, "in_basket": 0}),
    "DoubleDoorCabinet": (6, {"on_table": 0, "on_shelf": 353, "in_drawer": 0, "in_basket": 7}),
    "Drawer": (6, {"on_table": 0, "on_shelf": 0, "in_drawer": 360, "in_basket": 0}),
    "DrawerShelf": (10, {"on_table": 0, "on_shelf": 48, "in_drawer": 499, "in_basket": 53}),
    "EketShelf": (5, {"on_table": 0, "on_shelf": 300, "in_drawer": 0, "in_basket": 0}),
    "LargeShelf": (10, {"on_table": 0, "on_shelf": 481, "in_drawer": 0, "in_basket": 119}),
    "LargeShelfDesk": (9, {"on_table": 208, "on_shelf": 266, "in_drawer": 0, "in_basket": 66}),
    "LayerShelf": (10, {"on_table": 0, "on_shelf": 362, "in_drawer": 0, "in_basket": 238}),
    "RoundTable": (9, {"on_table": 237, "on_shelf": 0, "in_drawer": 0, "in_basket": 303}),
    "SingleDoorCabinetDesk": (7, {"on_table": 201, "on_shelf": 214, "in_drawer": 0, "in_basket": 5}),
    "TriangleShelfDesk": (5, {"on_table": 0, "on_shelf": 300, "in_drawer": 0, "in_basket": 0}),
}
#: Where the plan departs from the paper's per-type split. In LayerShelf and LargeShelf,
#: baskets on low or high boards are rarely both visible and reachable (build version 5 met
#: about 140 of LayerShelf's 238 and 79 of LargeShelf's 119; their scenes fill the shortfall
#: with shelf tasks), while RoundTable's baskets fill readily. So RoundTable takes basket
#: tasks in place of table tasks, and DeskWall table tasks in place of shelf tasks: the
#: suite's category totals then land within 10% of the paper's (``suite stats`` checks them
#: against the paper's, not against this plan). Every type keeps its scenes and task count.
PLAN_SHIFTS = {
    "RoundTable": {"on_table": -135, "in_basket": +135},
    "DeskWall": {"on_table": +135, "on_shelf": -135},
}
TASKS_PER_SCENE = 60
NEED_BOOST = 2.0  # weight spread over the still-needed categories, on top of the original's (sum 1.3)
#: Labels whose objects are chosen to fit and turned along the surface when the scene needs
#: them (small, walled supports where a random object and yaw rarely fit).
FIT_LABELS = ("in_drawer", "in_basket")
CAMERA_NEED_BOOST = 2.0  # camera score weight: 1 per label plus this x the label's share of the need


@dataclass(frozen=True)
class SuiteRecipe:
    """What a suite is made of. ``scale`` < 1 shrinks every scene count (at least one
    scene per type) for val or quick builds; ``tasks_per_scene`` shrinks the quotas."""

    name: str = "test"
    object_split: str = "test"
    seed: int = 0
    scale: float = 1.0
    tasks_per_scene: int = TASKS_PER_SCENE
    max_arrangements: int = 160  # arrangements tried per scene before giving up on its quota
    num_objects: int = 15
    #: Arrangements a scene short of its task count may try in all (the fill phase; None:
    #: no fill). Left out of a scene result's identity: a result made with a smaller fill
    #: budget is continued, not remade.
    fill_arrangements: int | None = None

    def __post_init__(self):
        if self.object_split not in ("train", "test"):
            raise ValueError(f"unknown object split {self.object_split!r}; valid: train, test")
        if not 0 < self.scale <= 1:
            raise ValueError(f"scale must be in (0, 1], got {self.scale}")
        if self.tasks_per_scene < 1:
            raise ValueError(f"tasks_per_scene must be positive, got {self.tasks_per_scene}")
        if self.fill_arrangements is not None and self.fill_arrangements < self.max_arrangements:
            raise ValueError(f"fill_arrangements ({self.fill_arrangements}) must be at least "
                             f"max_arrangements ({self.max_arrangements}), or None for no fill")

    @property
    def arrangement_budget(self) -> int:
        """The most arrangements any scene tries (quota phase plus fill phase)."""
        return self.max_arrangements if self.fill_arrangements is None else self.fill_arrangements

    def to_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def _recipe_identity(recipe_dict: dict) -> dict:
    """What a scene's result depends on besides its plan: the recipe without its fill budget
    (a short scene's result for a smaller budget is where a larger budget's build passes)."""
    return {k: v for k, v in recipe_dict.items() if k != "fill_arrangements"}


#: ``test`` is the benchmark (test-split objects). ``train`` and ``val`` hold train-split
#: objects only, with the same filters and the same scene-type and category mix: ``train``
#: for demonstrations and learning (as large as ``test``), ``val`` for choosing
#: hyper-parameters (a tenth of it, over 19 scenes so every type has one or two). The paper
#: tunes every method on validation tasks of the train split; nothing here looks at test.
RECIPES = {
    "test": SuiteRecipe("test", "test", seed=0, fill_arrangements=400),
    "train": SuiteRecipe("train", "train", seed=2, fill_arrangements=400),
    "val": SuiteRecipe("val", "train", seed=1, scale=0.2, tasks_per_scene=32, fill_arrangements=400),
}


def recipe(name: str) -> SuiteRecipe:
    if name not in RECIPES:
        raise ValueError(f"unknown suite recipe {name!r}; valid: {', '.join(RECIPES)}")
    return RECIPES[name]


# ----------------------------------------------------------------------------- plan
@dataclass(frozen=True)
class ScenePlan:
    index: int  # position in the suite's scene list (generation order)
    scene_type: str
    scene_seed: int
    quota: dict  # category label -> tasks wanted


def _largest_remainder(total: int, weights) -> list[int]:
    weights = np.asarray(weights, dtype=float)
    if weights.sum() <= 0:
        return [0] * len(weights)
    exact = total * weights / weights.sum()
    counts = np.floor(exact).astype(int)
    for i in np.argsort(-(exact - counts), kind="stable")[: total - counts.sum()]:
        counts[i] += 1
    return counts.tolist()


def plan_scenes(r: SuiteRecipe, shifts: dict | None = None) -> list[ScenePlan]:
    """The scenes of a suite with their per-category quotas, in generation order: scene
    types interleaved (round robin by type, largest first) so the first scenes made
    already cover every type. ``shifts``: changes to the paper's per-type category counts
    (default ``PLAN_SHIFTS``; ``{}`` gives the paper's own split)."""
    shifts = PLAN_SHIFTS if shifts is None else shifts
    per_type = {}
    for scene_type, (n_scenes, by_label) in PAPER_TABLE.items():
        shift = shifts.get(scene_type, {})
        by_label = {c: by_label[c] + shift.get(c, 0) for c in CATEGORY_ORDER}
        n = max(1, int(round(n_scenes * r.scale)))
        # Category quotas per scene: the type's paper mix, tasks_per_scene each.
        label_counts = _largest_remainder(n * r.tasks_per_scene, [by_label[c] for c in CATEGORY_ORDER])
        quotas = [dict.fromkeys(CATEGORY_ORDER, 0) for _ in range(n)]
        for c, total in zip(CATEGORY_ORDER, label_counts):
            for s, count in enumerate(_largest_remainder(total, [1] * n)):
                quotas[(s + CATEGORY_ORDER.index(c)) % n][c] += count  # spread the remainders
        # Every scene gets tasks_per_scene: move surplus of one scene to another.
        per_type[scene_type] = _balance(quotas, r.tasks_per_scene)
    order = sorted(PAPER_TABLE, key=lambda t: (-PAPER_TABLE[t][0], t))
    plans, round_ = [], 0
    while any(round_ < len(per_type[t]) for t in order):
        for scene_type in order:
            if round_ < len(per_type[scene_type]):
                index = len(plans)
                seed = int(np.random.SeedSequence([r.seed, index]).generate_state(1)[0] & 0x7FFFFFFF)
                plans.append(ScenePlan(index, scene_type, seed, per_type[scene_type][round_]))
        round_ += 1
    return plans


def _balance(quotas: list[dict], per_scene: int) -> list[dict]:
    quotas = [dict(q) for q in quotas]
    for _ in range(per_scene * len(quotas)):
        sums = [sum(q.values()) for q in quotas]
        hi, lo = int(np.argmax(sums)), int(np.argmin(sums))
        if sums[hi] <= per_scene and sums[lo] >= per_scene:
            break
        c = max(CATEGORY_ORDER, key=lambda c: quotas[hi][c])
        quotas[hi][c] -= 1
        quotas[lo][c] += 1
    return quotas


# ----------------------------------------------------------------------------- one scene
def _arrangement_seed(r: SuiteRecipe, scene: ScenePlan, k: int) -> int:
    return int(np.random.SeedSequence([r.seed, scene.index, k]).generate_state(1)[0] & 0x7FFFFFFF)


def placement_weights(need: dict) -> tuple[tuple[str, float], ...]:
    """Support-label weights for the next arrangement: the original's weights, plus weight
    in proportion to what each category still lacks, so objects go where tasks are needed
    (a DrawerShelf wants mostly in-drawer targets) while every support keeps some clutter."""
    from .sampler import LABEL_WEIGHTS

    total = sum(need.values())
    return tuple((label, float(LABEL_WEIGHTS[label] + (NEED_BOOST * need.get(label, 0) / total if total else 0.0)))
                 for label in CATEGORY_ORDER)


def camera_weights(need: dict) -> tuple[tuple[str, float], ...]:
    """Label weights of the camera view score: every label 1, plus ``CAMERA_NEED_BOOST`` x its
    share of what the scene still lacks, so views favour the drawers or baskets it needs."""
    total = sum(need.values())
    return tuple((label, 1.0 + (CAMERA_NEED_BOOST * need.get(label, 0) / total if total else 0.0))
                 for label in CATEGORY_ORDER)


def sample_arrangement(r: SuiteRecipe, scene: ScenePlan, k: int, need: dict | None = None) -> TaskSpec | None:
    """Arrangement ``k`` of a scene: a settled task (target 0 for now), or None if none fits.
    ``need``: the categories' missing task counts, which lean the placement (None: the
    scene's whole quota)."""
    from ..objects.loading import object_ids
    from .sampler import SamplerConfig, _sample_in_scene

    seed = _arrangement_seed(r, scene, k)
    need = scene.quota if need is None else need
    config = SamplerConfig(num_objects=r.num_objects, object_split=r.object_split,
                           label_weights=placement_weights(need),
                           fit_labels=tuple(label for label in FIT_LABELS if need.get(label, 0) > 0),
                           camera_label_weights=camera_weights(need))
    task = _sample_in_scene(np.random.default_rng(seed), scene.scene_type, scene.scene_seed, None,
                            object_ids(r.object_split), config)
    if task is None:
        return None
    return replace(task, target_index=0, seed=seed)


def _scene_key(r: SuiteRecipe, scene: ScenePlan) -> dict:
    return {"build_version": BUILD_VERSION, "recipe": _recipe_identity(r.to_dict()), "scene_seed": scene.scene_seed,
            "quota": scene.quota}


def _new_scene_state(scene: ScenePlan) -> dict:
    """A scene's build state, JSON-safe (it is what a progress file holds): the next
    arrangement, what each category still lacks, the accepted tasks and the spare passing
    objects as [arrangement, object, label], the kept arrangements, the filter counts."""
    return {"next": 0, "need": dict(scene.quota), "accepted": [], "spare": [], "arrangements": [],
            "rejected": {}, "candidates": 0, "seconds": 0.0}


def _take_passing(state: dict, task: TaskSpec, check, wanted: list[int]) -> None:
    """Count every object's verdict and keep the passing ones: as a task while its category
    has quota, else as a spare; the arrangement is kept if any object passed."""
    need, rejected, index = state["need"], state["rejected"], len(state["arrangements"])
    state["candidates"] += len(task.objects)
    kept = False
    for i, placement in enumerate(task.objects):
        label = placement.support_label
        reason = check.rejection(i)
        if reason == "reachable" and i not in check.reachable:
            reason = "unchecked"  # stable and visible, but its category was full: no IK
        rejected[reason or "passed"] = rejected.get(reason or "passed", 0) + 1
        if reason is not None:
            continue
        if i in wanted and need[label] > 0:
            need[label] -= 1
            state["accepted"].append([index, i, label])
        else:
            state["spare"].append([index, i, label])
        kept = True
    if kept:
        state["arrangements"].append(task.to_dict())


def build_scene(r: SuiteRecipe, scene: ScenePlan, filter_env, log=None, progress_path=None) -> dict:
    """Generate one scene's tasks. Returns a JSON-safe result: the accepted tasks, the
    per-filter rejection counts, the time it took.

    ``progress_path``: after every arrangement the scene's state is written there
    (atomically), and a later call continues from it, so a killed build loses at most one
    arrangement of each scene in progress. The state is everything the remaining
    arrangements depend on, so the result is the same as an uninterrupted build's."""
    start = time.perf_counter()
    state = _new_scene_state(scene)
    if progress_path is not None and Path(progress_path).exists():
        saved = json.loads(Path(progress_path).read_text())
        if saved.get("key") == _scene_key(r, scene):
            state = saved["state"]
            if log:
                log(f"scene {scene.index}: continuing at arrangement {state['next']}")
    need, per_scene = state["need"], sum(scene.quota.values())
    for k in range(state["next"], r.arrangement_budget):
        filling = k >= r.max_arrangements
        if sum(need.values()) == 0 or (filling and len(state["accepted"]) + len(state["spare"]) >= per_scene):
            break
        task = sample_arrangement(r, scene, k, {} if filling else need)
        if task is None:
            state["rejected"]["no_arrangement"] = state["rejected"].get("no_arrangement", 0) + 1
        else:
            # IK (the costly filter) only for objects whose category still has quota here;
            # when filling, for all: any passing object then counts.
            wanted = [i for i, o in enumerate(task.objects) if filling or need[o.support_label] > 0]
            _take_passing(state, task, filter_env.check(task, targets=wanted, seed=_arrangement_seed(r, scene, k)),
                          wanted)
            if log:
                log(f"scene {scene.index} {scene.scene_type} arrangement {k}: "
                    f"{len(state['accepted'])} tasks, still need {sum(need.values())}")
        state["next"] = k + 1
        if progress_path is not None:
            state["seconds"] += time.perf_counter() - start
            start = time.perf_counter()
            atomic_write_text(progress_path, canonical_json({"key": _scene_key(r, scene), "state": state}) + "\n")
    shortfall = {c: n for c, n in need.items() if n > 0}
    # Fill from other categories, in generation order.
    accepted = state["accepted"] + state["spare"][:sum(shortfall.values())]
    used = sorted({a for a, _, _ in accepted})
    renumber = {a: j for j, a in enumerate(used)}
    return {
        "build_version": BUILD_VERSION,
        "recipe": r.to_dict(),
        "scene": {"index": scene.index, "scene_type": scene.scene_type, "scene_seed": scene.scene_seed,
                  "quota": scene.quota},
        "arrangements": [state["arrangements"][a] for a in used],
        "tasks": [[renumber[a], i] for a, i, _ in accepted],
        "shortfall": shortfall,
        "tried": state["next"],
        "candidates": state["candidates"],
        "rejected": dict(sorted(state["rejected"].items())),
        "seconds": state["seconds"] + time.perf_counter() - start,
    }


# ----------------------------------------------------------------------------- many scenes
_WORKER_ENV = None


def _worker_init():
    import torch

    torch.set_num_threads(1)  # one core per worker; also keeps IK bit-identical across worker counts


def _scene_path(work_dir: Path, scene: ScenePlan) -> Path:
    return work_dir / f"scene_{scene.index:03d}.json"


def _is_short(result: dict) -> bool:
    return len(result["tasks"]) < sum(result["scene"]["quota"].values())


def _tried(r: SuiteRecipe, result: dict) -> int:
    """Arrangements a scene result tried. (Results made before this was recorded: a short
    scene tried all ``max_arrangements``, a full one at most that many.)"""
    return result.get("tried", r.max_arrangements)


def _stale_reason(r: SuiteRecipe, plan: ScenePlan, result: dict) -> str | None:
    """Why a per-scene result was not made for this plan's scene (None: it was, or it is the
    state a larger fill budget continues from)."""
    if (result.get("build_version") != BUILD_VERSION
            or _recipe_identity(result.get("recipe", {})) != _recipe_identity(r.to_dict())):
        return "made by another recipe or build version"
    if result["scene"]["scene_seed"] != plan.scene_seed:
        return "for another scene than the plan's"
    if result["scene"]["quota"] != plan.quota:
        return "made for other category quotas than the plan's"
    if _tried(r, result) > r.arrangement_budget:
        return f"made with more arrangements than this recipe's {r.arrangement_budget}"
    return None


def _to_continue(r: SuiteRecipe, result: dict) -> bool:
    """A (not stale) result short of its task count that the fill budget lets go on."""
    return _is_short(result) and _tried(r, result) < r.arrangement_budget


def _state_from_result(r: SuiteRecipe, result: dict) -> dict:
    """The build state a short scene ended in, rebuilt from its result, to continue it with
    a larger fill budget. Exact because a short scene kept every passing object: its tasks
    are all accepted objects, then all spares, and it kept every arrangement, in order."""
    assert _is_short(result), "only a short scene's result holds its whole state"
    quota, shortfall = result["scene"]["quota"], result["shortfall"]
    n_accepted = sum(quota.values()) - sum(shortfall.values())
    labelled = [[a, i, result["arrangements"][a]["objects"][i]["support_label"]] for a, i in result["tasks"]]
    return {"next": _tried(r, result), "need": {c: shortfall.get(c, 0) for c in quota},
            "accepted": labelled[:n_accepted], "spare": labelled[n_accepted:],
            "arrangements": result["arrangements"], "rejected": dict(result["rejected"]),
            "candidates": result["candidates"], "seconds": result["seconds"]}


def _scene_status(r: SuiteRecipe, plan: ScenePlan, work_dir: Path) -> str:
    """What a build does with a plan's scene: "new" (no result yet), "stale" (remade),
    "short" (continued by the fill budget) or "done" (kept)."""
    path = _scene_path(work_dir, plan)
    if not path.exists():
        return "new"
    result = json.loads(path.read_text())
    if _stale_reason(r, plan, result) is not None:
        return "stale"
    return "short" if _to_continue(r, result) else "done"


def _build_one(args) -> str:
    global _WORKER_ENV
    r, scene, work_dir, continue_result = args
    path = _scene_path(Path(work_dir), scene)  # build_scenes hands out only scenes still to do
    if _WORKER_ENV is None:
        from .filters import FilterEnv

        _WORKER_ENV = FilterEnv(num_objects=r.num_objects)
    progress = path.with_suffix(".progress.json")
    if continue_result and not progress.exists():  # a short scene that a larger fill budget continues
        atomic_write_text(progress, canonical_json({"key": _scene_key(r, scene),
                                                    "state": _state_from_result(r, json.loads(path.read_text()))}) + "\n")
    result = build_scene(r, scene, _WORKER_ENV, progress_path=progress)
    atomic_write_text(path, canonical_json(result) + "\n")
    progress.unlink(missing_ok=True)
    return str(path)


def build_scenes(r: SuiteRecipe, work_dir, workers: int = 1, limit: int | None = None, log=print,
                 reverse: bool = False) -> list[Path]:
    """Make the per-scene results (skipping those already in ``work_dir``); ``limit``: only
    the first that many scenes of the plan. Workers are ``spawn``ed processes. ``reverse``:
    take the scenes last first, so that two machines building one suite into copies of a
    work directory meet in the middle instead of doing the same scenes (merge the copies
    with ``merge_work_dirs``)."""
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    plans = plan_scenes(r)[:limit]
    status = {p.index: _scene_status(r, p, work_dir) for p in plans}
    todo = [p for p in plans if status[p.index] != "done"]
    stale = [p.index for p in todo if status[p.index] == "stale"]
    short = [p.index for p in todo if status[p.index] == "short"]
    log(f"{r.name}: {len(plans) - len(todo)} of {len(plans)} scenes done, {len(todo)} to make with {workers} workers"
        + (f" (remaking stale scenes {stale})" if stale else "")
        + (f" (continuing short scenes {short} up to {r.arrangement_budget} arrangements)" if short else ""))
    jobs = [(r, p, str(work_dir), p.index in short) for p in (todo[::-1] if reverse else todo)]
    if workers <= 1:
        _worker_init()
        for job in jobs:
            log(f"made {_build_one(job)}")
    else:
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(workers, initializer=_worker_init, maxtasksperchild=None) as pool:
            for path in pool.imap_unordered(_build_one, jobs):
                log(f"made {path}")
    return [_scene_path(work_dir, p) for p in plans]


def merge_work_dirs(source, target) -> list[str]:
    """Bring ``source``'s scene files into ``target`` where they are further along: a
    finished ``scene_NNN.json`` wins over a progress file (which it replaces), and of two
    progress files the one with more arrangements tried. Returns the names taken. (A
    scene's result does not depend on where it was made, so either copy is the scene.)"""
    source, target = Path(source), Path(target)
    taken = []

    def progress_next(path: Path) -> int:
        return json.loads(path.read_text())["state"]["next"] if path.exists() else -1

    for done in sorted(source.glob("scene_[0-9][0-9][0-9].json")):
        if not (target / done.name).exists():
            atomic_write_text(target / done.name, done.read_text())
            (target / done.name).with_suffix(".progress.json").unlink(missing_ok=True)
            taken.append(done.name)
    for progress in sorted(source.glob("scene_*.progress.json")):
        finished = target / progress.name.replace(".progress.json", ".json")
        if not finished.exists() and progress_next(progress) > progress_next(target / progress.name):
            atomic_write_text(target / progress.name, progress.read_text())
            taken.append(progress.name)
    return taken


def load_scene_results(r: SuiteRecipe, work_dir) -> list[dict]:
    """The finished per-scene results in plan order (stale ones, from another recipe or build
    version, raise)."""
    results = []
    for plan in plan_scenes(r):
        path = _scene_path(Path(work_dir), plan)
        if not path.exists():
            continue
        result = json.loads(path.read_text())
        reason = _stale_reason(r, plan, result)
        if reason:
            raise ValueError(f"{path} was {reason}; build again (it is remade) or delete it")
        results.append(result)
    return results


def stratified_order(keys: list) -> list[int]:
    """Indices of ``keys`` (stratum of each item, items of a stratum in their given order)
    so that every prefix holds each stratum in proportion to its size."""
    strata = sorted(set(keys), key=str)
    rank = {s: i for i, s in enumerate(strata)}
    size = Counter(keys)
    seen = Counter()
    positions = []
    for i, key in enumerate(keys):
        positions.append(((seen[key] + 0.5) / size[key], rank[key], i))
        seen[key] += 1
    return [i for _, _, i in sorted(positions)]


def assemble_suite(r: SuiteRecipe, work_dir) -> TaskSuite:
    """The suite from the finished scenes, in stratified order; ``info`` says how complete it is."""
    results = load_scene_results(r, work_dir)
    tasks: list[TaskSpec] = []
    for result in results:
        arrangements = [TaskSpec.from_dict(a) for a in result["arrangements"]]
        # Within a scene, round robin over arrangements so a prefix of a stratum spreads over them.
        for a, i in result["tasks"]:
            tasks.append(replace(arrangements[a], target_index=i))
    # Strata: type x category; within one, scenes interleave (the j-th task of each scene first).
    per_scene_seen = Counter()
    keyed = []
    for t in tasks:
        stratum = (t.scene_type, t.target_label)
        sub = (stratum, t.scene_seed)
        keyed.append((stratum, per_scene_seen[sub], t.scene_seed))
        per_scene_seen[sub] += 1
    within = sorted(range(len(tasks)), key=lambda i: (keyed[i][0], keyed[i][1], keyed[i][2]))
    keys = [keyed[i][0] for i in within]
    order = [within[j] for j in stratified_order(keys)]
    planned = plan_scenes(r)
    info = {
        "recipe": r.to_dict(),
        "build_version": BUILD_VERSION,
        "planned_scenes": len(planned),
        "planned_tasks": len(planned) * r.tasks_per_scene,
        "complete_scenes": len(results),
        "complete": len(results) == len(planned) and not any(_to_continue(r, res) for res in results),
        "complete_scene_indices": [res["scene"]["index"] for res in results],
        "shortfall": {str(res["scene"]["index"]): res["shortfall"] for res in results if res["shortfall"]},
        "candidates": sum(res["candidates"] for res in results),
        "rejected_by_type": _rejections_by_type(results),
    }
    return TaskSuite(r.name, {f"{r.name}/{k:04d}": tasks[i] for k, i in enumerate(order)}, info)


def _rejections_by_type(results) -> dict:
    out: dict = {}
    for res in results:
        counts = out.setdefault(res["scene"]["scene_type"], Counter())
        counts.update(res["rejected"])
    return {t: dict(sorted(c.items())) for t, c in sorted(out.items())}


def smoke_subset(suite: TaskSuite, size: int = 20) -> TaskSuite:
    """About ``size`` tasks covering every category and as many scene types as possible:
    first one task per (type, category) stratum in suite order until ``size`` or all
    strata are covered, categories first, then the suite order fills the rest."""
    chosen: list[str] = []
    seen_labels, seen_types = set(), set()
    ids = suite.ids()
    for want in ("label", "type", "any"):
        for task_id in ids:
            if len(chosen) >= size:
                break
            if task_id in chosen:
                continue
            t = suite.get(task_id)
            if want == "label" and t.target_label in seen_labels:
                continue
            if want == "type" and t.scene_type in seen_types:
                continue
            chosen.append(task_id)
            seen_labels.add(t.target_label)
            seen_types.add(t.scene_type)
    return suite.subset("smoke", chosen, {"what": f"{len(chosen)} tasks of {suite.name}: every category, most types"})


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 16))
