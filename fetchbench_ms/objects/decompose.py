"""Convex decomposition of scanned meshes with CoACD, and the compact form it is shipped in.

Needs only numpy and coacd (no trimesh, no package imports), so the same file runs on a
bare many-core machine for the one-off heavy job (see scripts/build/build_objects_ycb.py).
CoACD with a fixed seed is deterministic for the same input and parameters.
"""
from __future__ import annotations

import json
import multiprocessing as mp
import os
import time

import numpy as np

#: CoACD settings used for every scan. ``preprocess_mode="on"`` remeshes each scan
#: into a manifold first (a third of the YCB scans are not watertight); a threshold of
#: 0.06 and at most 24 hulls keep mugs and cups recognisable while staying a few dozen
#: PhysX shapes; ``max_ch_vertex`` bounds the size of what is shipped.
COACD_PARAMS = dict(
    threshold=0.06,
    max_convex_hull=24,
    preprocess_mode="on",
    preprocess_resolution=50,
    resolution=2000,
    mcts_nodes=20,
    mcts_iterations=100,
    mcts_max_depth=3,
    merge=True,
    decimate=True,
    max_ch_vertex=64,
    seed=0,
)


def decompose(vertices: np.ndarray, faces: np.ndarray, params: dict | None = None) -> tuple[list[np.ndarray], float]:
    """Hull vertex arrays of the CoACD decomposition of one mesh, and seconds taken."""
    import coacd

    coacd.set_log_level("error")
    start = time.perf_counter()
    parts = coacd.run_coacd(
        coacd.Mesh(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)),
        **(params or COACD_PARAMS),
    )
    return [np.asarray(v, dtype=np.float64) for v, _ in parts], time.perf_counter() - start


# ---------------------------------------------------------------------------- packing
# Hull vertices only are stored: a convex part is the hull of its vertices, so faces are
# recomputed on load. Vertices are quantised to int16 inside each object's bounding box
# (a 25 cm box gives ~4 um steps).


def pack(decompositions: dict[str, list[np.ndarray]]) -> dict[str, np.ndarray]:
    """Arrays for one .npz holding many objects' convex parts (names sorted)."""
    names = sorted(decompositions)
    points, part_sizes, parts_per_object, lows, highs = [], [], [], [], []
    for name in names:
        parts = decompositions[name]
        stacked = np.concatenate(parts)
        low, high = stacked.min(axis=0), stacked.max(axis=0)
        span = np.maximum(high - low, 1e-9)
        q = np.round((stacked - low) / span * 65535.0) - 32768.0
        points.append(q.astype(np.int16))
        part_sizes += [len(p) for p in parts]
        parts_per_object.append(len(parts))
        lows.append(low)
        highs.append(high)
    return dict(
        names=np.array(names),
        points=np.concatenate(points),
        part_sizes=np.array(part_sizes, dtype=np.int32),
        parts_per_object=np.array(parts_per_object, dtype=np.int32),
        low=np.array(lows, dtype=np.float64),
        high=np.array(highs, dtype=np.float64),
    )


def unpack(arrays) -> dict[str, list[np.ndarray]]:
    """Inverse of ``pack`` (up to quantisation): name -> list of part vertex arrays."""
    out: dict[str, list[np.ndarray]] = {}
    point_ends = np.cumsum(arrays["part_sizes"])
    part_ends = np.cumsum(arrays["parts_per_object"])
    part_start = 0
    for i, name in enumerate(arrays["names"].tolist()):
        low, high = arrays["low"][i], arrays["high"][i]
        span = np.maximum(high - low, 1e-9)
        parts = []
        for j in range(part_start, int(part_ends[i])):
            start = int(point_ends[j - 1]) if j > 0 else 0
            q = arrays["points"][start : int(point_ends[j])].astype(np.float64)
            parts.append(low + (q + 32768.0) / 65535.0 * span)
        out[name] = parts
        part_start = int(part_ends[i])
    return out


# ---------------------------------------------------------------------------- many scans
# Raw results (float64 hull vertices per scan, and seconds taken) are saved after every
# finished scan with an atomic rename, and scans already saved are skipped: a run cut
# off by a time limit resumes where it stopped.


def save_raw(path: str, results: dict, seconds: dict) -> None:
    arrays = {f"{name}/{i:03d}": part for name, parts in results.items() for i, part in enumerate(parts)}
    arrays["__seconds__"] = np.frombuffer(json.dumps(seconds, sort_keys=True).encode(), dtype=np.uint8)
    tmp = path + ".tmp.npz"
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def load_raw(path: str) -> tuple[dict[str, list[np.ndarray]], dict[str, float]]:
    """Name -> part vertex arrays, and name -> seconds, from a ``decompose_many`` output."""
    results: dict[str, list[np.ndarray]] = {}
    with np.load(path) as data:
        seconds = json.loads(bytes(data["__seconds__"]).decode()) if "__seconds__" in data.files else {}
        for key in sorted(k for k in data.files if k != "__seconds__"):
            results.setdefault(key.rsplit("/", 1)[0], []).append(np.asarray(data[key], dtype=np.float64))
    return results, seconds


def _work(item):
    name, vertices, faces = item
    parts, seconds = decompose(vertices, faces)
    return name, parts, seconds


def decompose_many(inputs_path: str, out_path: str, workers: int, deadline: float = float("inf"), log=print) -> dict:
    """Decompose every scan of ``inputs_path`` (``<name>/vertices``, ``<name>/faces``)
    into ``out_path`` over ``workers`` spawned processes; stop cleanly at ``deadline`` s."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core per scan; parallel over scans
    with np.load(inputs_path) as data:
        names = sorted({k.rsplit("/", 1)[0] for k in data.files})
        items = [(n, data[f"{n}/vertices"].astype(np.float64), data[f"{n}/faces"].astype(np.int64)) for n in names]
    results, seconds = load_raw(out_path) if os.path.exists(out_path) else ({}, {})
    todo = sorted((it for it in items if it[0] not in results), key=lambda it: -len(it[2]))
    log(f"{len(results)} done, {len(todo)} to decompose on {workers} workers")
    start = time.perf_counter()
    if todo:
        with mp.get_context("spawn").Pool(workers) as pool:
            pending = pool.imap_unordered(_work, todo)
            for _ in todo:
                try:
                    name, parts, secs = pending.next(timeout=max(deadline - (time.perf_counter() - start), 0.001))
                except mp.TimeoutError:
                    log(f"deadline of {deadline:.0f} s reached; stopping (resumable)")
                    pool.terminate()
                    break
                results[name], seconds[name] = parts, secs
                save_raw(out_path, results, seconds)
                log(f"{name}: {len(parts)} parts in {secs:.1f} s (elapsed {time.perf_counter() - start:.0f} s)")
    wall = time.perf_counter() - start
    log(f"{len(results)} of {len(items)} scans decomposed; wall {wall:.1f} s, sum of per-scan times {sum(seconds.values()):.0f} s")
    return {"done": len(results), "total": len(items), "wall_s": wall}
