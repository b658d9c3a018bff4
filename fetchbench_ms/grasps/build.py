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
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from ..utils.io import canonical_json, sha256_bytes
from . import physics
from .sampler import SamplerConfig, sample_candidates
from .store import (
    GRASPS_VERSION,
    ObjectTrials,
    read_shard_arrays,
    shard_name,
    shard_of,
    shard_summary,
    write_manifest,
    write_shard,
)


@dataclass(frozen=True)
class LabelSettings:
    """Everything that decides the labels; recorded in every shard and in the manifest."""

    seed: int = 0
    candidates_per_round: int = 32
    max_rounds: int = 5
    #: Stop drawing more rounds once an object has this many verified successes.
    target_successes: int = 24
    slots: int = 16
    density: float = physics.DENSITY
    object_friction: float = physics.OBJECT_FRICTION
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    trial: physics.TrialConfig = field(default_factory=physics.TrialConfig)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["sampler"]["depth_range"] = list(d["sampler"]["depth_range"])
        d["version"] = GRASPS_VERSION
        return d

    def digest(self) -> str:
        return sha256_bytes(canonical_json(self.as_dict()).encode())[:16]


def object_rng(seed: int, object_id: str) -> np.random.Generator:
    return np.random.default_rng([seed, int(sha256_bytes(object_id.encode())[:15], 16)])


def label_object(labeller: physics.GraspLabeller, asset, settings: LabelSettings) -> ObjectTrials:
    """Sample and verify rounds of candidates on one object until it has
    ``target_successes`` successes or ``max_rounds`` rounds are spent."""
    rng = object_rng(settings.seed, asset.object_id)
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


def shard_meta(shard: int, object_ids: list[str], settings: LabelSettings) -> dict:
    return {
        "shard": shard,
        "settings_digest": settings.digest(),
        "objects_digest": sha256_bytes("\n".join(sorted(object_ids)).encode())[:16],
    }


def label_shard(directory: str, shard: int, object_ids: list[str], loader: str | Callable, settings: LabelSettings) -> dict:
    """Label every object of one shard and write its file; runs in a worker process.

    ``loader`` maps an object id to its ``ObjectAsset``: a function (module-level, so that
    ``spawn`` can pickle it) or its ``"package.module:function"`` name."""
    started = time.perf_counter()
    load = resolve_loader(loader) if isinstance(loader, str) else loader
    labeller = physics.GraspLabeller(slots=settings.slots, object_friction=settings.object_friction, config=settings.trial)
    trials = [label_object(labeller, load(object_id), settings) for object_id in sorted(object_ids)]
    path = write_shard(Path(directory), shard, trials, shard_meta(shard, object_ids, settings))
    return {"shard": shard, "path": str(path), "seconds": time.perf_counter() - started,
            "trials": int(sum(len(t.success) for t in trials)), "objects": len(trials)}


def _worker_init() -> None:
    # One core per worker: keep numpy/BLAS from starting thread pools that fight each other.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"


def _shard_is_current(path: Path, meta: dict) -> bool:
    if not path.exists():
        return False
    try:
        stored = read_shard_arrays(path)
    except Exception:  # a truncated or foreign file is simply rebuilt
        return False
    return json.loads(str(stored["meta"])) == meta


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
    todo = [s for s in wanted if not _shard_is_current(directory / shard_name(s), shard_meta(s, by_shard[s], settings))]
    log(f"{len(by_shard)} shards hold {sum(map(len, by_shard.values()))} objects; {len(wanted) - len(todo)} done, {len(todo)} to label")

    def finish() -> dict:
        entries = []
        for s in sorted(by_shard):
            path = directory / shard_name(s)
            if _shard_is_current(path, shard_meta(s, by_shard[s], settings)):
                entries.append(shard_summary(path))
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

