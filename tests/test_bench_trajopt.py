"""bench_trajopt.py's phase table (``--phases``): a plan's phases by searched problem one at a
time, by batch batched (the batch's shared phases once, its problems' own summed)."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

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


def test_kernel_profile_tables_the_searched_plans_operators(tmp_path):
    """--kernel-profile plans the searched problems again under torch.profiler and writes the
    operator table (on a CPU the aten operators; on CUDA their kernels too), most time first;
    problems the straight segment solved are left out."""
    import numpy as np

    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.demo_worlds import hand_pose, shelf_worlds
    from fetchbench_ms.planning.ik import solve_ik
    from fetchbench_ms.planning.robot import Q_DEFAULT, panda

    bench = import_script(ROOT / "scripts/bench/bench_trajopt.py")
    checker = CollisionChecker(panda(), shelf_worlds()[0])
    goals = solve_ik(checker.robot, hand_pose([0.68, -0.1, 0.12]), checker=checker, q_seed=Q_DEFAULT, n_seeds=32,
                     rng=np.random.default_rng(1))
    problem = dict(checker=checker, q_start=Q_DEFAULT, q_goals=goals.q[:2], start_tolerance=0.0)
    rows = {"rrtconnect": [PlanResult("solved", None, 0.0, 0), PlanResult("direct", None, 0.0, 0)]}
    out = tmp_path / "kernels.txt"
    small = dict(seeds=2, mppi_iters=1, mppi_particles=2, opt_iters=10, rrt_fallback=False)
    bench.write_kernel_profile([problem, problem], rows, "cpu", small, str(out))
    text = out.read_text()
    head, table = text.split("\n", 2)[1], text.split("\n", 2)[2]
    assert "on cpu; 1 searched plans one at a time" in head and "sorted by self_cpu_time_total" in head
    assert "aten::" in table and "Self CPU" in table
    calls = int(head.split(" profiled calls")[0].rsplit(" ", 1)[1])
    assert calls > 1000  # a plan is thousands of small operators: what a GPU launches one by one


def test_show_reprints_a_records_figures_and_phases(capsys):
    """--show JSON: the figures docs/trajopt-speed.md quotes, from the shipped record."""
    bench = import_script(ROOT / "scripts/bench/bench_trajopt.py")
    bench.show_records([str(ROOT / "results/planning/bench-trajopt-h200-val20-b16-phases-cuda-graph.json")])
    out = capsys.readouterr().out
    assert "config {'cuda_graph': True}" in out and "searched median 0.909 s" in out
    assert "particles 0.096, adam 0.665" in out and "phases_sum 2.305" in out


def test_config_items_parse_literals_booleans_and_bare_words():
    """--config NAME=VALUE: Python literals, true/false, a bare word as a string; an unknown
    field, or a value the config refuses, is one line naming the valid ones."""
    bench = import_script(ROOT / "scripts/bench/bench_trajopt.py")
    got = bench.config_overrides(["seeds=8", "cuda_graph=true", "compile_backend=inductor", "graph_capacity=(8, 4, 16)"])
    assert got == {"seeds": 8, "cuda_graph": True, "compile_backend": "inductor", "graph_capacity": (8, 4, 16)}
    with pytest.raises(SystemExit, match="unknown TrajoptConfig field 'nope'; valid: .*compile_backend"):
        bench.config_overrides(["nope=1"])
    with pytest.raises(SystemExit, match="bad --config: unknown graph_pool 'own'; valid: shared, loop"):
        bench.config_overrides(["graph_pool=own"])
    assert bench.config_overrides(["certify=0.005", "graph_pool=loop"]) == {"certify": 0.005, "graph_pool": "loop"}


def test_the_checker_bench_times_the_segments_the_planners_check():
    """bench_checker.py: a problem's segments densified at the planners' 0.02 rad (start and
    goal included, one run per goal), every configuration checked in each timed pass."""
    import numpy as np

    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.demo_worlds import shelf_worlds
    from fetchbench_ms.planning.robot import Q_DEFAULT, panda

    bench = import_script(ROOT / "scripts/bench/bench_checker.py")
    goals = np.stack([Q_DEFAULT + 0.09, Q_DEFAULT - 0.05])
    q = bench.segment_configs(dict(q_start=Q_DEFAULT, q_goals=goals))
    assert len(q) == 6 + 4  # 0.09 rad in 5 steps, 0.05 in 3 (with both ends)
    assert np.allclose(q[0], Q_DEFAULT) and np.allclose(q[5], goals[0]) and np.allclose(q[-1], goals[1])
    checker = CollisionChecker(panda(), shelf_worlds()[0])
    assert bench.configs_per_second(checker, q, batch=4, repeats=2) > 0
    assert checker.n_checked == 2 * len(q)


def test_the_throughput_bench_plans_every_problem_and_counts_the_wall_time_of_all_workers(shelf_problem):
    """bench_trajopt_throughput.py: a pass plans every problem in order, batch by batch, with
    the same plans each pass (counts, not time); throughput is all workers' problems over
    the span from the first timed start to the last end."""
    import numpy as np

    from fetchbench_ms.planning.robot import Q_DEFAULT
    from fetchbench_ms.planning.trajopt import TrajoptConfig

    bench = import_script(ROOT / "scripts/bench/bench_trajopt_throughput.py")
    checker, _, goals = shelf_problem
    near = Q_DEFAULT + 0.05
    problems = [dict(checker=checker, q_start=Q_DEFAULT, q_goals=q, start_tolerance=0.0)
                for q in (goals[:2], near, goals[:2])]
    cfg = TrajoptConfig(n_waypoints=12, seeds=4, opt_iters=10, collision_substeps=2, rrt_fallback=False, device="cpu")
    first, again = (bench.plan_pass(problems, cfg, batch=2, time_limit=300.0) for _ in range(2))
    assert [r.status for r in first] == [r.status for r in again] and first[1].status == "direct"
    assert first[0].success and all(np.array_equal(a.path, b.path) for a, b in zip(first, again) if a.success)
    parts = [dict(problems=3, solved=3, searched=2, start=10.0, end=12.0, same_as_warm=True),
             dict(problems=5, solved=4, searched=1, start=10.5, end=14.0, same_as_warm=True)]
    out = bench.aggregate(parts)
    assert out["problems"] == 8 and out["seconds"] == 4.0 and out["problems_per_s"] == 2.0
    assert out["success"] == 7 / 8 and out["searched"] == 3 and out["same_as_warm"]
    assert not bench.aggregate([dict(parts[0], same_as_warm=False), parts[1]])["same_as_warm"]


def test_records_say_the_counts_they_planned_with():
    """A record names the optimiser's counts even when its flags set none: the defaults' counts
    are a fact of the code, not of the record."""
    bench = import_script(ROOT / "scripts/bench/bench_trajopt.py")
    assert bench.counts_of({}) == "8x40x2"
    assert bench.counts_of(bench.config_overrides(["seeds=16", "opt_iters=80", "collision_substeps=3",
                                                   "world_grid=0.015"])) == "16x80x3"


def test_the_world_grid_bench_bakes_uncached_and_the_same_values_at_any_chunk():
    """``bench_world_grid.bake_ms`` measures a real bake each time (the world's cache is not
    read nor left filled), restores ``BAKED_CHUNK``, and two chunk sizes bake equal grids."""
    from fetchbench_ms.planning import distance
    from fetchbench_ms.planning.demo_worlds import shelf_worlds

    bench = import_script(ROOT / "scripts/bench/bench_world_grid.py")
    world, _ = shelf_worlds()
    chunks = dict(distance.BAKED_CHUNK)
    device = torch.device("cpu")
    ms_a, a, peak = bench.bake_ms(world, (), 0.05, device, 1 << 10, 24)
    ms_b, b, _ = bench.bake_ms(world, (), 0.05, device, 1 << 14, 24)
    assert torch.equal(a, b) and a.shape == tuple(distance.grid_shape(0.05))
    assert ms_a > 0 and ms_b > 0 and peak == 0
    assert distance.BAKED_CHUNK == chunks and "_baked_grids" not in world.__dict__
    assert (a < distance.GRID_TRUNCATION).any() and (a == distance.GRID_TRUNCATION).any()  # near and far vertices
