"""``fetchbench grasps ...``: build, verify, list, show and summarise the grasp library."""
from __future__ import annotations

import json
import os
from pathlib import Path


def _store(args):
    from .store import GraspStore

    return GraspStore(args.dir)


def _parse_shards(text: str | None):
    if not text:
        return None
    from .store import NUM_SHARDS

    shards = set()
    for piece in text.split(","):
        low, _, high = piece.partition("-")
        try:
            shards.update(range(int(low), int(high or low) + 1))
        except ValueError:
            raise ValueError(f"--shards {text!r}: use e.g. '0-15' or '3,7,9' with indices 0..{NUM_SHARDS - 1}") from None
    bad = sorted(s for s in shards if not 0 <= s < NUM_SHARDS)
    if bad:
        raise ValueError(f"--shards: {bad} out of range; valid shard indices are 0..{NUM_SHARDS - 1}")
    return sorted(shards)


def cmd_build(args) -> int:
    from ..objects.asset import SOURCES
    from .build import LabelSettings, build

    if args.source and args.source not in SOURCES:
        raise ValueError(f"unknown source {args.source!r}; valid: {', '.join(SOURCES)}")
    if args.ids_file and args.targets_of:
        raise ValueError("give --ids-file or --targets-of, not both")
    if args.targets_of:
        from ..tasks.suite import load_suite

        ids = sorted({t.target.object_id for t in load_suite(args.targets_of).tasks.values()})
        ids = [i for i in ids if not args.source or i.split("/")[0] == args.source]
    elif args.ids_file:
        ids = [line.strip() for line in Path(args.ids_file).read_text().splitlines() if line.strip()]
        ids = [i for i in ids if not args.source or i.split("/")[0] == args.source]
    else:
        from ..objects import catalog

        records = catalog.list_objects(source=args.source) if args.source else catalog.list_objects()
        ids = [r.object_id for r in records]
    if args.limit:
        ids = sorted(ids)[: args.limit]
    settings = LabelSettings(seed=args.seed, candidates_per_round=args.candidates)
    from .store import default_dir

    if args.hand == "robotiq_2f_85":
        # The Robotiq re-tries the Franka labels' candidates (grasp_labels.robotiq): its own store.
        from .robotiq import RobotiqLabelSettings

        if not args.dir:
            raise ValueError("--hand robotiq_2f_85 writes a store of its own: give --dir (e.g. assets/grasps_robotiq)")
        settings = RobotiqLabelSettings(seed=args.seed, candidates_per_round=args.candidates)
    out = args.dir or os.fspath(default_dir())
    manifest = build(out, ids, loader=args.loader, settings=settings, workers=args.workers, shards=_parse_shards(args.shards), deadline_s=args.deadline)
    done = sum(e["objects"] for e in manifest["shards"].values())
    kept = sum(len(e["kept"]) for e in manifest["shards"].values())
    print(f"{done}/{len(ids)} objects labelled, {kept} kept (>= {manifest['min_successes']} successes) in {out}")
    return 0


def cmd_verify(args) -> int:
    store = _store(args)
    problems = store.verify()
    for problem in problems:
        print(problem)
    print(f"{len(store.manifest['shards'])} shard files checked, {len(problems)} problems")
    return 1 if problems else 0


def cmd_list(args) -> int:
    store = _store(args)
    counts = store.successes_per_object()
    kept = set(store.kept_ids())
    for object_id in sorted(counts):
        if args.dropped == (object_id not in kept):
            print(f"{object_id}\t{counts[object_id]}")
    return 0


def cmd_show(args) -> int:
    from ..objects import catalog
    from .show import render_grasps_png

    grasps = _store(args).load(args.object_id)
    asset = catalog.get_object(args.object_id)
    drawn = render_grasps_png(asset, grasps, args.out, max_grasps=args.max, show_failures=args.failures)
    print(f"wrote {args.out}: {drawn} grasps of {args.object_id}")
    return 0


def cmd_stats(args) -> int:
    stats = _store(args).stats()
    if args.json:
        print(json.dumps(stats, indent=1, sort_keys=True))
    else:
        for key, value in stats.items():
            print(f"{key}: {value:.3f}" if isinstance(value, float) else f"{key}: {value}")
    return 0


def add_commands(subparsers):
    """``fetchbench grasps ...``; returns its sub-commands (``predict`` is added by
    ``grasp_prediction.cli``), and adds the grasp counts to ``fetchbench objects stats``."""
    from ..objects import register_stats_extension

    register_stats_extension(_load_grasp_stats)
    parser = subparsers.add_parser("grasps", help="physics-verified Franka grasp labels")
    sub = parser.add_subparsers(dest="grasps_command", required=True, metavar="ACTION")
    common = {"default": None, "help": "grasp directory (default: assets/grasps or $FETCHBENCH_GRASPS_DIR)"}

    p = sub.add_parser("build", help="label the catalog's objects (resumes from finished shards)")
    p.add_argument("--dir", **common)
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="worker processes (0 = in this process)")
    p.add_argument("--shards", default=None, help="only these shard indices, e.g. '0-15' or '3,7'")
    p.add_argument("--source", default=None, help="only objects of this source (ycb, blob, procedural)")
    p.add_argument("--ids-file", default=None, help="label the ids listed in this file (one a line) instead of the catalog's")
    p.add_argument("--targets-of", default=None, metavar="SUITE",
                   help="label the target objects of a task suite's tasks (test, val, smoke, or a suite file)")
    p.add_argument("--loader", default="fetchbench_ms.objects.catalog:get_object",
                   help="object id -> ObjectAsset function, 'module:function' (fetchbench_ms.grasp_labels.build:object_from_source needs no catalog index)")
    p.add_argument("--limit", type=int, default=0, help="only the first N object ids (sorted), for trials")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--hand", default="franka_hand", choices=("franka_hand", "robotiq_2f_85"),
                   help="robotiq_2f_85: re-try the shipped Franka labels' candidates with the Robotiq 2F-85 "
                        "in physics (docs/robots.md); needs --dir")
    p.add_argument("--candidates", type=int, default=32, help="candidates per sampling round")
    p.add_argument("--deadline", type=float, default=None, help="seconds; start no shard that would end later")
    p.set_defaults(func=cmd_build)

    p = sub.add_parser("verify", help="check shipped grasp files against their recorded sha256")
    p.add_argument("--dir", **common)
    p.set_defaults(func=cmd_verify)

    p = sub.add_parser("list", help="object ids kept (>= 16 successes) with their success counts")
    p.add_argument("--dir", **common)
    p.add_argument("--dropped", action="store_true", help="list the dropped objects instead")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("show", help="draw an object with its successful grasps to a PNG")
    p.add_argument("object_id")
    p.add_argument("--out", required=True)
    p.add_argument("--dir", **common)
    p.add_argument("--max", type=int, default=40, help="draw at most this many grasps")
    p.add_argument("--failures", action="store_true", help="also draw failed trials (red)")
    p.set_defaults(func=cmd_show)

    p = sub.add_parser("stats", help="grasp counts and success rates")
    p.add_argument("--dir", **common)
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_stats)
    return sub


def _load_grasp_stats(out: dict) -> None:
    """Loads ``store``, which registers ``store.add_grasp_stats`` (``catalog.stats`` calls it
    next): the grasp counts in ``fetchbench objects stats``, the store read only then."""
    from . import store  # noqa: F401
