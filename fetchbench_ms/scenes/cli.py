"""``fetchbench scenes ...``: list, inspect, generate, check, render and export scene types."""
from __future__ import annotations

import argparse
import json
import sys

from ..utils.io import atomic_write_text, canonical_json


def parse_overrides(items: list[str] | None) -> dict[str, float]:
    """``["desk.height=0.75", ...]`` -> ``{"desk.height": 0.75}`` (values are checked by the type)."""
    overrides = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise ValueError(f"--set takes NAME=VALUE, got {item!r}")
        try:
            overrides[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--set {name}: {value!r} is not a number") from None
    return overrides


def seed_arg(text: str) -> int:
    """argparse type of a generator seed: an integer >= 0."""
    try:
        seed = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a seed is an integer >= 0, got {text!r}") from None
    if seed < 0:
        raise argparse.ArgumentTypeError(f"a seed is an integer >= 0, got {seed}")
    return seed


def _spec(args):
    from .registry import generate

    return generate(args.type, args.seed, parse_overrides(args.set))


def _add_instance_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("type", help="scene type (see `fetchbench scenes list`)")
    parser.add_argument("--seed", type=seed_arg, default=0, help="generator seed (default 0)")
    parser.add_argument("--set", action="append", metavar="NAME=VALUE", help="fix one parameter (repeatable)")


def cmd_list(args) -> int:
    from .registry import scene_types

    types = scene_types()
    if args.json:
        rows = [
            {"name": t.name, "n_params": len(t.params), "support_labels": list(t.support_labels), "description": t.description}
            for t in types.values()
        ]
        print(json.dumps(rows, indent=2))
        return 0
    if not types:
        print("no scene types registered")
        return 0
    print(f"{'scene type':<24}{'params':>7}  support labels")
    for t in types.values():
        print(f"{t.name:<24}{len(t.params):>7}  {', '.join(t.support_labels)}")
    print(f"{len(types)} types, {sum(len(t.params) for t in types.values())} parameters")
    return 0


def cmd_params(args) -> int:
    from .registry import get_scene_type

    st = get_scene_type(args.type)
    if args.json:
        rows = [{"name": p.name, "low": p.low, "high": p.high, "unit": p.unit, "kind": p.kind, "doc": p.doc} for p in st.params]
        print(json.dumps(rows, indent=2))
        return 0
    for p in st.params:
        print(f"{p.name:<32}{p.low:>9g} .. {p.high:<9g}{p.unit:<7}{p.doc}")
    return 0


def cmd_generate(args) -> int:
    spec = _spec(args)
    text = json.dumps(spec.to_dict(), indent=1, sort_keys=True) + "\n"
    if args.out:
        atomic_write_text(args.out, text)
        print(f"wrote {args.out} ({len(spec.parts)} parts, {len(spec.support_surfaces)} surfaces, hash {spec.content_hash()[:12]})")
    else:
        sys.stdout.write(text)
    return 0


def cmd_check(args) -> int:
    from .checks import check_scene
    from .registry import generate

    failures = 0
    for seed in _seed_list(args.seeds) if args.seeds else [args.seed]:
        spec = generate(args.type, seed, parse_overrides(args.set))
        report = check_scene(spec, tuple(args.only) if args.only else None)
        problems = [f"[{name}] {p}" for name, ps in report.items() for p in ps]
        failures += bool(problems)
        print(f"{args.type} seed {seed}: {'ok' if not problems else f'{len(problems)} problem(s)'}")
        for p in problems:
            print(f"  {p}")
    return 1 if failures else 0


def _seed_list(text: str) -> list[int]:
    """"3" -> [3]; "0-9" -> [0..9]; "1,4,7" -> [1, 4, 7]."""
    seeds = []
    for chunk in text.split(","):
        lo, sep, hi = chunk.partition("-")
        try:
            seeds += list(range(int(lo), int(hi) + 1)) if sep else [int(lo)]
        except ValueError:
            raise ValueError(f"--seeds takes N, A-B or a comma list, got {text!r}") from None
    return seeds


def cmd_render(args) -> int:
    from .render import render_scene, save_png

    spec = _spec(args)
    if not args.out.lower().endswith(".png"):
        raise ValueError(f"--out must name a .png file, got {args.out!r}")
    save_png(render_scene(spec, args.width, args.height, highlight=not args.no_highlight), args.out)
    print(f"wrote {args.out} ({args.width}x{args.height})")
    return 0


def cmd_export(args) -> int:
    from .export import export_scene

    spec = _spec(args)
    export_scene(spec, args.out, with_surfaces=args.with_surfaces)
    print(f"wrote {args.out} ({len(spec.parts)} parts)")
    return 0


def cmd_stats(args) -> int:
    from .registry import scene_types
    from .stats import stats_table, type_stats

    names = args.types or list(scene_types())
    stats = [type_stats(n, range(args.seeds)) for n in names]
    if args.json:
        print(canonical_json([s.to_dict() for s in stats]))
    else:
        print(stats_table(stats))
    return 0


def cmd_gallery(args) -> int:
    """One picture per type, a gallery page and the statistics (the first main job)."""
    import time
    from pathlib import Path

    from .gallery import render_gallery, write_gallery_page
    from .registry import scene_types
    from .stats import stats_table, type_stats

    out_dir = Path(args.out)
    width, height = _size(args.size)
    names = list(scene_types())
    start = time.perf_counter()
    print(f"scene gallery: {len(names)} scene types -> {out_dir}/ "
          "(the first picture compiles the renderer's shaders, ~10 s on CPU)")
    images = render_gallery(out_dir / "gallery", names, args.seed, width, height, progress=lambda n, p: print(f"  {p}"))
    stats = {n: type_stats(n, range(args.stat_seeds)) for n in names}
    page = write_gallery_page(out_dir / "scenes.md", images, args.seed, stats)
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
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size takes WIDTHxHEIGHT, e.g. 320x240; got {text!r}") from None
    return width, height


def add_commands(subparsers) -> None:
    scenes = subparsers.add_parser("scenes", help="procedural furniture scene types")
    sub = scenes.add_subparsers(dest="scenes_command", required=True, metavar="SUBCOMMAND")

    p = sub.add_parser("list", help="scene types, their parameter counts and support labels")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("params", help="parameter table of one type")
    p.add_argument("type")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_params)

    p = sub.add_parser("generate", help="one scene instance as SceneSpec JSON")
    _add_instance_args(p)
    p.add_argument("--out", help="write to this file instead of stdout")
    p.set_defaults(func=cmd_generate)

    p = sub.add_parser("check", help="run the geometric checks (exit 1 when any fails)")
    _add_instance_args(p)
    p.add_argument("--seeds", default=None, help="seeds to check: N, A-B or a comma list (default: --seed)")
    p.add_argument("--only", action="append", metavar="CHECK", help="run only this check (repeatable)")
    p.set_defaults(func=cmd_check)

    p = sub.add_parser("render", help="a PNG of one instance with its support surfaces highlighted")
    _add_instance_args(p)
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=480)
    p.add_argument("--no-highlight", action="store_true", help="furniture only, no surface overlays")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("export", help="one instance as a GLB or OBJ mesh scene")
    _add_instance_args(p)
    p.add_argument("--out", required=True, help="file to write (.glb or .obj)")
    p.add_argument("--with-surfaces", action="store_true", help="add the support surfaces as thin slabs")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("stats", help="per-type statistics over seeds")
    p.add_argument("types", nargs="*", help="types (default: all)")
    p.add_argument("--seeds", type=seed_arg, default=8, help="number of seeds (0..N-1), >= 1")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_stats)

    p = sub.add_parser("gallery", help="one picture per type, a gallery page and the statistics")
    p.add_argument("--out", default="out/gallery", help="output folder (default out/gallery)")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the pictured instances")
    p.add_argument("--stat-seeds", type=seed_arg, default=8, help="seeds the statistics average over")
    p.add_argument("--size", default="320x240", help="picture size WIDTHxHEIGHT")
    p.set_defaults(func=cmd_gallery)
