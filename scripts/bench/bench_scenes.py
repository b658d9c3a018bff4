"""Benchmark of the scene library: per type, generation time (median and 95th percentile),
the time to load a scene into SAPIEN as static bodies (median), and parameter counts.

    python scripts/bench/bench_scenes.py [--seeds 50] [--load-seeds 10] [TYPE ...]

Goals: median generation <= 50 ms, median SAPIEN load <= 0.3 s. Loading is timed from
creating the SAPIEN scene (CPU physics + renderer) to the built static furniture body (the mesh cache is warmed first, as
it is in any run after the first). Figures depend on machine load: say under what load
they were taken.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("types", nargs="*", help="scene types (default: all registered)")
    parser.add_argument("--seeds", type=int, default=50, help="instances timed for generation per type")
    parser.add_argument("--load-seeds", type=int, default=10, help="instances timed for SAPIEN loading per type")
    args = parser.parse_args()

    from fetchbench_ms.scenes import generate, get_scene_type, scene_types
    from fetchbench_ms.scenes.sapien_build import build_static_scene
    from fetchbench_ms.utils.sapien_device import new_scene

    names = args.types or list(scene_types())
    for name in names:
        get_scene_type(name)  # unknown names fail here, naming the valid ones
    load_avg = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"scene benchmark: {args.seeds} seeds for generation, {args.load_seeds} for SAPIEN loading; "
          f"load average {load_avg:.2f} on {os.cpu_count()} CPUs")
    header = f"{'scene type':<24}{'gen median ms':>14}{'gen p95 ms':>12}{'load median s':>15}{'params':>8}{'parts':>7}"
    print(header)
    print("-" * len(header))
    gen_medians, load_medians, total_params = [], [], 0
    for name in names:
        gen_times, parts = [], []
        for seed in range(args.seeds):
            start = time.perf_counter()
            spec = generate(name, seed)
            gen_times.append(time.perf_counter() - start)
            parts.append(len(spec.parts))
        load_times = []
        for seed in range(args.load_seeds):
            spec = generate(name, seed)
            build_static_scene(new_scene(), spec)  # warm the mesh cache for convex parts
            start = time.perf_counter()
            scene = new_scene()
            build_static_scene(scene, spec)
            load_times.append(time.perf_counter() - start)
            del scene
        n_params = len(get_scene_type(name).params)
        total_params += n_params
        gen_ms = np.asarray(gen_times) * 1000
        gen_medians.append(np.median(gen_ms))
        load_medians.append(np.median(load_times))
        print(f"{name:<24}{np.median(gen_ms):>14.1f}{np.percentile(gen_ms, 95):>12.1f}"
              f"{np.median(load_times):>15.3f}{n_params:>8}{np.mean(parts):>7.1f}")
    print("-" * len(header))
    print(f"{'worst type':<24}{max(gen_medians):>14.1f}{'':>12}{max(load_medians):>15.3f}{total_params:>8}")
    print(f"total independent parameters over {len(names)} types: {total_params}")
    ok = max(gen_medians) <= 50 and max(load_medians) <= 0.3
    print(f"goals (median generation <= 50 ms, median load <= 0.3 s): {'met' if ok else 'NOT met'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
