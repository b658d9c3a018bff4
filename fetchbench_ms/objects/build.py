"""Rebuild the object catalog from its sources: YCB decompositions, per-object derived
values (extents, mass properties, stable poses, fingerprint), the index and manifest.

Resumable: per-object results are appended (atomically, one JSON line each) to a work
file under ``$FETCHBENCH_CACHE/objects_build/`` tagged with the code versions, and a
rerun skips what is there. Parallel: objects are built in ``spawn`` worker processes.
Outputs are written to temporary names and renamed, and are byte-identical for the
same sources and code (sorted keys, fixed zip timestamps, fixed xz settings).
"""
from __future__ import annotations

import io
import json
import multiprocessing as mp
import os
import time
from pathlib import Path

import numpy as np

from ..utils.io import append_jsonl_atomic, atomic_write_bytes, atomic_write_text, canonical_json, npz_bytes, sha256_bytes
from ..utils.mesh_cache import cache_dir
from ..utils.packed import xz_bytes
from . import catalog, decompose, geometry as g, ycb


def work_dir() -> Path:
    return cache_dir() / "objects_build"


def _write_manifest(directory: Path, files: dict[str, bytes], extra: dict) -> None:
    manifest = {
        "versions": catalog.version_info(),
        "files": {name: {"sha256": sha256_bytes(data), "bytes": len(data)} for name, data in sorted(files.items())},
        **extra,
    }
    atomic_write_text(directory / catalog.MANIFEST_NAME, json.dumps(manifest, indent=1, sort_keys=True) + "\n")


# ------------------------------------------------------------------ YCB decompositions


def repair_parts(parts: list[np.ndarray]) -> list[np.ndarray]:
    """CoACD hulls made fit for PhysX: slivers thickened to >= 2.5 mm, and the pieces
    with a negligible share of the volume (< 0.1 %) dropped."""
    meshes = [g.thicken(g.hull(p)) for p in parts]
    total = sum(float(m.volume) for m in meshes)
    return [np.asarray(m.vertices) for m in meshes if float(m.volume) >= 1e-3 * total]


def _reusable_ycb(names: list[str], log=print) -> bytes | None:
    """The shipped decomposition file, if it verifies and covers every scan."""
    try:
        data = catalog.verified_bytes(catalog.YCB_CONVEX_NAME, catalog.asset_dir())
    except (FileNotFoundError, ValueError) as error:
        log(f"shipped YCB decompositions not reusable: {error}")
        return None
    with np.load(io.BytesIO(data)) as arrays:
        shipped = set(arrays["names"].tolist())
    return data if shipped == set(names) else None


def build_ycb(directory: Path, raw_path: str | None, workers: int, reuse: bool = True, log=print) -> bytes:
    """The packed YCB decomposition file's bytes (written into ``directory``).

    Source, in order: the shipped file when ``reuse`` and it verifies; raw decompositions
    from ``raw_path`` (e.g. brought back from a many-core machine); the resumable local
    raw file, computing any missing scan with CoACD here (minutes per scan)."""
    names = ycb.decomposition_candidates()
    if reuse and raw_path is None:
        data = _reusable_ycb(names, log=log)
        if data is not None:
            atomic_write_bytes(directory / catalog.YCB_CONVEX_NAME, data)
            log(f"YCB: reusing the shipped decompositions of {len(names)} scans (verified)")
            return data
    local_raw = work_dir() / "ycb_raw.npz"
    raw: dict[str, list[np.ndarray]] = {}
    seconds: dict[str, float] = {}
    for path in [p for p in (raw_path, str(local_raw)) if p]:
        if os.path.exists(path):
            got, secs = decompose.load_raw(path)
            for name in names:
                if name not in raw and name in got:
                    raw[name], seconds[name] = got[name], secs.get(name, float("nan"))
    missing = [n for n in names if n not in raw]
    if missing:
        log(f"decomposing {len(missing)} YCB scans with CoACD here (minutes each): {', '.join(missing)}")
        inputs = work_dir() / "ycb_inputs.npz"
        arrays = {}
        for name in missing:
            mesh = ycb.load_scan(name)
            arrays[f"{name}/vertices"] = np.asarray(mesh.vertices, dtype=np.float32)
            arrays[f"{name}/faces"] = np.asarray(mesh.faces, dtype=np.int32)
        inputs.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(inputs, npz_bytes(arrays))
        decompose.decompose_many(str(inputs), str(local_raw), workers, log=log)
        got, secs = decompose.load_raw(str(local_raw))
        for name in missing:
            raw[name], seconds[name] = got[name], secs.get(name, float("nan"))
    packed = decompose.pack({name: repair_parts(raw[name]) for name in names})
    data = npz_bytes(packed)
    atomic_write_bytes(directory / catalog.YCB_CONVEX_NAME, data)
    log(f"YCB: {len(names)} decompositions packed ({len(data) / 1e6:.2f} MB); "
        f"CoACD time (sum over scans, as recorded) {np.nansum(list(seconds.values())):.0f} s")
    return data


