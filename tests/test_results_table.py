"""The shipped records and their tables: docs/results.md holds exactly what `fetchbench results
table` prints; pack + table on a small run give the expected figures; pack refuses bad input;
the packed bytes are reproducible."""
from __future__ import annotations

import gzip
import json
import lzma
import os
from pathlib import Path

from fetchbench_ms.cli import main
from fetchbench_ms.evaluation import ResultsStore
from fetchbench_ms.evaluation.results_table import BEGIN, END, load_runs, pack, pipeline_label, tables
from fetchbench_ms.solutions.sense_plan_act import IMPROVEMENTS

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "results.md"
PHASES = ("ik_found", "pregrasp_plan", "approach_reached", "grasped", "retrieval_plan", "held_at_end")


def record(task_id: str, category: str, reached: int, success: bool, failure=None, time=1.0, clen=2.0):
    return {"task_id": task_id, "seed": 1, "env_id": "FetchBench-v0", "method": "ga-mesh-rrt",
            "scene_type": "Desk", "category": category, "target_object": "blob/1", "success": success,
            "failure": None if success else failure, "computation_time": time, "cspace_length": clen,
            "phases": {p: k < reached for k, p in enumerate(PHASES)}, "attempts": 1}


def make_run(root: Path, records: list[dict], method="ga-mesh-rrt", options=None, tasks="0:2",
             source="suite.json", source_sha256="ab" * 32) -> Path:
    store = ResultsStore(root)
    store.open_run({"method": method, "source": source, "source_sha256": source_sha256,
                    "method_options": options or {"retries": 1}, "selection": {"suite": "test", "tasks": tasks}})
    for r in records:  # appended out of task order: the pack sorts them
        store.append({**r, "method": method})
    return root


TWO = [record("test/0001", "on_shelf", 2, False, "motion_planning_failure", time=3.0, clen=0.5),
       record("test/0000", "on_table", 6, True, time=1.0, clen=4.0)]


def test_docs_table_is_the_commands_output(capsys):
    """The check: docs/results.md's tables are `fetchbench results table`'s output."""
    assert main(["results", "table"]) == 0
    output = capsys.readouterr().out
    text = DOC.read_text()
    assert text.count(BEGIN) == 1 and text.count(END) == 1
    assert text.split(BEGIN + "\n", 1)[1].split(END, 1)[0] == output
    assert main(["results", "table", "--check", str(DOC)]) == 0


def test_check_names_the_first_differing_line(tmp_path, capsys):
    runs = tmp_path / "runs"
    pack(make_run(tmp_path / "a", TWO), "a-test2", runs)
    doc = tmp_path / "doc.md"
    doc.write_text(f"# T\n\n{BEGIN}\nold\n{END}\nafter\n")
    assert main(["results", "table", "--runs-dir", str(runs), "--check", str(doc)]) == 1
    assert f"{doc}:4: differs" in capsys.readouterr().err
    assert main(["results", "table", "--runs-dir", str(runs), "--write", str(doc)]) == 0
    assert main(["results", "table", "--runs-dir", str(runs), "--check", str(doc)]) == 0
    assert doc.read_text().startswith(f"# T\n\n{BEGIN}\n### Runs") and doc.read_text().endswith(f"{END}\nafter\n")


