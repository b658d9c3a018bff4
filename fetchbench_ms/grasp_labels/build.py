"""Resumable, parallel builder of the grasp library.

Objects hash into ``NUM_SHARDS`` shards; a worker process (``spawn``) labels one whole
shard in a fresh ``GraspLabeller`` scene and writes the shard file atomically, and the
parent rewrites the manifest after each one. A re-run skips every shard whose file is
present, intact and made with the same settings and object list, so an interrupted
build (or a time-limited one, ``deadline_s``) continues where it stopped.

Every random choice of an object draws from ``default_rng([seed, hash(object id)])``
and each shard starts from a fresh scene, so a shard's labels do not depend on which
worker made it or what it made before.
"""
from __future__ import annotations

import importlib
import json
import multiprocessing
import os
import time
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..utils.io import sha256_bytes
from . import physics
from .sampler import sample_candidates
from .settings import LabelSettings
from .store import (
    ObjectTrials,
    encode_trials,
    legacy_shard_name,
    read_shard_arrays,
    shard_name,
    shard_of,
    shard_summary,
    split_shard,
    _store,
    write_manifest,
    write_shard,
)


def object_rng(seed: int, object_id: str) -> np.random.Generator:
    return np.random.default_rng([seed, int(sha256_bytes(object_id.encode())[:15], 16)])


def label_object(asset, settings: LabelSettings) -> ObjectTrials:
    """Sample and verify rounds of candidates on one object until it has
    ``target_successes`` successes or ``max_rounds`` rounds are spent.

    Each object gets a fresh scene (40 ms), so its labels are a function of the object
    and the settings alone, whatever was labelled before in the same process."""
    if getattr(settings, "hand", "franka_hand") != "franka_hand":
        from .robotiq import label_object_robotiq

        return label_object_robotiq(asset, settings)
    rng = object_rng(settings.seed, asset.object_id)
    labeller = physics.GraspLabeller(slots=settings.slots, config=settings.trial, object_friction=settings.object_friction)
    labeller.set_object(asset, density=settings.density)
    poses, success, width = [], [], []
    for _ in range(settings.max_rounds):
        candidates = sample_candidates(asset, settings.candidates_per_round, rng, settings.sampler)
        if len(candidates) == 0:
            break
        result = labeller.label(asset, candidates.T_object_hand)
        poses.append(candidates.T_object_hand)
        success.append(result.success)
        width.append(result.width)
        if sum(int(s.sum()) for s in success) >= settings.target_successes:
            break
    return ObjectTrials(
        object_id=asset.object_id,
        T_object_hand=np.concatenate(poses) if poses else np.zeros((0, 4, 4)),
        success=np.concatenate(success) if success else np.zeros(0, bool),
        width=np.concatenate(width) if width else np.zeros(0),
    )


def resolve_loader(spec: str) -> Callable:
    """``"package.module:function"`` -> the function (an object id -> ``ObjectAsset`` loader)."""
    module, _, name = spec.partition(":")
    if not name:
        raise ValueError(f"asset loader {spec!r} must look like 'package.module:function'")
    return getattr(importlib.import_module(module), name)


def shard_meta(shard: int, settings: LabelSettings) -> dict:
    return {"shard": shard, "settings_digest": settings.digest()}


def label_shard(directory: str, shard: int, object_ids: list[str], loader: str | Callable, settings: LabelSettings) -> dict:
    """Label the objects of one shard that its file lacks and write the merged file; runs
    in a worker process. Labels already in an intact file made with the same settings are
    kept bit for bit (each object's labels depend on nothing else), so adding objects to
    the catalog labels only the new ones.

    ``loader`` maps an object id to its ``ObjectAsset``: a function (module-level, so that
    ``spawn`` can pickle it) or its ``"package.module:function"`` name."""
    started = time.perf_counter()
    load = resolve_loader(loader) if isinstance(loader, str) else loader
    path = Path(directory) / shard_name(shard)
    legacy = Path(directory) / legacy_shard_name(shard)  # the earlier .npz form: its labels are kept
    meta = shard_meta(shard, settings)
    objects, skipped = {}, set()
    existing = _read_if_same_settings(path, meta)
    if existing is None:
        existing = _read_if_same_settings(legacy, meta)
    if existing is not None:
        objects = split_shard(existing)
        skipped = set(json.loads(str(existing["meta"])).get("skipped", []))
    labelled = 0
    for object_id in sorted(set(object_ids) - set(objects) - skipped):
        try:
            asset = load(object_id)
        except ValueError:  # not fetchable by the catalog's own limits: nothing to label
            skipped.add(object_id)
            continue
        trials = label_object(asset, settings)
        objects[object_id] = encode_trials(trials)
        labelled += len(trials.success)
    write_shard(Path(directory), shard, objects, {**meta, "skipped": sorted(skipped)})
    legacy.unlink(missing_ok=True)
    return {"shard": shard, "seconds": time.perf_counter() - started, "trials": labelled, "objects": len(objects)}


