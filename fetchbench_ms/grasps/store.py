"""Shipped grasp labels: sharded ``.npz`` files plus a manifest with hashes.

Layout of ``assets/grasps`` (or ``$FETCHBENCH_GRASPS_DIR``)::

    manifest.json        version, labelling settings, per shard: file name, sha256,
                         object count, trial count, ids kept (>= MIN_SUCCESSES successes)
    shard_00.npz ...     one per non-empty shard (object ids hash into NUM_SHARDS shards)

A shard holds every trial of its objects, concatenated, with ``offsets`` marking where
each object's trials start: ``quat_wxyz`` (float16) and ``position`` (float32) of the
``panda_hand`` pose in the object frame, ``success`` (uint8) and ``width`` (float16, the
finger gap measured after closing, m). See ``fetchbench_ms.grasps`` for the hand frame.

Every read checks the shard's sha256 against the manifest and the manifest's version
against ``GRASPS_VERSION``: a stale or corrupt file is an error, never silently used.
"""
from __future__ import annotations

import functools
import io
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..utils.io import atomic_write_bytes, atomic_write_text, canonical_json, sha256_bytes, sha256_file
from ..utils.paths import assets_root

#: Bump when the sampler, the physics test or the file layout changes: old files become stale.
GRASPS_VERSION = 2
NUM_SHARDS = 64
#: Objects with fewer verified successful grasps than this are dropped from the benchmark.
MIN_SUCCESSES = 16
MANIFEST = "manifest.json"


def default_dir() -> Path:
    override = os.environ.get("FETCHBENCH_GRASPS_DIR")
    if override:
        return Path(override)
    return assets_root() / "grasps"


def shard_of(object_id: str) -> int:
    """Shard index of an object: a stable hash of its id, independent of the catalog's order."""
    return int(sha256_bytes(object_id.encode())[:8], 16) % NUM_SHARDS


def shard_name(shard: int) -> str:
    return f"shard_{shard:02d}.npz"


@dataclass(frozen=True)
class Grasps:
    """All labelled trials of one object. Poses are ``panda_hand`` in the object frame."""

    object_id: str
    T_object_hand: np.ndarray  # (N, 4, 4)
    success: np.ndarray  # (N,) bool
    width: np.ndarray  # (N,) finger gap after closing, m

    def __len__(self) -> int:
        return len(self.success)

    @property
    def successful(self) -> "Grasps":
        keep = self.success
        return Grasps(self.object_id, self.T_object_hand[keep], self.success[keep], self.width[keep])


@dataclass(frozen=True)
class ObjectTrials:
    """What the builder hands the store for one object."""

    object_id: str
    T_object_hand: np.ndarray  # (N, 4, 4)
    success: np.ndarray  # (N,) bool
    width: np.ndarray  # (N,)


def encode_trials(trials: ObjectTrials) -> dict[str, np.ndarray]:
    """One object's trials in the stored dtypes (quaternions wxyz with w >= 0)."""
    T = trials.T_object_hand
    quat_xyzw = Rotation.from_matrix(T[:, :3, :3]).as_quat() if len(T) else np.zeros((0, 4))
    quat_wxyz = quat_xyzw[:, [3, 0, 1, 2]]
    quat_wxyz *= np.where(quat_wxyz[:, :1] < 0, -1.0, 1.0)  # one sign per rotation
    return {
        "quat_wxyz": quat_wxyz.astype(np.float16),
        "position": T[:, :3, 3].astype(np.float32),
        "success": np.asarray(trials.success).astype(np.uint8),
        "width": np.asarray(trials.width).astype(np.float16),
    }


TRIAL_FIELDS = ("quat_wxyz", "position", "success", "width")


def encode_shard(objects: dict[str, dict[str, np.ndarray]], meta: dict) -> bytes:
    """The bytes of one shard file from each object's encoded trials (``encode_trials``);
    deterministic for the same input (objects sorted by id, no timestamps)."""
    ids = sorted(objects)
    counts = [len(objects[i]["success"]) for i in ids]
    arrays = {
        "meta": np.array(canonical_json(meta)),
        "object_ids": np.array(ids, dtype=np.str_),
        "offsets": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
    }
    empty = encode_trials(ObjectTrials("", np.zeros((0, 4, 4)), np.zeros(0, bool), np.zeros(0)))
    for field in TRIAL_FIELDS:
        arrays[field] = np.concatenate([objects[i][field] for i in ids]) if ids else empty[field]
    return _npz_bytes(arrays)


