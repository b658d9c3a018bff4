"""Convex-decompose the YCB scans with CoACD, in parallel (the one heavy step of the catalog).

CoACD takes minutes per 16k-triangle scan, so this runs once on a many-core machine and
its result is shipped (assets/objects/ycb_convex.npz, written by `fetchbench objects
build`, which runs this same decomposition locally for any scan it lacks).

    # here: write the selected scans (vertices + faces) to one file
    python scripts/build_objects_ycb.py prepare --out .devwork/objects/ycb_inputs.npz
    # anywhere with numpy + coacd (no package import needed):
    python scripts/build_objects_ycb.py decompose --inputs ycb_inputs.npz --out raw.npz --workers 16
    # here: post-process, pack and record in the manifest
    python -m fetchbench_ms objects build --ycb-raw raw.npz

``decompose`` saves its results after every finished scan (atomic rename), and skips
scans already in ``--out``, so a cut-off run resumes.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def _load_decompose():
    try:
        from fetchbench_ms.objects import decompose
    except ImportError:  # standalone copy beside this script (bare machine)
        import decompose  # type: ignore
    return decompose


def _work(item):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    name, vertices, faces = item
    parts, seconds = _load_decompose().decompose(vertices, faces)
    return name, parts, seconds


def _save_raw(path: str, results: dict, seconds: dict) -> None:
    arrays = {}
    for name, parts in results.items():
        for i, part in enumerate(parts):
            arrays[f"{name}/{i:03d}"] = part
    arrays["__seconds__"] = np.frombuffer(json.dumps(seconds, sort_keys=True).encode(), dtype=np.uint8)
    tmp = path + ".tmp.npz"
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, path)


def load_raw(path: str) -> tuple[dict[str, list[np.ndarray]], dict[str, float]]:
    """Name -> part vertex arrays, and name -> seconds, from a ``decompose`` output."""
    results: dict[str, list[np.ndarray]] = {}
    with np.load(path) as data:
        seconds = json.loads(bytes(data["__seconds__"]).decode()) if "__seconds__" in data.files else {}
        for key in sorted(k for k in data.files if k != "__seconds__"):
            name = key.rsplit("/", 1)[0]
            results.setdefault(name, []).append(np.asarray(data[key], dtype=np.float64))
    return results, seconds


def cmd_prepare(args) -> None:
    from fetchbench_ms.objects import ycb

    arrays = {}
    for name in ycb.decomposition_candidates():
        mesh = ycb.load_scan(name)
        arrays[f"{name}/vertices"] = np.asarray(mesh.vertices, dtype=np.float32)  # STL is float32
        arrays[f"{name}/faces"] = np.asarray(mesh.faces, dtype=np.int32)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    np.savez_compressed(args.out, **arrays)
    print(f"wrote {len(arrays) // 2} scans to {args.out}")


def cmd_decompose(args) -> None:
    with np.load(args.inputs) as data:
        names = sorted({k.rsplit("/", 1)[0] for k in data.files})
        items = [(n, data[f"{n}/vertices"].astype(np.float64), data[f"{n}/faces"].astype(np.int64)) for n in names]
    results, seconds = load_raw(args.out) if os.path.exists(args.out) else ({}, {})
    todo = [it for it in items if it[0] not in results]
    # Biggest first, so the slowest scans do not start last.
    todo.sort(key=lambda it: -len(it[2]))
    print(f"{len(results)} done, {len(todo)} to decompose on {args.workers} workers", flush=True)
    start = time.perf_counter()
    with mp.get_context("spawn").Pool(args.workers) as pool:
        pending = pool.imap_unordered(_work, todo)
        for _ in todo:
            remaining = args.deadline - (time.perf_counter() - start)
            try:
                name, parts, secs = pending.next(timeout=max(remaining, 0.001))
            except mp.TimeoutError:
                # Stop cleanly before an outer time limit: what finished is saved and a
                # later run resumes from it.
                print(f"deadline of {args.deadline:.0f} s reached; stopping", flush=True)
                pool.terminate()
                break
            results[name], seconds[name] = parts, secs
            _save_raw(args.out, results, seconds)
            print(f"{name}: {len(parts)} parts in {secs:.1f} s (elapsed {time.perf_counter() - start:.0f} s)", flush=True)
    print(f"{len(results)} of {len(items)} scans decomposed; wall {time.perf_counter() - start:.1f} s, "
          f"sum of per-scan times {sum(seconds.values()):.0f} s", flush=True)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_prepare)
    d = sub.add_parser("decompose")
    d.add_argument("--inputs", required=True)
    d.add_argument("--out", required=True)
    d.add_argument("--workers", type=int, default=max(1, os.cpu_count() or 1))
    d.add_argument("--deadline", type=float, default=float("inf"), help="stop after this many seconds (resumable)")
    d.set_defaults(func=cmd_decompose)
    args = parser.parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
