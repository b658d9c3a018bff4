"""Generate a FetchBench task suite (resumable) and write assets/suites/<name>.suite.xz.

    nice python scripts/build/build_suite.py --suite test --workers 2          # make scenes, then assemble
    python scripts/build/build_suite.py --suite test --assemble-only           # ship what is finished
    python scripts/build/build_suite.py --suite test --smoke 20                # also write smoke.suite.xz
    python scripts/build/build_suite.py --suite train --reverse                # a second machine, last scenes first
    python scripts/build/build_suite.py --suite train --merge-from DIR --assemble-only   # join its copy

Per-scene results go to --work-dir (default build/suites/<name>) and are skipped on
re-run, so an interrupted build continues where it stopped. The suite file is the same
bytes for the same recipe whatever --workers is.
"""
from __future__ import annotations

import argparse
import tarfile
import time
from pathlib import Path

from fetchbench_ms.tasks import suite_build
from fetchbench_ms.tasks.suite import suites_dir


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--suite", default="test", help=f"recipe: {', '.join(suite_build.RECIPES)}")
    p.add_argument("--workers", type=int, default=suite_build.default_workers())
    p.add_argument("--limit", type=int, default=None, help="make only the first N scenes of the plan")
    p.add_argument("--work-dir", default=None)
    p.add_argument("--assemble-only", action="store_true", help="write the suite from the scenes already made")
    p.add_argument("--smoke", type=int, default=0, help="also write the smoke subset of this many tasks")
    p.add_argument("--out", default=None, help="suite file (default assets/suites/<name>.suite.xz; .json.gz, .json: "
                                                "those forms)")
    p.add_argument("--reverse", action="store_true", help="make the scenes last first (a second machine's share)")
    p.add_argument("--merge-from", default=None, metavar="DIR",
                   help="first take the scenes that another copy of the work dir has further along")
    args = p.parse_args(argv)
    r = suite_build.recipe(args.suite)
    work_dir = args.work_dir or f"build/suites/{r.name}"
    # A partial build ships its per-scene results so the next run continues it.
    archive = suites_dir() / "partial" / f"{r.name}-scenes.tar.gz"
    if not Path(work_dir).exists() and archive.exists():
        with tarfile.open(archive) as tar:
            tar.extractall(Path(work_dir).parent, filter="data")
        print(f"continuing from {archive}")
    if args.merge_from:
        taken = suite_build.merge_work_dirs(args.merge_from, work_dir)
        print(f"took {len(taken)} scene files from {args.merge_from}")
    start = time.perf_counter()
    if not args.assemble_only:
        suite_build.build_scenes(r, work_dir, workers=args.workers, limit=args.limit, reverse=args.reverse)
        print(f"made scenes in {time.perf_counter() - start:.0f} s wall ({args.workers} workers)")
    suite = suite_build.assemble_suite(r, work_dir)
    out = args.out or suites_dir() / f"{r.name}.suite.xz"
    suite.save(out)
    info = suite.info
    print(f"wrote {out}: {len(suite)} tasks from {info['complete_scenes']} of {info['planned_scenes']} scenes "
          f"({'complete' if info['complete'] else 'partial'})")
    archive.unlink(missing_ok=True)
    if not info["complete"] and args.out is None:
        archive.parent.mkdir(parents=True, exist_ok=True)
        with tarfile.open(archive, "w:gz") as tar:
            tar.add(work_dir, arcname=Path(work_dir).name)
        print(f"wrote {archive}: the finished scenes, to continue the build")
    if args.smoke:
        smoke = suite_build.smoke_subset(suite, args.smoke)
        smoke.save(suites_dir() / "smoke.suite.xz")
        print(f"wrote {suites_dir() / 'smoke.suite.xz'}: {len(smoke)} tasks")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
