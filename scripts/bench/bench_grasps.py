"""Figures of the grasp library.

    # labelling throughput on a sample of catalog objects, one process per core
    python scripts/bench/bench_grasps.py throughput --objects 16 --workers 2
    # library figures: counts, success rate, size on disk, dropped objects, re-verification
    python scripts/bench/bench_grasps.py library --reverify 96
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import time
from pathlib import Path

import numpy as np

from fetchbench_ms.grasp_labels import physics
from fetchbench_ms.grasp_labels.build import LabelSettings, label_object
from fetchbench_ms.grasp_labels.store import GraspStore, default_dir


def _label_some(object_ids: list[str]) -> dict:
    """Label ``object_ids`` in one process; time sampling+physics together, as the builder runs."""
    os.environ["OMP_NUM_THREADS"] = "1"
    from fetchbench_ms.grasp_labels.build import object_from_source

    settings = LabelSettings()
    assets = [object_from_source(i) for i in object_ids]  # building objects is the catalog's cost, not ours
    started = time.perf_counter()
    per_object = [label_object(asset, settings) for asset in assets]
    return {
        "seconds": time.perf_counter() - started,
        "trials": sum(len(t.success) for t in per_object),
        "successes": [int(t.success.sum()) for t in per_object],
    }


def throughput(args) -> None:
    # Objects drawn from those the shipped library labelled (all sources the build covered).
    labelled = GraspStore(default_dir()).object_ids()
    labelled = [i for i in labelled if not args.source or i.split("/")[0] == args.source]
    rng = np.random.default_rng(args.seed)
    ids = sorted(rng.choice(labelled, size=min(args.objects, len(labelled)), replace=False))
    chunks = [ids[i :: args.workers] for i in range(args.workers)]
    started = time.perf_counter()
    with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
        results = pool.map(_label_some, chunks)
    wall = time.perf_counter() - started
    trials = sum(r["trials"] for r in results)
    successes = [s for r in results for s in r["successes"]]
    busy = sum(r["seconds"] for r in results)
    per_core = trials / busy
    print(f"objects sampled: {len(ids)} ({args.source or 'all sources'}), workers: {args.workers}, cpu_count: {os.cpu_count()}")
    print(f"trials: {trials}, verified successes: {sum(successes)} ({sum(successes) / max(trials, 1):.1%} of candidates)")
    print(f"mean successes per object: {np.mean(successes):.1f}; objects with < 16: {sum(s < 16 for s in successes)}")
    print(f"throughput: {trials / wall:.1f} trials/s on {args.workers} processes (wall, incl. start-up), {per_core:.1f} trials/s per busy core")
    n_catalog = len(GraspStore(default_dir()).object_ids())
    mean_trials = trials / len(ids)
    core_hours = n_catalog * mean_trials / per_core / 3600
    print(f"projected full rebuild: {n_catalog} objects x {mean_trials:.1f} trials = {core_hours:.2f} core-hours "
          f"({core_hours * 60 / 16:.0f} min on 16 cores, {core_hours / 2:.1f} h on 2)")


def library(args) -> None:
    directory = Path(args.dir) if args.dir else default_dir()
    store = GraspStore(directory)
    stats = store.stats()
    size = sum(f.stat().st_size for f in directory.iterdir() if f.is_file())
    print(f"grasp library {directory} (version {stats['version']})")
    print(f"objects labelled: {stats['objects_labelled']}, kept: {stats['objects_kept']}, dropped (< {store.manifest['min_successes']} successes): {stats['objects_dropped']}")
    print(f"trials: {stats['trials']}, verified success rate of sampled candidates: {stats['success_rate']:.1%}")
    print(f"mean successful grasps per kept object: {stats['mean_successes_per_kept_object']:.1f}")
    print(f"size on disk: {size / 2**20:.2f} MiB in {sum(1 for _ in directory.iterdir())} files")
    try:
        from fetchbench_ms.grasp_labels.store import catalog_grasp_stats
        from fetchbench_ms.objects import catalog

        coverage = catalog_grasp_stats(catalog.list_objects(), directory)
        print(f"catalog objects: {coverage['objects']}, labelled: {coverage['labelled']}, kept: {coverage['kept']}, "
              f"dropped: {coverage['dropped']}, unlabelled: {len(coverage['unlabelled'])}")
        for source, s in coverage["by_source"].items():
            print(f"  {source:10s} kept {s['kept']}/{s['objects']}, dropped {s['dropped']}, success rate {s['success_rate']:.1%}")
    except FileNotFoundError as error:  # no catalog index: library figures only
        print(f"(no catalog coverage: {error})")
    problems = store.verify()
    print(f"hash check: {'ok' if not problems else problems}")
    if args.reverify:
        agreement(store, args.reverify, args.seed)


def agreement(store: GraspStore, n: int, seed: int) -> None:
    """Re-run a seeded sample of stored trials (half successes, half failures) in physics."""
    from fetchbench_ms.grasp_labels.build import object_from_source

    rng = np.random.default_rng(seed)
    ids = rng.choice(store.object_ids(), size=min(n // 4, len(store.object_ids())), replace=False)
    labeller = physics.GraspLabeller(slots=16)
    same_success = same_failure = n_success = n_failure = 0
    started = time.perf_counter()
    for object_id in sorted(ids):
        grasps = store.load(str(object_id))
        asset = object_from_source(str(object_id))
        ok, bad = np.flatnonzero(grasps.success), np.flatnonzero(~grasps.success)
        pick = np.concatenate([rng.choice(ok, size=min(2, len(ok)), replace=False), rng.choice(bad, size=min(2, len(bad)), replace=False)])
        result = labeller.label(asset, grasps.T_object_hand[pick])
        stored = grasps.success[pick]
        same_success += int(np.sum(result.success & stored))
        same_failure += int(np.sum(~result.success & ~stored))
        n_success += int(stored.sum())
        n_failure += int((~stored).sum())
    print(f"re-verification: stored successes held again {same_success}/{n_success} "
          f"({same_success / max(n_success, 1):.1%}); stored failures failed again {same_failure}/{n_failure} "
          f"({same_failure / max(n_failure, 1):.1%}); {time.perf_counter() - started:.0f} s")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("throughput")
    p.add_argument("--objects", type=int, default=16)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--source", default=None)
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=throughput)
    p = sub.add_parser("library")
    p.add_argument("--dir", default=None)
    p.add_argument("--reverify", type=int, default=0, help="re-run about this many stored trials")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=library)
    args = parser.parse_args(argv)
    args.func(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
