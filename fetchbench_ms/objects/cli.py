"""`fetchbench objects ...`: build, verify, stats, render."""
from __future__ import annotations

import json
import os


def _build(args) -> int:
    from .build import build

    build(workers=args.workers, ycb_raw=args.ycb_raw, redo_ycb=args.redo_ycb)
    return 0


def _verify(args) -> int:
    from .build import verify

    result = verify(sample=args.sample)
    for name, digest in result["files"].items():
        print(f"ok  {name}  sha256 {digest[:16]}...")
    if args.sample:
        print(f"ok  {result['objects_rebuilt_and_matched']} objects rebuilt from their sources match the index")
    return 0


def _stats(args) -> int:
    from .catalog import stats

    data = stats()
    if args.json:
        print(json.dumps(data, indent=1, sort_keys=True))
        return 0
    print(f"objects: {data['total']}  (train {data['by_split'].get('train', 0)}, test {data['by_split'].get('test', 0)})")
    print("by source:")
    for source, c in sorted(data["by_source"].items()):
        print(f"  {source:12s} {c['total']:5d}  train {c['train']:5d}  test {c['test']:4d}  dropped {data['dropped'].get(source, 0)}")
    print("by category:")
    for category, c in sorted(data["by_category"].items()):
        print(f"  {category:16s} {c['total']:5d}  train {c['train']:5d}  test {c['test']:4d}  sources {','.join(sorted(c['sources']))}")
    for key in sorted(set(data) - {"total", "by_split", "by_source", "by_category", "dropped"}):
        print(f"{key}: {json.dumps(data[key], sort_keys=True)}")  # added by extensions
    return 0


def _render(args) -> int:
    from .catalog import get_object, list_objects
    from .render import contact_sheet

    records = list_objects(category=args.category, source=args.source, split=args.split)
    if not records:
        raise ValueError(f"no objects with category={args.category!r} source={args.source!r} split={args.split!r}")
    step = max(1, len(records) // args.count)
    chosen = records[::step][: args.count]
    assets = [get_object(r.object_id) for r in chosen]
    contact_sheet(assets, args.out, columns=args.columns, title=f"{args.category}: {len(chosen)} of {len(records)}")
    print(f"wrote {os.path.abspath(args.out)} ({len(chosen)} objects)")
    return 0


def add_commands(subparsers) -> None:
    objects = subparsers.add_parser("objects", help="object catalog: build, verify, stats, render")
    sub = objects.add_subparsers(dest="objects_command", required=True, metavar="ACTION")
    b = sub.add_parser("build", help="rebuild the catalog (decompositions, stable poses, index); resumable")
    b.add_argument("--workers", type=int, default=max(1, min(os.cpu_count() or 1, 8)), help="worker processes")
    b.add_argument("--ycb-raw", default=None, help="raw CoACD results (scripts/build/build_objects_ycb.py decompose)")
    b.add_argument("--redo-ycb", action="store_true", help="recompute YCB decompositions (CoACD, slow) instead of reusing the shipped file")
    b.set_defaults(func=_build)
    v = sub.add_parser("verify", help="check shipped files against their recorded hashes")
    v.add_argument("--sample", type=int, default=0, help="also rebuild N random objects and compare with the index")
    v.set_defaults(func=_verify)
    s = sub.add_parser("stats", help="counts per source, category and split")
    s.add_argument("--json", action="store_true")
    s.set_defaults(func=_stats)
    r = sub.add_parser("render", help="contact sheet of objects of one category (matplotlib, CPU)")
    r.add_argument("--category", required=True)
    r.add_argument("--source", default=None)
    r.add_argument("--split", default=None)
    r.add_argument("--count", type=int, default=12)
    r.add_argument("--columns", type=int, default=6)
    r.add_argument("--out", required=True)
    r.set_defaults(func=_render)
