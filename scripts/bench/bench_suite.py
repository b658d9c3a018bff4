"""Suite generation figures: time per scene / per task, and the share of candidate targets
each filter rejects, by scene type.

    python scripts/bench/bench_suite.py --suite test                     # from build/suites/test
    nice python scripts/bench/bench_suite.py --suite test --fresh 2      # make 2 scenes in a temp dir first

Reads the per-scene results the generator wrote (each records its own worker-seconds),
so it reports the real build; ``--fresh N`` times N scenes from scratch in one process.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from collections import Counter

from fetchbench_ms.tasks import suite_build
from fetchbench_ms.tasks.suite_cli import format_rejections


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--suite", default="test", help=f"recipe: {', '.join(suite_build.RECIPES)}")
    p.add_argument("--work-dir", default=None)
    p.add_argument("--fresh", type=int, default=0, help="time this many scenes from scratch (1 worker)")
    p.add_argument("--workers", type=int, default=2, help="workers to project the full build's wall time for")
    args = p.parse_args(argv)
    r = suite_build.recipe(args.suite)
    work_dir = args.work_dir or f"build/suites/{r.name}"
    if args.fresh:
        work_dir = tempfile.mkdtemp(prefix="bench_suite_")
        start = time.perf_counter()
        suite_build.build_scenes(r, work_dir, workers=1, limit=args.fresh, log=lambda *_: None)
        print(f"{args.fresh} scenes from scratch in {time.perf_counter() - start:.1f} s wall (1 worker, incl. env start)")
    results = suite_build.load_scene_results(r, work_dir)
    if not results:
        print(f"no finished scenes in {work_dir}")
        return 1
    seconds = sum(res["seconds"] for res in results)
    tasks = sum(len(res["tasks"]) for res in results)
    planned = suite_build.plan_scenes(r)
    per_scene = seconds / len(results)
    print(f"suite {r.name}: {len(results)} of {len(planned)} scenes, {tasks} tasks, {seconds:.0f} worker-seconds "
          f"({per_scene:.0f} s a scene, {seconds / max(tasks, 1):.1f} s a task)")
    print(f"projected full build: {per_scene * len(planned) / 3600:.1f} worker-hours, "
          f"{per_scene * len(planned) / args.workers / 3600:.1f} h wall with {args.workers} workers")
    by_type = {}
    for res in results:
        by_type.setdefault(res["scene"]["scene_type"], Counter()).update(res["rejected"])
    print("filter rejections (share of candidate targets, first failing filter: stable, visible, reachable):")
    print(format_rejections({"rejected_by_type": {t: dict(c) for t, c in sorted(by_type.items())}}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
