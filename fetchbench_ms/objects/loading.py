"""Loading the objects tasks are made of, from the object catalog (``objects.catalog``), cached.

Which catalog version a task was sampled with is stored in the task
(``TaskSpec.object_source``) and checked when the task is loaded, so a task never gets
other geometry than it was sampled with.
"""
from __future__ import annotations

import functools

import numpy as np

from ..utils.io import canonical_json
from . import catalog
from .asset import ObjectAsset


def object_ids(split: str = "test") -> list[str]:
    """Ids of the objects tasks may use, sorted (a fixed order keeps sampling reproducible)."""
    return sorted(r.object_id for r in catalog.list_objects(split=split))


#: Objects a process keeps loaded. A task holds about 15, and a long evaluation goes through
#: the whole split (748 test objects, 5,219 train), so an unbounded cache would end up
#: holding the split (0.1-1 MB an object). 256 keeps well over a task's worth and the objects
#: that recur across a suite's tasks; one evicted is rebuilt in ~30 ms, the same asset
#: (``catalog.get_object`` checks its geometry against the index's fingerprint).
LOADED_OBJECTS_KEPT = 256


@functools.lru_cache(maxsize=LOADED_OBJECTS_KEPT)
def load_object(object_id: str) -> ObjectAsset:
    """The ``ObjectAsset`` for ``object_id`` (cached: assets are immutable)."""
    return catalog.get_object(object_id)


def object_source() -> str:
    """Name and version of the object source (stored in every sampled task)."""
    return "catalog/" + canonical_json(catalog.version_info())


def check_object_source(task_source: str) -> None:
    if task_source != object_source():
        raise ValueError(
            f"task was sampled with objects from {task_source!r} but this install has {object_source()!r}: "
            "its objects would not be the same; resample the task"
        )


def collision_vertices(asset: ObjectAsset) -> np.ndarray:
    """All convex-part vertices in the object frame, (N, 3)."""
    return np.concatenate([np.asarray(p.vertices) for p in asset.convex_parts], axis=0)