def split_shard(arrays: dict[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    """Inverse of ``encode_shard``: each object's encoded trials, bit for bit."""
    offsets = arrays["offsets"]
    return {
        str(object_id): {field: arrays[field][offsets[k] : offsets[k + 1]] for field in TRIAL_FIELDS}
        for k, object_id in enumerate(arrays["object_ids"])
    }


def _npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An ``.npz`` (readable by ``np.load``) with fixed zip timestamps: ``np.savez_compressed``
    stamps the current time, so the same labels would hash differently on every build."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for key, array in arrays.items():
            member = io.BytesIO()
            np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, member.getvalue(), compresslevel=9)
    return buffer.getvalue()


def write_shard(directory: Path, shard: int, objects: dict[str, dict[str, np.ndarray]], meta: dict) -> Path:
    path = Path(directory) / shard_name(shard)
    atomic_write_bytes(path, encode_shard(objects, meta))
    return path


def read_shard_arrays(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {key: data[key] for key in data.files}


def shard_summary(path: Path, object_ids=None, min_successes: int = MIN_SUCCESSES) -> dict:
    """Manifest entry of one shard file: hash, counts and the ids that keep enough grasps.

    ``object_ids`` limits the entry to the objects the catalog lists now (a shard may
    also hold labels of objects the catalog has since dropped)."""
    arrays = read_shard_arrays(path)
    offsets, success = arrays["offsets"], arrays["success"].astype(bool)
    ids = [str(x) for x in arrays["object_ids"]]
    counts = np.diff(offsets)
    per_object = [int(success[a:b].sum()) for a, b in zip(offsets[:-1], offsets[1:])]
    wanted = None if object_ids is None else set(object_ids)
    listed = [k for k, i in enumerate(ids) if wanted is None or i in wanted]
    return {
        "file": path.name,
        "sha256": sha256_file(path),
        "meta": json.loads(str(arrays["meta"])),
        "objects": len(listed),
        "trials": int(sum(counts[k] for k in listed)),
        "successes": int(sum(per_object[k] for k in listed)),
        "successes_per_object": {ids[k]: per_object[k] for k in listed},
        "kept": [ids[k] for k in listed if per_object[k] >= min_successes],
    }


def write_manifest(directory: Path, settings: dict, shard_entries: list[dict]) -> dict:
    manifest = {
        "version": GRASPS_VERSION,
        "num_shards": NUM_SHARDS,
        "min_successes": MIN_SUCCESSES,
        "settings": settings,
        "shards": {str(e["meta"]["shard"]): {k: v for k, v in e.items() if k != "meta"} for e in shard_entries},
    }
    atomic_write_text(Path(directory) / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    return manifest


class GraspStore:
    """Read access to one grasp directory, with hash and version checks."""

    def __init__(self, directory: str | os.PathLike | None = None):
        self.directory = Path(directory) if directory is not None else default_dir()
        path = self.directory / MANIFEST
        if not path.exists():
            raise FileNotFoundError(f"no grasp manifest at {path}; build it with `fetchbench grasps build`")
        self.manifest = json.loads(path.read_text())
        if self.manifest.get("version") != GRASPS_VERSION:
            raise ValueError(
                f"stale grasp labels in {self.directory}: built by version {self.manifest.get('version')}, "
                f"this code reads version {GRASPS_VERSION}; rebuild with `fetchbench grasps build`"
            )
        self._shards: dict[int, dict[str, np.ndarray]] = {}

    def object_ids(self) -> list[str]:
        return sorted(i for e in self.manifest["shards"].values() for i in e["successes_per_object"])

    def kept_ids(self) -> list[str]:
        return sorted(i for e in self.manifest["shards"].values() for i in e["kept"])

    def successes_per_object(self) -> dict[str, int]:
        return {i: n for e in self.manifest["shards"].values() for i, n in e["successes_per_object"].items()}

    def _shard(self, shard: int) -> dict[str, np.ndarray]:
        if shard not in self._shards:
            entry = self.manifest["shards"][str(shard)]
            path = self.directory / entry["file"]
            digest = sha256_file(path)
            if digest != entry["sha256"]:
                raise ValueError(
                    f"grasp file {path} is corrupt or was changed: sha256 {digest[:12]}... does not match the "
                    f"manifest's {entry['sha256'][:12]}...; rebuild it with `fetchbench grasps build`"
                )
            self._shards[shard] = read_shard_arrays(path)
        return self._shards[shard]

    def load(self, object_id: str) -> Grasps:
        shard = shard_of(object_id)
        entry = self.manifest["shards"].get(str(shard))
        if entry is None or object_id not in entry["successes_per_object"]:
            known = self.object_ids()
            raise KeyError(
                f"no grasps for object {object_id!r}; {len(known)} objects have grasps "
                f"(e.g. {', '.join(known[:3])}); list them with `fetchbench grasps list`"
            )
        arrays = self._shard(shard)
        index = int(np.searchsorted(arrays["object_ids"], object_id))
        start, stop = arrays["offsets"][index], arrays["offsets"][index + 1]
        quat_wxyz = arrays["quat_wxyz"][start:stop].astype(np.float64)
        quat_wxyz /= np.linalg.norm(quat_wxyz, axis=1, keepdims=True)
        T = np.tile(np.eye(4), (stop - start, 1, 1))
        if stop > start:
            T[:, :3, :3] = Rotation.from_quat(quat_wxyz[:, [1, 2, 3, 0]]).as_matrix()
        T[:, :3, 3] = arrays["position"][start:stop]
        return Grasps(
            object_id=object_id,
            T_object_hand=T,
            success=arrays["success"][start:stop].astype(bool),
            width=arrays["width"][start:stop].astype(np.float64),
        )

    def verify(self) -> list[str]:
        """Problems found (empty when every shard file matches its recorded hash)."""
        problems = []
        for entry in self.manifest["shards"].values():
            path = self.directory / entry["file"]
            if not path.exists():
                problems.append(f"{path}: missing")
            elif sha256_file(path) != entry["sha256"]:
                problems.append(f"{path}: sha256 does not match the manifest")
        return problems

    def stats(self) -> dict:
        per_object = self.successes_per_object()
        trials = sum(e["trials"] for e in self.manifest["shards"].values())
        successes = sum(e["successes"] for e in self.manifest["shards"].values())
        kept = self.kept_ids()
        return {
            "version": self.manifest["version"],
            "objects_labelled": len(per_object),
            "objects_kept": len(kept),
            "objects_dropped": len(per_object) - len(kept),
            "trials": trials,
            "successes": successes,
            "success_rate": successes / trials if trials else 0.0,
            "mean_successes_per_kept_object": (sum(per_object[i] for i in kept) / len(kept)) if kept else 0.0,
        }


@functools.lru_cache(maxsize=4)
def _store(directory: str) -> GraspStore:
    return GraspStore(directory)


def _default_store() -> GraspStore:
    return _store(os.fspath(default_dir()))


def load_grasps(object_id: str, directory: str | os.PathLike | None = None) -> Grasps:
    """Every labelled trial of ``object_id`` (use ``.successful`` for the verified grasps)."""
    store = _store(os.fspath(directory)) if directory is not None else _default_store()
    return store.load(object_id)


def objects_with_grasps(directory: str | os.PathLike | None = None) -> list[str]:
    """Ids of the objects with at least ``MIN_SUCCESSES`` verified grasps: the ones tasks may use."""
    store = _store(os.fspath(directory)) if directory is not None else _default_store()
    return store.kept_ids()


def catalog_grasp_stats(records, directory: str | os.PathLike | None = None) -> dict:
    """Grasp figures for catalog ``records``: overall and per source and category
    (labelled, kept, dropped, trials, success rate of sampled candidates), and which
    catalog objects have no labels yet."""
    store = _store(os.fspath(directory)) if directory is not None else _default_store()
    counts = store.successes_per_object()
    trials = {}
    for shard in sorted(int(s) for s in store.manifest["shards"]):
        arrays = store._shard(shard)  # hash-checked
        offsets = arrays["offsets"]
        for k, object_id in enumerate(arrays["object_ids"]):
            trials[str(object_id)] = int(offsets[k + 1] - offsets[k])

    def summary(group) -> dict:
        labelled = [r.object_id for r in group if r.object_id in counts]
        kept = [i for i in labelled if counts[i] >= MIN_SUCCESSES]
        n_trials = sum(trials.get(i, 0) for i in labelled)
        n_success = sum(counts[i] for i in labelled)
        return {
            "objects": len(group),
            "labelled": len(labelled),
            "kept": len(kept),
            "dropped": len(labelled) - len(kept),
            "trials": n_trials,
            "success_rate": round(n_success / n_trials, 4) if n_trials else 0.0,
            "mean_successes_per_kept": round(sum(counts[i] for i in kept) / len(kept), 2) if kept else 0.0,
        }

    by = lambda key: {v: summary([r for r in records if getattr(r, key) == v]) for v in sorted({getattr(r, key) for r in records})}  # noqa: E731
    return {
        **summary(records),
        "version": store.manifest["version"],
        "by_source": by("source"),
        "by_category": by("category"),
        "unlabelled": sorted(r.object_id for r in records if r.object_id not in counts),
    }


def add_grasp_stats(out: dict) -> None:
    """Extension of ``fetchbench objects stats`` (``catalog.register_stats_extension``)."""
    from ..objects import catalog

    try:
        stats = catalog_grasp_stats(catalog.list_objects())
    except (FileNotFoundError, ValueError) as error:  # no or stale library: say so, keep the object stats
        out["grasps"] = {"error": str(error)}
        return
    by_category = stats.pop("by_category")
    unlabelled = stats.pop("unlabelled")
    out["grasps"] = {**stats, "unlabelled": len(unlabelled)}
    out["grasps_by_category"] = {c: f"{s['kept']}/{s['objects']} kept, {s['success_rate']:.0%} of trials held" for c, s in by_category.items()}


def _register_with_catalog() -> None:
    from ..objects import catalog

    # `fetchbench objects stats` (and catalog.stats()) report grasp counts once this module is loaded.
    catalog.register_stats_extension(add_grasp_stats)


_register_with_catalog()