def test_pack_and_table_round_trip(tmp_path, capsys):
    runs = tmp_path / "runs"
    assert main(["results", "pack", str(make_run(tmp_path / "a", TWO)), "--name", "ga-mesh-rrt-test2-legacy",
                 "--runs-dir", str(runs)]) == 0
    folder = runs / "ga-mesh-rrt-test2-legacy"
    assert sorted(p.name for p in folder.iterdir()) == ["results.jsonl.xz", "run.json"]
    lines = lzma.decompress((folder / "results.jsonl.xz").read_bytes()).decode().splitlines()
    assert [json.loads(line)["task_id"] for line in lines] == ["test/0000", "test/0001"]
    capsys.readouterr()
    assert main(["results", "table", "--runs-dir", str(runs)]) == 0
    out = capsys.readouterr().out
    assert "### Earlier runs (extended pipeline, wall-clock planning budgets)" in out
    row = next(line for line in out.splitlines() if line.startswith("| ga-mesh-rrt-test2-legacy"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[:5] == ["ga-mesh-rrt-test2-legacy", "`ga-mesh-rrt`", "legacy", "test 0:2", "2"]
    assert cells[5] == "**0.500** (0.095-0.905)"  # 1 of 2, 95% Wilson interval
    assert cells[6].startswith("0.529 (funnel 0.947 / 0.903 / 0.681)")  # the paper's GA-Mesh-RRTConnect
    assert cells[7:11] == ["1.000 (1)", "0.000 (1)", "-", "-"]
    assert cells[11:15] == ["1.000", "0.500", "0.500", "0.500"]  # approach plan, exec, retrieval plan, final
    assert cells[15:18] == ["0", "2.00 s", "4.00 rad"]
    assert cells[18] == "motion planning failure 1"


def test_current_runs_and_ablation(tmp_path):
    """Runs with a pipeline get the main table; each variant is set beside the `paper` run."""
    runs = tmp_path / "runs"
    ok = [record(f"test/{i:04d}", "on_table", 6, True) for i in range(4)]
    bad = [record(f"test/{i:04d}", "on_table", 1, False, "timeout") for i in range(4)]
    variants = {"paper": (ok[:3] + bad[3:], {}),  # 0.75
                "paper-60hz": (ok[:2] + bad[2:], {"env_options": {"sim_freq": 60}}),  # 0.50
                "ours": (ok, {"improvements": ["retreat", "extra_lifts", "start_escape", "cgn_filter"]}),  # 1.00
                "ours-minus-retreat": (ok[:1] + bad[1:], {"improvements": ["extra_lifts", "start_escape",
                                                                           "cgn_filter"]})}
    for name, (records, extra) in variants.items():
        pipeline = "ours" if name.startswith("ours") else "paper"
        pack(make_run(tmp_path / name, records, options={"retries": 1, "pipeline": pipeline, **extra}), name, runs)
    # the runner's own name of a variant reads the same
    assert pipeline_label({"method_options": {"pipeline": "ours-minus-retreat+cgn_filter"}}) == \
        "ours minus retreat, cgn_filter"
    out = tables(load_runs(runs))
    assert "Earlier runs" not in out and "| ours minus retreat |" in out and "| paper + sim_freq=60 |" in out
    assert "| 0.250 | 0.250 | 0.250 | 0.250 | 3 |" in out  # the timeouts column
    ablation = out.split("### Ablations")[1]
    # paper + env option: (0.75 - 0.50) / (0.75 - 0.529) of the gap, toward the paper
    assert "| paper-60hz | paper + sim_freq=60 | 0.500 | -25.0 | +113 % |" in ablation
    # ours minus X: its drop from ours, (1.00 - 0.25) / (1.00 - 0.529)
    assert "| ours-minus-retreat | ours minus retreat | 0.250 | -50.0 | +159 % |" in ablation
    assert "| ours | ours | 1.000 | +25.0 | - |" in ablation


def test_planner_option_runs_are_labelled_and_set_beside_the_paper_run(tmp_path):
    """A run with planner options is named by them (after the env options, sorted) and set
    beside the method's `paper`-variant run on the same tasks, with its share of the gap."""
    runs = tmp_path / "runs"
    ok = [record(f"test/{i:04d}", "on_table", 6, True) for i in range(4)]
    bad = [record(f"test/{i:04d}", "on_table", 1, False, "motion_planning_failure") for i in range(4)]
    variants = {"paper": (ok[:3] + bad[3:], {}),  # 0.75
                "paper-no-goal-credit": (ok[:2] + bad[2:], {"planner_options": {"mppi_goal_region": 0}}),  # 0.50
                "paper-60hz-distance": (ok[:1] + bad[1:], {"env_options": {"sim_freq": 60}, "planner_options": {
                    "mppi_goal_region": 0, "mppi_cost": "distance"}})}  # 0.25
    for name, (records, extra) in variants.items():
        options = {"grasp_model": "pretrained", "retries": 1, "pipeline": "paper", "improvements": [], **extra}
        pack(make_run(tmp_path / name, records, method="cgn-ptd-mppi", options=options), name, runs)
    out = tables(load_runs(runs))
    assert "| paper + mppi_goal_region=0 |" in out
    ablation = out.split("### Ablations")[1]
    # (0.75 - 0.50) / (0.75 - 0.121): the paper's CGN-Cabinet
    assert "| paper-no-goal-credit | paper + mppi_goal_region=0 | 0.500 | -25.0 | +40 % |" in ablation
    assert ("| paper-60hz-distance | paper + sim_freq=60 + mppi_cost=distance + mppi_goal_region=0 | 0.250 | "
            "-50.0 | +79 % |") in ablation


def test_runs_of_other_trajopt_counts_are_compared_only_with_their_own(tmp_path):
    """``trajopt_counts`` sets the planner's counts, not a factor of the pipeline: a run that
    names it is labelled by it and set beside the `paper` run of the same counts, never beside
    a run of the defaults (their difference would not be the pipeline's)."""
    runs = tmp_path / "runs"
    ok = [record(f"test/{i:04d}", "on_table", 6, True) for i in range(4)]
    bad = [record(f"test/{i:04d}", "on_table", 1, False, "motion_planning_failure") for i in range(4)]
    full = {"planner_options": {"trajopt_counts": "16x80x3"}}
    variants = {"paper": (ok[:2] + bad[2:], "paper", {}),  # 0.50
                "ours": (ok[:3] + bad[3:], "ours", {}),  # 0.75
                "paper-full": (ok[:1] + bad[1:], "paper", full),  # 0.25
                "ours-full": (ok, "ours", full),  # 1.00
                "ours-minus-retreat-full": (ok[:2] + bad[2:], "ours-minus-retreat", full)}  # 0.50
    for name, (records, pipeline, extra) in variants.items():
        improvements = [] if pipeline == "paper" else [i for i in IMPROVEMENTS if i not in pipeline]
        options = {"retries": 1, "pipeline": pipeline.split("-")[0], "improvements": improvements, **extra}
        pack(make_run(tmp_path / name, records, method="ga-mesh-trajopt", options=options), name, runs)
    out = tables(load_runs(runs))
    assert "| paper + trajopt_counts=16x80x3 |" in out and "| ours + trajopt_counts=16x80x3 |" in out
    rows = [line for line in out.split("### Ablations")[1].splitlines() if line.startswith("| `ga-mesh-trajopt`")]
    pairs = {(line.split(" | ")[2], line.split(" | ")[5]) for line in rows}
    assert pairs == {("paper", "ours"), ("paper-full", "ours-full"), ("paper-full", "ours-minus-retreat-full")}
    # ours minus retreat's share of the gap is taken against the ours run of its own counts
    assert "| ours-minus-retreat-full | ours minus retreat + trajopt_counts=16x80x3 | 0.500 | +25.0 | +152 % |" in out


def test_pack_refuses_bad_input(tmp_path, capsys):
    runs = tmp_path / "runs"
    (tmp_path / "empty").mkdir()
    cases = [([str(tmp_path / "missing")], "is not a directory"),
             ([str(tmp_path / "empty")], "not a results directory (no run.json)"),
             ([str(make_run(tmp_path / "none", []))], "holds no finished task"),
             ([str(make_run(tmp_path / "a", TWO)), "--name", "Bad Name"], "bad run name 'Bad Name'")]
    for args, message in cases:
        argv = ["results", "pack", *args] + ([] if "--name" in args else ["--name", "x"]) + ["--runs-dir", str(runs)]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    assert not runs.exists() or not any(runs.iterdir())
    # another run under a taken name: refused unless --force
    pack(make_run(tmp_path / "b", TWO), "taken", runs)
    assert pack(make_run(tmp_path / "b", TWO), "taken", runs) == runs / "taken"  # the same run: no change
    other = make_run(tmp_path / "c", TWO[:1])
    assert main(["results", "pack", str(other), "--name", "taken", "--runs-dir", str(runs)]) == 2
    assert "holds another run (its results.jsonl.xz differ)" in capsys.readouterr().err
    assert main(["results", "pack", str(other), "--name", "taken", "--runs-dir", str(runs), "--force"]) == 0
    assert len(ResultsStore(runs / "taken").records()) == 1
    assert [p.name for p in runs.iterdir()] == ["taken"]  # no staging folder left behind


def test_shards_of_one_run_pack_as_that_run(tmp_path, capsys):
    """A run split with --tasks over machines packs to the bytes of the same run made whole."""
    whole = pack(make_run(tmp_path / "whole", TWO), "r", tmp_path / "runs1")
    first, second = make_run(tmp_path / "s0", TWO[1:], tasks="0:1"), make_run(tmp_path / "s1", TWO[:1], tasks="1:2")
    assert main(["results", "pack", str(second), str(first), "--name", "r", "--runs-dir", str(tmp_path / "runs2")]) == 0
    for name in ("run.json", "results.jsonl.xz"):
        assert (whole / name).read_bytes() == (tmp_path / "runs2" / "r" / name).read_bytes()
    # the same suite file at another path (another machine's checkout) is the same run: its hash says so
    moved = make_run(tmp_path / "moved", TWO[:1], tasks="1:2", source="/elsewhere/suite.json")
    assert main(["results", "pack", str(first), str(moved), "--name", "r", "--runs-dir", str(tmp_path / "runs2")]) == 0
    assert "holds another run" not in capsys.readouterr().err
    gap = make_run(tmp_path / "gap", TWO[:1], tasks="2:3")
    edited = make_run(tmp_path / "edited", TWO[:1], tasks="1:2", source_sha256="cd" * 32)
    other = make_run(tmp_path / "other", TWO[:1], tasks="1:2", options={"retries": 5})
    overlap = make_run(tmp_path / "overlap", TWO[:1], tasks="0:2")
    for shards, message in [([first, gap], "leave a gap (tasks 1 and 2)"), ([first, overlap], "overlap"),
                            ([first, other], "is not a shard of the same run"),
                            ([first, edited], "(its source_sha256 differ)"),
                            ([first, make_run(tmp_path / "dup", TWO[1:], tasks="1:2")], "records of the same task")]:
        assert main(["results", "pack", *map(str, shards), "--name", "x", "--runs-dir", str(tmp_path / "runs3")]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "runs3").exists()


def test_packed_bytes_are_reproducible(tmp_path):
    a = pack(make_run(tmp_path / "a", TWO), "r", tmp_path / "runs1")
    b = pack(make_run(tmp_path / "b", TWO[::-1]), "r", tmp_path / "runs2")  # other append order, later mtime
    for name in ("run.json", "results.jsonl.xz"):
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert (a / "results.jsonl.xz").read_bytes()[:6] == b"\xfd7zXZ\0"  # xz: no name, no time in it


def test_a_run_packed_with_gzip_reads_and_repacks_to_xz(tmp_path):
    """A folder in the earlier form (``results.jsonl.gz``) reads as a run; packing the same
    run over it rewrites it in the present form without --force."""
    a = pack(make_run(tmp_path / "a", TWO), "r", tmp_path / "runs")
    lines = lzma.decompress((a / "results.jsonl.xz").read_bytes())
    (a / "results.jsonl.gz").write_bytes(gzip.compress(lines, mtime=0))
    (a / "results.jsonl.xz").unlink()
    assert [r["task_id"] for r in ResultsStore(a).records()] == ["test/0000", "test/0001"]
    assert [r.name for r in load_runs(tmp_path / "runs")] == ["r"]
    assert pack(make_run(tmp_path / "b", TWO), "r", tmp_path / "runs") == a
    assert sorted(p.name for p in a.iterdir()) == ["results.jsonl.xz", "run.json"]
    assert lzma.decompress((a / "results.jsonl.xz").read_bytes()) == lines


def test_packed_folder_follows_the_umask(tmp_path):
    """A packed run is readable by others where the umask says so (a staging folder from
    mkdtemp is 0700, and the rename would keep that)."""
    old = os.umask(0o022)
    try:
        run = pack(make_run(tmp_path / "a", TWO), "r", tmp_path / "runs")
    finally:
        os.umask(old)
    assert run.stat().st_mode & 0o777 == 0o755
    assert (run / "run.json").stat().st_mode & 0o777 == 0o644


def test_other_robots_get_their_own_paper_figure_and_are_compared_only_with_themselves(tmp_path):
    """A Kinova run is set beside the paper's "Other Manipulators" figure of its robot, never
    beside the Panda's, and its ablation pairs it with the same robot's `paper` run."""
    runs = tmp_path / "runs"
    ok = [record(f"test/{i:04d}", "on_table", 6, True) for i in range(2)]
    bad = [record(f"test/{i:04d}", "on_table", 1, False, "motion_planning_failure") for i in range(2)]
    for name, records, opts in (("panda-paper", ok, {"pipeline": "paper"}),
                                ("kinova-paper", ok[:1] + bad[1:], {"pipeline": "paper", "robot": "kinova_gen3_robotiq"}),
                                ("kinova-ours", ok, {"pipeline": "ours",
                                                     "robot": "kinova_gen3_robotiq"})):
        pack(make_run(tmp_path / name, records, method="ga-mesh-trajopt", options={"retries": 1, **opts}), name, runs)
    out = tables(load_runs(runs))
    main_table, ablation = out.split("### Ablations")
    kinova_row = next(line for line in main_table.splitlines() if line.startswith("| kinova-paper |"))
    assert "`ga-mesh-trajopt` on `kinova_gen3_robotiq`" in kinova_row and "| 0.471 |" in kinova_row
    assert "0.671" not in kinova_row
    panda_row = next(line for line in main_table.splitlines() if line.startswith("| panda-paper |"))
    assert "0.671 (funnel 0.865 / 0.861 / 0.776)" in panda_row
    assert "| kinova-paper | 0.500 | 0.471 | kinova-ours | ours | 1.000 | +50.0 |" in ablation
    assert "panda-paper | 1.000 | 0.671 | kinova" not in ablation


def test_task_times_compares_machine_kinds_on_the_tasks_they_share(tmp_path, capsys):
    """scripts/bench/task_times.py: per method, the median, p90 and mean seconds a task of each set,
    over the tasks every set has; a method missing from a set is left out; no common method
    exits 1 saying so."""
    from script_modules import load_script

    times = load_script(Path(__file__).resolve().parents[1] / "scripts/bench/task_times.py", "task_times")

    def run(name, walls, method="ga-mesh-rrt"):
        records = [{**record(f"test/{i:04d}", "on_table", 6, True), "wall_time": w} for i, w in enumerate(walls)]
        return make_run(tmp_path / name, records, method=method)

    laptop = [run("laptop-rrt", [3.0, 5.0, 7.0, 100.0]), run("laptop-mppi", [1.0], method="cgn-ptd-mppi")]
    node = [run("node-rrt", [1.0, 2.0, 3.0])]
    assert times.main(["--set", "laptop=" + ",".join(map(str, laptop)), "--set", f"node={node[0]}"]) == 0
    out = capsys.readouterr().out
    assert "| `ga-mesh-rrt` | 3 | 5.0 / 7.0 / 5.00 | 2.0 / 3.0 / 2.00 |" in out  # task 3 is the laptop's only
    assert "cgn-ptd-mppi" not in out
    assert times.main(["--set", f"laptop={laptop[1]}", "--set", f"node={node[0]}"]) == 1
    assert "nothing to compare" in capsys.readouterr().err


def test_evaluation_md_prints_task_times_table_as_the_records_give_it(capsys):
    """docs/evaluation.md's seconds-a-task table is `scripts/bench/task_times.py`'s output on
    the shipped repeatability records, verbatim: a record re-run without the table reprinted
    fails here."""
    from script_modules import load_script

    root = Path(__file__).resolve().parents[1]
    times = load_script(root / "scripts/bench/task_times.py", "task_times")
    assert times.main([]) == 0
    table = capsys.readouterr().out.strip()
    assert table.count("\n") >= 3 and table in (root / "docs/evaluation.md").read_text()
