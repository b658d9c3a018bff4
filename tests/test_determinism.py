"""Generated assets rebuild to the shipped bytes, also on other CPUs' floating-point paths.

NumPy and OpenBLAS pick their SIMD kernels from the CPU at run time; switching the
newer ones off (``NPY_DISABLE_CPU_FEATURES``, ``OPENBLAS_CORETYPE``) makes this machine
compute as an AVX2-only or SSE4-only one would. docs/determinism.md has the measurements.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys

from fetchbench_ms import determinism

#: Objects that had machine-dependent stable poses before catalog version 2 (ties between
#: symmetric facets, 180-degree poses), and one of each other source.
HARD_OBJECTS = ["procedural/ball/0000", "procedural/ball/0123", "procedural/block/0000", "procedural/box/0000",
                "procedural/can/0000", "procedural/soap_bar/0099", "procedural/pill_bottle/0144", "blob/000", "ycb/025_mug"]
SCENE_SEEDS = 2


def _digests() -> dict:
    objects, _ = determinism.rebuild_objects(HARD_OBJECTS)
    scenes, _ = determinism.rebuild_scenes(SCENE_SEEDS, suites=())
    return {"objects": {k: determinism._digest(v) for k, v in objects.items()}, "scenes": scenes}


def test_a_sample_of_every_kind_of_shipped_asset_rebuilds_byte_for_byte():
    """Objects with stable poses, every scene of the shipped suites, and the first
    arrangement of two test-suite scenes (placed and settled in physics again)."""
    ids = determinism.sample_object_ids(per_source=1) + HARD_OBJECTS
    _, object_mismatches = determinism.rebuild_objects(sorted(set(ids)))
    scenes, scene_mismatches = determinism.rebuild_scenes(0)
    arrangements, suite_mismatches = determinism.rebuild_suite_arrangements(2)
    assert len(scenes) >= 100 and len(arrangements) == 2
    assert object_mismatches + scene_mismatches + suite_mismatches == []


def test_other_cpu_feature_levels_give_the_same_bytes():
    from numpy._core._multiarray_umath import __cpu_features__

    newer = [f for f in ("X86_V3", "X86_V4", "AVX512_ICL", "AVX512_SPR") if __cpu_features__.get(f)]
    here = _digests()
    for disabled, coretype in ((newer, "Nehalem"), ([f for f in newer if f != "X86_V3"], "Haswell")):
        env = {**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(disabled), "OPENBLAS_CORETYPE": coretype}
        code = "import json, test_determinism as t; print(json.dumps(t._digests()))"
        out = subprocess.run([sys.executable, "-c", code], env=env, cwd=os.path.dirname(__file__),
                             capture_output=True, text=True, check=True).stdout
        assert json.loads(out.splitlines()[-1]) == here, (disabled, coretype)
