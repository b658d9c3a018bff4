"""bench_trajopt.py's phase table (``--phases``): a plan's phases by searched problem one at a
time, by batch batched (the batch's shared phases once, its problems' own summed)."""
from __future__ import annotations

from pathlib import Path

import pytest

from fetchbench_ms.planning.rrt import PlanResult
from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]


def _result(status: str, **phase_s) -> PlanResult:
    return PlanResult(status, None, 0.0, 0, extras={"phase_s": phase_s})


def test_phase_medians_per_problem_and_per_batch():
    bench = import_script(ROOT / "scripts/bench/bench_trajopt.py")
    shared = dict(world=0.1, seeds=0.0, particles=1.0, adam=2.0, final_costs=0.2, to_host=0.0, batch_size=2)
    one = _result("solved", prepare=0.5, select=0.3, **shared)
    other = _result("trajopt+rrtconnect", prepare=0.1, select=0.1, fallback=4.0, **shared)
    direct = _result("direct", prepare=9.0)
    batch = bench.phase_record([one, direct, other])
    assert batch["prepare"] == pytest.approx(0.6) and batch["fallback"] == 4.0  # the problems' own, summed
    assert batch["adam"] == 2.0 and "batch_size" not in batch  # shared: once
    assert bench.phase_record([direct]) is None and bench.phase_record([PlanResult("solved", None, 0.0, 0)]) is None
    one_at_a_time, n = bench.phase_medians("trajopt", [one, direct, other])
    assert n == 2 and one_at_a_time["fallback"] == 2.0 and one_at_a_time["adam"] == 2.0
    assert one_at_a_time["phases_sum"] == pytest.approx((4.1 + 7.5) / 2)
    one.extras["batch_phase_s"] = batch  # run_planners: one record per batch, on its first result
    medians, n = bench.phase_medians("trajopt batch 4", [one, direct, other])
    assert n == 1 and medians == dict(batch, phases_sum=sum(batch.values()))
    assert bench.phase_medians("rrtconnect", [PlanResult("solved", None, 0.0, 0)]) is None
