"""Digests of every generator's output on a fixed sample, to compare machines.

Run it on two machines (or on one with other CPU features switched off, see below) and
diff the printed JSON: equal digests mean byte-identical outputs. ``--against-shipped``
also compares each rebuilt output with the shipped assets and exits 1 on a difference.

    python scripts/bench/check_determinism.py --against-shipped > here.json
    # the same code paths as a CPU without AVX-512, and one with SSE4 only:
    NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" OPENBLAS_CORETYPE=Haswell python scripts/bench/check_determinism.py
    NPY_DISABLE_CPU_FEATURES="X86_V3 X86_V4 AVX512_ICL AVX512_SPR" OPENBLAS_CORETYPE=Nehalem python scripts/bench/check_determinism.py

NumPy picks SIMD kernels (sin, exp, sums) and OpenBLAS picks its kernels from the CPU at
run time, so these two variables reproduce another machine's floating-point paths here.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from fetchbench_ms.determinism import rebuild_sample


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", type=int, default=40, help="objects per source rebuilt (stable poses included)")
    parser.add_argument("--scene-seeds", type=int, default=4, help="seeds per scene type")
    parser.add_argument("--task-seeds", type=int, default=3, help="seed-sampled tasks (settled in physics)")
    parser.add_argument("--suite-scenes", type=int, default=2, help="test-suite scenes whose first arrangement is rebuilt")
    parser.add_argument("--against-shipped", action="store_true", help="compare with the shipped assets; exit 1 on a difference")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    report = rebuild_sample(objects_per_source=args.objects, scene_seeds=args.scene_seeds, task_seeds=args.task_seeds,
                            suite_scenes=args.suite_scenes)
    report["seconds"] = round(time.perf_counter() - start, 1)
    print(json.dumps(report, indent=1, sort_keys=True))
    if args.against_shipped and report["mismatches"]:
        print(f"{len(report['mismatches'])} outputs differ from the shipped assets", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
