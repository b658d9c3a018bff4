"""Figures of the object catalog: counts, size on disk, and the time of a full rebuild.

    python scripts/bench/bench_objects.py              # counts and size of what is shipped
    python scripts/bench/bench_objects.py --rebuild    # + rebuild from scratch into a
                                                       #   temporary folder (fresh work
                                                       #   cache), time it, and check the
                                                       #   result is byte-identical
    python scripts/bench/bench_objects.py --drop 300   # + share of N random objects that
                                                       #   rest in their most likely pose
                                                       #   when dropped from 5 mm (SAPIEN)

The rebuild reuses the shipped (hash-verified) YCB decompositions: CoACD itself ran on a
16-core machine (scripts/build/build_objects_ycb.py), see the report for its time.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from fetchbench_ms.objects import build, catalog


def disk_usage(directory: Path) -> int:
    return sum(p.stat().st_size for p in directory.rglob("*") if p.is_file())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rebuild", action="store_true")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--drop", type=int, default=0, help="drop-test this many random objects")
    args = parser.parse_args()

    s = catalog.stats()
    print(f"objects {s['total']}: train {s['by_split']['train']}, test {s['by_split']['test']} "
          f"(ratio {s['by_split']['train'] / s['by_split']['test']:.2f}:1)")
    for source, c in sorted(s["by_source"].items()):
        print(f"  {source:11s} {c['total']:5d} (train {c['train']}, test {c['test']}, dropped {s['dropped'].get(source, 0)})")
    print(f"categories: {len(s['by_category'])}")
    directory = catalog.asset_dir()
    for name, entry in sorted(catalog.read_manifest()["files"].items()):
        print(f"  {name}: {entry['bytes'] / 1e6:.2f} MB")
    print(f"assets/objects on disk: {disk_usage(directory) / 1e6:.2f} MB")

    if args.drop:
        import numpy as np

        ids = [r.object_id for r in catalog.list_objects()]
        chosen = np.random.default_rng(0).choice(ids, size=min(args.drop, len(ids)), replace=False).tolist()
        start = time.perf_counter()
        unstable = []
        from fetchbench_ms.objects.sapien_build import drop_on_plane

        for oid in chosen:
            _, tilt, dz = drop_on_plane(catalog.get_object(oid))
            if tilt > 15.0 or abs(dz) > 0.01:
                unstable.append(f"{oid} (tilt {tilt:.0f} deg, dz {dz * 1000:.0f} mm)")
        print(f"drop test: {len(chosen) - len(unstable)}/{len(chosen)} objects rest in their most likely pose "
              f"(tilt <= 15 deg, height within 1 cm) [{time.perf_counter() - start:.0f} s]")
        for line in unstable:
            print(f"  moved: {line}")

    if args.rebuild:
        with tempfile.TemporaryDirectory() as tmp:
            os.environ["FETCHBENCH_CACHE"] = str(Path(tmp) / "cache")  # nothing to resume from
            start = time.perf_counter()
            summary = build.build(Path(tmp) / "objects", workers=args.workers, log=lambda m: None)
            seconds = time.perf_counter() - start
            same = all(
                (Path(tmp) / "objects" / name).read_bytes() == (directory / name).read_bytes()
                for name in (catalog.INDEX_NAME, catalog.YCB_CONVEX_NAME)
            )
        print(f"full rebuild on {args.workers} processes: {seconds:.0f} s ({summary['objects']} objects, "
              f"{summary['dropped']} dropped); byte-identical to the shipped files: {same}")


if __name__ == "__main__":
    main()
