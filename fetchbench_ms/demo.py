"""``fetchbench demo``: the project's main job (``make demo``).

For now (until the evaluation exists) it shows the procedural scene library: it renders
one picture per scene type with the support surfaces highlighted, writes a gallery page
and the scene statistics to the output folder, and prints the statistics.
"""
from __future__ import annotations

import time
from pathlib import Path

from .scenes.cli import seed_arg
from .utils.io import atomic_write_text, canonical_json


def run_demo(out_dir: str | Path, seed: int = 0, stat_seeds: int = 8, width: int = 320, height: int = 240) -> int:
    from .scenes.gallery import render_gallery, write_gallery_page
    from .scenes.registry import scene_types
    from .scenes.stats import stats_table, type_stats

    out_dir = Path(out_dir)
    names = list(scene_types())
    if not names:
        raise FileNotFoundError("no scene types are registered (fetchbench_ms/scenes/types/ is empty)")
    print(f"FetchBench-MS demo: {len(names)} scene types -> {out_dir}/")
    start = time.perf_counter()
    print("rendering the gallery (the first picture compiles the renderer's shaders, ~10 s on CPU)")
    images = render_gallery(out_dir / "gallery", names, seed, width, height, progress=lambda n, p: print(f"  {p}"))
    stats = {n: type_stats(n, range(stat_seeds)) for n in names}
    page = write_gallery_page(out_dir / "scenes.md", images, seed, stats)
    atomic_write_text(out_dir / "scene_stats.json", canonical_json([s.to_dict() for s in stats.values()]) + "\n")
    print()
    print(stats_table(list(stats.values())))
    print()
    print(f"gallery page: {page}")
    print(f"statistics:   {out_dir / 'scene_stats.json'}")
    print(f"done in {time.perf_counter() - start:.1f} s")
    return 0


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size takes WIDTHxHEIGHT, e.g. 320x240; got {text!r}") from None
    return w, h


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("demo", help="the main job: scene gallery and statistics (make demo)")
    p.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the pictured instances")
    p.add_argument("--stat-seeds", type=int, default=8, help="seeds the statistics average over")
    p.add_argument("--size", default="320x240", help="picture size WIDTHxHEIGHT")
    p.set_defaults(func=lambda a: run_demo(a.out, a.seed, a.stat_seeds, *_size(a.size)))
