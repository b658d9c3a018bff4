"""Convex-decompose the YCB scans with CoACD, in parallel (the one heavy step of the catalog).

CoACD takes minutes per 16k-triangle scan on one core, so this runs once on a many-core
machine and its result is shipped (assets/objects/ycb_convex.npz, written by
`fetchbench objects build`, which runs the same decomposition locally for any scan that
no raw result covers).

    # here: write the selected scans (vertices + faces) to one file
    python scripts/build/build_objects_ycb.py prepare --out ycb_inputs.npz
    # anywhere with numpy + coacd: copy this script and fetchbench_ms/objects/decompose.py
    python build_objects_ycb.py decompose --inputs ycb_inputs.npz --out ycb_raw.npz --workers 16 --deadline 560
    # here: repair, pack and record in the manifest
    fetchbench objects build --ycb-raw ycb_raw.npz

``decompose`` saves after every finished scan and skips scans already saved, so a run
cut off by a time limit resumes.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

try:
    from fetchbench_ms.objects import decompose
except ImportError:  # a bare machine: decompose.py copied beside this script
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import decompose  # type: ignore


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
    decompose.decompose_many(args.inputs, args.out, args.workers, args.deadline, log=lambda m: print(m, flush=True))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("prepare", help="write the selected YCB scans to one .npz")
    p.add_argument("--out", required=True)
    p.set_defaults(func=cmd_prepare)
    d = sub.add_parser("decompose", help="CoACD over many processes, resumable")
    d.add_argument("--inputs", required=True)
    d.add_argument("--out", required=True)
    d.add_argument("--workers", type=int, default=max(1, os.cpu_count() or 1))
    d.add_argument("--deadline", type=float, default=float("inf"), help="stop after this many seconds (resumable)")
    d.set_defaults(func=cmd_decompose)
    args = parser.parse_args(argv)
    args.func(args)


if __name__ == "__main__":
    main()