# ------------------------------------------------------------------ per-object values


def _build_one(object_id: str) -> dict:
    try:
        asset, problems = catalog.build_object(object_id)
    except ValueError as error:  # broken source file (e.g. blob 168's NaN vertices)
        return {"id": object_id, "dropped": [str(error)]}
    if problems:
        return {"id": object_id, "dropped": problems}
    return {"id": object_id, "entry": catalog.index_entry(asset)}


def _worker_init(asset_directory: str) -> None:
    os.environ["FETCHBENCH_OBJECT_ASSETS"] = asset_directory
    os.environ.setdefault("OMP_NUM_THREADS", "1")


def build(
    directory: Path | None = None,
    workers: int = 2,
    ycb_raw: str | None = None,
    limit: int | None = None,
    redo_ycb: bool = False,
    log=print,
) -> dict:
    """Rebuild everything into ``directory`` (default: the shipped asset folder).

    ``limit`` builds only the first N ids of each source (for tests); ``redo_ycb``
    recomputes the YCB decompositions instead of reusing the verified shipped file.
    Returns a summary."""
    directory = Path(directory or catalog.asset_dir())
    directory.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    ycb_data = build_ycb(directory, ycb_raw, workers, reuse=not redo_ycb, log=log)
    _write_manifest(directory, {catalog.YCB_CONVEX_NAME: ycb_data}, {"partial": True})
    catalog.clear_caches()
    ycb_seconds = time.perf_counter() - start

    ids = catalog.source_ids()
    if limit is not None:
        per_source: dict[str, int] = {}
        kept = []
        for oid in ids:
            source = oid.split("/")[0]
            if per_source.get(source, 0) < limit:
                kept.append(oid)
                per_source[source] = per_source.get(source, 0) + 1
        ids = kept
    # The work file is valid only for these code versions and this YCB file.
    tag = {"versions": catalog.version_info(), "ycb_sha256": sha256_bytes(ycb_data), "directory": str(directory)}
    work_file = work_dir() / f"objects-{sha256_bytes(canonical_json(tag).encode())[:16]}.jsonl"
    done: dict[str, dict] = {}
    if work_file.exists():
        for line in work_file.read_text().splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:  # a line cut by a crash is redone
                continue
            done[row["id"]] = row
    todo = [oid for oid in ids if oid not in done]
    log(f"objects: {len(ids)} ids, {len(ids) - len(todo)} already built ({work_file}), {len(todo)} to build on {workers} processes")
    t0 = time.perf_counter()
    if todo:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_worker_init, initargs=(str(directory),)) as pool:
            for k, row in enumerate(pool.imap_unordered(_build_one, todo, chunksize=8), 1):
                append_jsonl_atomic(work_file, row)
                done[row["id"]] = row
                if k % 500 == 0 or k == len(todo):
                    log(f"  {k}/{len(todo)} built ({time.perf_counter() - t0:.0f} s)")
    objects = {oid: done[oid]["entry"] for oid in sorted(ids) if "entry" in done[oid]}
    dropped = {oid: done[oid]["dropped"] for oid in sorted(ids) if "dropped" in done[oid]}
    index = {"versions": catalog.version_info(), "objects": objects, "dropped": dropped}
    index_data = xz_bytes(canonical_json(index).encode("utf-8"))
    atomic_write_bytes(directory / catalog.INDEX_NAME, index_data)
    _write_manifest(
        directory,
        {catalog.YCB_CONVEX_NAME: ycb_data, catalog.INDEX_NAME: index_data},
        {"coacd_params": decompose.COACD_PARAMS, "counts": {"objects": len(objects), "dropped": len(dropped)}},
    )
    (directory / catalog.LEGACY_INDEX_NAME).unlink(missing_ok=True)  # the manifest no longer names it
    catalog.clear_caches()
    summary = {
        "objects": len(objects),
        "dropped": len(dropped),
        "seconds_total": round(time.perf_counter() - start, 1),
        "seconds_ycb_pack": round(ycb_seconds, 1),
        "seconds_objects": round(time.perf_counter() - t0, 1),
        "built_now": len(todo),
    }
    log(f"catalog: {summary}")
    return summary


def verify(directory: Path | None = None, sample: int = 0, seed: int = 0) -> dict:
    """Check every shipped file against the manifest and versions; rebuild ``sample``
    random objects from their sources and compare them with the index."""
    directory = Path(directory or catalog.asset_dir())
    hashes = catalog.verify_files(directory)
    index = catalog.load_index() if directory == catalog.asset_dir() else None
    checked = []
    if sample and index is not None:
        ids = sorted(index["objects"])
        rng = np.random.default_rng(seed)
        for oid in rng.choice(ids, size=min(sample, len(ids)), replace=False).tolist():
            catalog.get_object(oid)  # raises on a fingerprint mismatch
            checked.append(oid)
    return {"files": hashes, "objects_rebuilt_and_matched": len(checked)}
