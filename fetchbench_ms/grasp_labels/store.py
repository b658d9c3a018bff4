"""Shipped grasp labels: sharded array files plus a manifest with hashes.

Layout of ``assets/grasps`` (or ``$FETCHBENCH_GRASPS_DIR``)::

    manifest.json.xz     version, labelling settings, per shard: file name, sha256,
                         object count, trial count, ids kept (>= MIN_SUCCESSES successes)
    shard_00.arrays.xz   one per non-empty shard (object ids hash into NUM_SHARDS shards)
    ...

A shard holds every trial of its objects, concatenated, with ``offsets`` marking where
each object's trials start: ``quat_wxyz`` (float16) and ``position`` (float32) of the
``panda_hand`` pose in the object frame, ``success`` (uint8) and ``width`` (float16, the
finger gap measured after closing, m). See ``fetchbench_ms.grasp_labels`` for the hand frame.

The files are packed losslessly (``utils.packed``): the manifest is its JSON, xz; a shard
is an ``.arrays.xz`` of those arrays, except that a quaternion's w, which its unit norm
nearly fixes, is stored as the float16 steps between it and sqrt(1 - x^2 - y^2 - z^2)
(``encode_shard``; a fifth of the bytes ``quat_wxyz`` took). Directories in the earlier
form (``manifest.json``, ``shard_NN.npz``) are read as well; the builder rewrites them.

Every read checks the shard's sha256 against the manifest and the manifest's version
against ``GRASPS_VERSION``: a stale or corrupt file is an error, never silently used.
"""
from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..utils.io import atomic_write_bytes, canonical_json, sha256_bytes, sha256_file
from ..utils.packed import ARRAYS_SUFFIX, pack_arrays, unpack_arrays, unxz_bytes, xz_bytes
from ..utils.paths import assets_root

#: Bump when the sampler, the physics test or the file layout changes: old files become stale.
GRASPS_VERSION = 2
NUM_SHARDS = 64
#: Objects with fewer verified successful grasps than this are dropped from the benchmark.
MIN_SUCCESSES = 16
MANIFEST = "manifest.json.xz"
#: The earlier forms of a grasp directory (read, never written): ``manifest.json``, ``shard_NN.npz``.
LEGACY_MANIFEST = "manifest.json"
LEGACY_SHARD_SUFFIX = ".npz"


def default_dir() -> Path:
    override = os.environ.get("FETCHBENCH_GRASPS_DIR")
    if override:
        return Path(override)
    return assets_root() / "grasps"


def shard_of(object_id: str) -> int:
    """Shard index of an object: a stable hash of its id, independent of the catalog's order."""
    return int(sha256_bytes(object_id.encode())[:8], 16) % NUM_SHARDS


def shard_name(shard: int) -> str:
    return f"shard_{shard:02d}{ARRAYS_SUFFIX}"


def legacy_shard_name(shard: int) -> str:
    return f"shard_{shard:02d}{LEGACY_SHARD_SUFFIX}"


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


def shard_arrays(objects: dict[str, dict[str, np.ndarray]], meta: dict) -> dict[str, np.ndarray]:
    """One shard's arrays from each object's encoded trials (``encode_trials``), objects by id."""
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
    return arrays


def _unit_quat_w(quat_xyz: np.ndarray) -> np.ndarray:
    """float16 sqrt(1 - x^2 - y^2 - z^2): the w >= 0 that makes the quaternion a unit one."""
    x, y, z = (quat_xyz[:, k].astype(np.float64) for k in range(3))
    return np.sqrt(np.maximum(0.0, 1.0 - (x * x + y * y + z * z))).astype(np.float16)


def encode_shard_arrays(arrays: dict[str, np.ndarray]) -> bytes:
    """The bytes of one shard file (``shard_arrays``'s arrays); the same arrays give the same
    bytes. ``quat_wxyz`` goes in as ``quat_xyz`` and ``quat_w_correction``, w's float16 bits
    less those of ``_unit_quat_w`` (modulo 2^16; mostly within a few steps of 0), with the
    sha256 of ``quat_wxyz``: the prediction is float arithmetic, and a reader whose rounding
    differed would notice (``decode_shard``)."""
    quat = np.ascontiguousarray(arrays["quat_wxyz"], dtype=np.float16)
    stored = {}
    for name, array in arrays.items():
        if name != "quat_wxyz":
            stored[name] = array
            continue
        stored["quat_xyz"] = np.ascontiguousarray(quat[:, 1:])
        stored["quat_w_correction"] = quat[:, 0].view(np.uint16) - _unit_quat_w(quat[:, 1:]).view(np.uint16)
        stored["quat_wxyz_sha256"] = np.array(sha256_bytes(quat.tobytes()))
    return pack_arrays(stored)