def _worker_init() -> None:
    # One core per worker: keep numpy/BLAS from starting thread pools that fight each other.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"


def _read_if_same_settings(path: Path, meta: dict) -> dict[str, np.ndarray] | None:
    """The shard's arrays if the file reads back intact (zip CRCs) and was made with these
    settings; None otherwise (a truncated, foreign or stale file is relabelled)."""
    if not path.exists():
        return None
    try:
        stored = read_shard_arrays(path)
    except Exception:
        return None
    stored_meta = json.loads(str(stored["meta"]))
    return stored if {k: stored_meta.get(k) for k in meta} == meta else None


def _shard_is_current(path: Path, meta: dict, object_ids: list[str]) -> bool:
    """Intact, same settings, and covering every wanted object (labelled or skipped)."""
    stored = _read_if_same_settings(path, meta)
    if stored is None:
        return False
    covered = set(map(str, stored["object_ids"])) | set(json.loads(str(stored["meta"])).get("skipped", []))
    return covered >= set(object_ids)


def build(
    directory: str | os.PathLike,
    object_ids: Iterable[str],
    loader: str | Callable = "fetchbench_ms.objects.catalog:get_object",
    settings: LabelSettings = LabelSettings(),
    workers: int = 1,
    shards: Iterable[int] | None = None,
    deadline_s: float | None = None,
    log: Callable[[str], None] = print,
) -> dict:
    """Label ``object_ids`` into ``directory`` (resuming), then write the manifest.

    ``shards`` limits the run to some shard indices; ``deadline_s`` stops starting new
    shards once the slowest shard seen so far would no longer finish in time.
    Returns the manifest.
    """
    started = time.perf_counter()
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    by_shard: dict[int, list[str]] = {}
    for object_id in sorted(set(object_ids)):
        by_shard.setdefault(shard_of(object_id), []).append(object_id)
    wanted = sorted(by_shard) if shards is None else sorted(set(shards) & set(by_shard))
    todo = [s for s in wanted if not _shard_is_current(directory / shard_name(s), shard_meta(s, settings), by_shard[s])]
    log(f"{len(by_shard)} shards hold {sum(map(len, by_shard.values()))} objects; {len(wanted) - len(todo)} done, {len(todo)} to label")

    def finish() -> dict:
        _store.cache_clear()  # readers in this process must see the new manifest
        entries = []
        for s in sorted(by_shard):
            path = directory / shard_name(s)
            if _shard_is_current(path, shard_meta(s, settings), by_shard[s]):
                entries.append(shard_summary(path, by_shard[s]))
        return write_manifest(directory, settings.as_dict(), entries)

    slowest = 0.0

    def time_left_for_another() -> bool:
        if deadline_s is None:
            return True
        return time.perf_counter() - started + 1.2 * slowest < deadline_s

    if workers <= 0:
        for s in todo:
            if not time_left_for_another():
                break
            result = label_shard(os.fspath(directory), s, by_shard[s], loader, settings)
            slowest = max(slowest, result["seconds"])
            log(f"shard {s:02d}: {result['objects']} objects, {result['trials']} trials in {result['seconds']:.0f} s")
            finish()
        return finish()

    context = multiprocessing.get_context("spawn")
    with context.Pool(workers, initializer=_worker_init) as pool:
        pending = {}
        queue = list(todo)
        while queue or pending:
            while queue and len(pending) < workers and time_left_for_another():
                s = queue.pop(0)
                pending[s] = pool.apply_async(label_shard, (os.fspath(directory), s, by_shard[s], loader, settings))
            if not pending:
                log(f"deadline: {len(queue)} shards left for the next run")
                break
            done = [s for s, r in pending.items() if r.ready()]
            if not done:
                time.sleep(0.5)
                continue
            for s in done:
                result = pending.pop(s).get()  # re-raises a worker's exception here
                slowest = max(slowest, result["seconds"])
                log(f"shard {s:02d}: {result['objects']} objects, {result['trials']} trials in {result['seconds']:.0f} s")
                finish()
    return finish()


def catalog_object_ids() -> list[str]:
    """Every object id of the catalog (the objects package decides what exists)."""
    from ..objects import catalog

    return [record.object_id for record in catalog.list_objects()]



def object_from_source(object_id: str):
    """An object rebuilt from its source without the catalog index (no stable poses: grasps
    do not need them). For batch machines that carry the code but not the shipped index;
    the geometry is the one ``catalog.get_object`` checks against the index fingerprint."""
    from ..objects import catalog

    asset, problems = catalog.build_object(object_id, with_stable_poses=False)
    if problems:
        raise ValueError(f"object {object_id!r} is not fetchable: {'; '.join(problems)}")
    return asset
