"""The report: built from small results directories with known records, its tables must
say what the records say; several directories compare side by side."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from fetchbench_ms.cli import main
from fetchbench_ms.evaluation import ResultsStore
from fetchbench_ms.evaluation.metrics import summarize, wilson_interval
from fetchbench_ms.evaluation.report import build_report, sample_failures

PHASES = ("ik_found", "pregrasp_plan", "approach_reached", "grasped", "retrieval_plan", "held_at_end")


def record(i: int, category: str, scene_type: str, reached: int, success: bool, failure=None, time=1.0, clen=2.0):
    """A task record whose first ``reached`` pipeline phases were reached."""
    return {"task_id": f"s/{i:04d}", "seed": i, "env_id": "FetchBench-v0", "method": "m", "success": success,
            "failure": None if success else failure, "category": category, "scene_type": scene_type,
            "target_object": f"blob/{i}", "computation_time": time, "cspace_length": clen,
            "phases": {p: k < reached for k, p in enumerate(PHASES)}}


def write_run(root: Path, method: str, records: list[dict]) -> Path:
    store = ResultsStore(root)
    store.open_run({"method": method, "source": "env:FetchBench-v0", "source_sha256": None,
                    "method_options": {"retries": 1}, "selection": {}})
    for r in records:
        store.append({**r, "method": method})
    return root


RUN_A = [
    record(0, "on_table", "Desk", 6, True, time=1.0, clen=3.0),
    record(1, "on_table", "Desk", 6, True, time=2.0, clen=5.0),
    record(2, "on_shelf", "LargeShelf", 1, False, "motion_planning_failure", time=9.0, clen=0.5),
    record(3, "on_shelf", "LargeShelf", 4, False, "grasp_failure", time=3.0, clen=4.0),
    record(4, "in_drawer", "Drawer", 0, False, "no_grasp_candidate", time=0.5, clen=0.0),
    {**record(5, "in_basket", "Desk", 0, False), "failure": "error", "computation_time": None,
     "cspace_length": None, "phases": None,
     "error": {"kind": "timeout", "message": "ran past the task time limit of 600 s", "traceback": ""}},
]
RUN_B = [record(i, "on_table", "Desk", 6, i % 2 == 0, "collision") for i in range(4)]


@pytest.fixture
def runs(tmp_path):
    return write_run(tmp_path / "a", "ga-mesh-rrt", RUN_A), write_run(tmp_path / "b", "idle", RUN_B)


def test_summary_numbers(runs):
    s = summarize(RUN_A)
    assert s["all"]["tasks"] == 6 and s["all"]["successes"] == 2 and s["all"]["errors"] == 1
    assert s["all"]["success_rate"] == round(2 / 6, 4)
    assert s["by_category"]["on_table"]["success_rate"] == 1.0
    assert list(s["by_category"]) == ["on_table", "on_shelf", "in_drawer", "in_basket"]
    assert s["by_scene_type"]["LargeShelf"]["failures"] == {"motion_planning_failure": 1, "grasp_failure": 1}
    assert s["all"]["median_computation_time"] == 2.0  # the errored task is left out
    funnel = s["all"]["funnel"]
    assert [funnel[k] for k in ("ik_found", "pregrasp_plan", "approach_reached", "grasped", "retrieval_plan")] == \
        [round(x / 6, 4) for x in (4, 3, 3, 3, 2)]
    assert funnel["success"] == round(2 / 6, 4)
    assert s["all"]["median_cspace_length_successes"] == 4.0  # of tasks 0 and 1


def test_first_try_rate_and_interval():
    # With --retries a success on a later try counts in the success rate, not the first-try one.
    retried = [{**record(i, "on_table", "Desk", 6, i < 3), "attempts": a} for i, a in enumerate((1, 1, 3, 5))]
    s = summarize(retried)["all"]
    assert s["success_rate"] == 0.75 and s["first_try_success_rate"] == 0.5
    lo, hi = s["success_ci95"]
    assert lo < 0.75 < hi and 0 <= lo and hi <= 1
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0
    # The usual figure: 246 of 600 is 0.41 +- about 0.04.
    lo, hi = wilson_interval(246, 600)
    assert abs(lo - 0.371) < 0.002 and abs(hi - 0.450) < 0.002


def test_report_tables_match_the_records(runs):
    page = build_report([runs[0]], runs[0] / "report", render=False)
    text = page.read_text()
    category_table = re.search(r'<table class="by_category">(.*?)</table>', text).group(1)
    # The method's row: on_table 2/2, on_shelf 0/2, in_drawer 0/1, in_basket 0/1, all 2/6.
    cells = re.findall(r"\((\d+)/(\d+)\)", category_table)
    assert cells == [("2", "2"), ("0", "2"), ("0", "1"), ("0", "1"), ("2", "6")]
    assert "33.3%" in category_table
    failures = re.search(r'<table class="failures">(.*?)</table>', text).group(1)
    for name in ("no_grasp_candidate", "motion_planning_failure", "grasp_failure", "error"):
        assert name in failures
    funnel = re.search(r'<table class="funnel">(.*?)</table>', text).group(1)
    assert re.findall(r"([\d.]+)%", funnel) == ["66.7", "50.0", "50.0", "50.0", "33.3", "33.3"]
    for png in ("success_by_category.png", "success_by_scene_type.png", "failures.png", "funnel.png",
                "computation_time.png", "cspace_length.png"):
        data = (page.parent / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
        assert f"src='{png}'" in text
    # The gallery shows failures of every class, the timeout with its message.
    assert "ran past the task time limit" in text
    assert text.count("<div class='card'>") == 4


def test_report_and_tables_give_the_c_space_median_of_the_successes(runs):
    """One definition of the C-space length column (the successes' median, 4.0 here; over
    every task that ran it would be 3.0), named as the results table names it."""
    from fetchbench_ms.evaluation.metrics import format_table

    page = build_report([runs[0]], runs[0] / "report", render=False)
    category_table = re.search(r'<table class="by_category">(.*?)</table>', page.read_text()).group(1)
    assert "median C-space length (successes, rad)" in category_table
    row = re.findall(r"<td>([^<]*)</td>", category_table)
    assert row[-1] == "4.00" and "3.00" not in row
    text = format_table(summarize(RUN_A))
    assert "med C-len (succ)" in text.splitlines()[0]
    assert text.splitlines()[-1].split()[5] == "4.00"  # all: tasks, success, errors, time, C-len


def test_comparing_two_runs_side_by_side(runs, tmp_path, capsys):
    out = tmp_path / "cmp"
    assert main(["report", str(runs[0]), str(runs[1]), "--out", str(out), "--no-render"]) == 0
    text = (out / "index.html").read_text()
    table = re.search(r'<table class="by_category">(.*?)</table>', text).group(1)
    rows = re.findall(r"<tr><td>(.*?)</td>", table)
    assert rows == ["ga-mesh-rrt", "idle"]
    idle_row = table.split("<tr><td>idle</td>")[1]
    assert re.findall(r"\((\d+)/(\d+)\)", idle_row)[0] == ("2", "4")
    scene_table = re.search(r'<table class="by_scene_type">(.*?)</table>', text).group(1)
    assert "<th>ga-mesh-rrt</th><th>idle</th>" in scene_table


def test_sample_failures_cycle_through_classes():
    picked = sample_failures(RUN_A, 3)
    assert [r["failure"] for r in picked] == ["motion_planning_failure", "grasp_failure", "no_grasp_candidate"]


def test_gallery_renders_the_start_of_a_failed_task(tmp_path):
    """Seed-mode record: the env rebuilds the task from its seed and both cameras are drawn."""
    root = write_run(tmp_path / "r", "idle", [{**record(0, "on_shelf", "LargeShelf", 0, False, "not_attempted"),
                                               "task_id": "FetchBench-Shelf-v0/seed-3", "seed": 3,
                                               "env_id": "FetchBench-Shelf-v0"}])
    page = build_report([root], gallery=1)
    images = list(page.parent.glob("start_*.png"))
    assert len(images) == 1
    from PIL import Image
    import numpy as np

    image = np.asarray(Image.open(images[0]))
    assert image.shape == (240, 640, 3) and image.std() > 10  # two 320x240 views, not blank
    # The target is outlined in a view that sees it.
    from fetchbench_ms.evaluation.report import TARGET_OUTLINE

    assert (image == TARGET_OUTLINE).all(axis=-1).sum() > 20


def test_outline_target_draws_around_the_mask_only():
    from fetchbench_ms.evaluation.report import TARGET_OUTLINE, outline_target
    import numpy as np

    rgb = np.full((10, 10, 3), 7, np.uint8)
    mask = np.zeros((10, 10), bool)
    mask[4:6, 4:6] = True
    out = outline_target(rgb, mask, width=1)
    drawn = (out == TARGET_OUTLINE).all(axis=-1)
    assert drawn.sum() == 8 and not (drawn & mask).any() and (out[mask] == 7).all()


@pytest.mark.slow
def test_demo_evaluates_and_reports(tmp_path, capsys):
    """The main job on two smoke tasks: the table is printed and the report written."""
    assert main(["demo", "--tasks", "0:2", "--workers", "1", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "ga-mesh-rrt on the 'smoke' suite" in out and "all" in out
    assert len((tmp_path / "results" / "results.jsonl").read_text().splitlines()) == 2
    assert (tmp_path / "report" / "index.html").exists()


def test_paper_row_goes_to_the_paper_variant_only():
    """The paper's figure stands beside a run of its variant: not one with env or planner options."""
    from fetchbench_ms.evaluation.report import Run, paper_reference

    def run(**options) -> Run:
        manifest = {"method": "cgn-ptd-mppi", "method_options": {"pipeline": "paper", **options}}
        return Run("cgn-ptd-mppi", Path("."), manifest, [], {})

    assert paper_reference(run())[0] == 0.121  # CGN-Cabinet
    assert paper_reference(run(env_options={"sim_freq": 60})) is None
    assert paper_reference(run(planner_options={"mppi_goal_region": 0})) is None


def test_report_of_a_run_where_every_task_errored_warns_nothing(tmp_path):
    import warnings

    errored = [{**r, "failure": "error", "computation_time": None, "cspace_length": None, "phases": None,
                "success": False, "error": {"kind": "exception", "message": "boom", "traceback": ""}}
               for r in RUN_B]
    root = write_run(tmp_path / "e", "idle", errored)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        build_report([root], root / "report", render=False)
    assert not [str(w.message) for w in caught if "legend" in str(w.message).lower()]