def decode_shard(data: bytes, what: str | os.PathLike = "shard") -> dict[str, np.ndarray]:
    """Inverse of ``encode_shard_arrays``: the arrays in their order, bit for bit."""
    stored = unpack_arrays(data, what)
    arrays = {}
    for name, array in stored.items():
        if name == "quat_xyz":
            w = (_unit_quat_w(array).view(np.uint16) + stored["quat_w_correction"]).view(np.float16)
            quat = np.concatenate([w[:, None], array], axis=1)
            if sha256_bytes(quat.tobytes()) != str(stored["quat_wxyz_sha256"]):
                raise ValueError(f"{what}: its quaternions decode to other values on this machine (float16 "
                                 "rounding differs): rebuild the shard here with `fetchbench grasps build`")
            arrays["quat_wxyz"] = quat
        elif name not in ("quat_w_correction", "quat_wxyz_sha256"):
            arrays[name] = array
    return arrays


def encode_shard(objects: dict[str, dict[str, np.ndarray]], meta: dict) -> bytes:
    """The bytes of one shard file from each object's encoded trials (``encode_trials``);
    deterministic for the same input (objects sorted by id, no timestamps)."""
    return encode_shard_arrays(shard_arrays(objects, meta))


def split_shard(arrays: dict[str, np.ndarray]) -> dict[str, dict[str, np.ndarray]]:
    """Inverse of ``encode_shard``: each object's encoded trials, bit for bit."""
    offsets = arrays["offsets"]
    return {
        str(object_id): {field: arrays[field][offsets[k] : offsets[k + 1]] for field in TRIAL_FIELDS}
        for k, object_id in enumerate(arrays["object_ids"])
    }


def write_shard(directory: Path, shard: int, objects: dict[str, dict[str, np.ndarray]], meta: dict) -> Path:
    path = Path(directory) / shard_name(shard)
    atomic_write_bytes(path, encode_shard(objects, meta))
    return path


def read_shard_arrays(path: Path) -> dict[str, np.ndarray]:
    """A shard file's arrays: packed (``shard_NN.arrays.xz``) or an earlier ``.npz``."""
    path = Path(path)
    if path.name.endswith(LEGACY_SHARD_SUFFIX):
        with np.load(path, allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    return decode_shard(path.read_bytes(), path)


def manifest_path(directory: str | os.PathLike) -> Path:
    """The directory's manifest: ``manifest.json.xz``, else an earlier ``manifest.json``."""
    packed = Path(directory) / MANIFEST
    legacy = Path(directory) / LEGACY_MANIFEST
    return legacy if not packed.exists() and legacy.exists() else packed


def read_manifest(directory: str | os.PathLike) -> dict:
    path = manifest_path(directory)
    if not path.exists():
        raise FileNotFoundError(f"no grasp manifest at {path}; build it with `fetchbench grasps build`")
    data = path.read_bytes()
    return json.loads(unxz_bytes(data, path) if path.name == MANIFEST else data)


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
    text = json.dumps(manifest, indent=1, sort_keys=True) + "\n"
    atomic_write_bytes(Path(directory) / MANIFEST, xz_bytes(text.encode()))
    (Path(directory) / LEGACY_MANIFEST).unlink(missing_ok=True)  # it would describe the old files
    return manifest


class GraspStore:
    """Read access to one grasp directory, with hash and version checks."""

    def __init__(self, directory: str | os.PathLike | None = None):
        self.directory = Path(directory) if directory is not None else default_dir()
        self.manifest = read_manifest(self.directory)
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
    """Extension of ``fetchbench objects stats`` (``objects.register_stats_extension``)."""
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
    from ..objects import register_stats_extension

    # `fetchbench objects stats` (and catalog.stats()) report grasp counts once this module is loaded.
    register_stats_extension(add_grasp_stats)


_register_with_catalog()
