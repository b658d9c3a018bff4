"""Regenerate the scene gallery: docs/img/scenes/<Type>.png (320x240, seed 0) and
docs/scene-gallery.md (pictures, colour key, each type's parameter table).

    python scripts/build/make_gallery.py [--seed 0] [--size 320x240] [--stat-seeds 8]

Run it after changing or adding a scene type, and commit the result.
"""
from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--size", default="320x240", help="WIDTHxHEIGHT")
    parser.add_argument("--stat-seeds", type=int, default=8, help="seeds the per-type statistics average over")
    parser.add_argument("--docs", type=Path, default=ROOT / "docs", help="docs folder")
    args = parser.parse_args()

    from fetchbench_ms.scenes.cli import _size
    from fetchbench_ms.scenes.gallery import render_gallery, write_gallery_page
    from fetchbench_ms.scenes.registry import scene_types
    from fetchbench_ms.scenes.stats import type_stats

    width, height = _size(args.size)
    names = list(scene_types())
    image_dir = args.docs / "img" / "scenes"
    # Pictures of types that no longer exist must not linger in the docs.
    for old in image_dir.glob("*.png"):
        if old.stem not in names:
            old.unlink()
    images = render_gallery(image_dir, names, args.seed, width, height, progress=lambda n, p: print(f"rendered {p}"))
    stats = {n: type_stats(n, range(args.stat_seeds)) for n in names}
    page = write_gallery_page(args.docs / "scene-gallery.md", images, args.seed, stats)
    print(f"wrote {page} ({len(names)} types)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
