"""scripts/imitation/imitation_round.py: one round of the growing imitation dataset end to end on the CPU
(two train tasks, a tiny MLP, one val task), its record, status, curve and choice rule."""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pytest

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]
# Few, small batches; the shipped MLP's network (the round goes on from its weights).
TINY = "--batch-size 8 --warmup 1 --val-every 10000 --log-every 1 --ckpt-every 10000"


@pytest.fixture(scope="module")
def rounds():
    return import_script(ROOT / "scripts/imitation/imitation_round.py")


def _shipped(**successes) -> dict:
    return {"validation_success": [{"method": m.replace("_", "-"), "successes": n, "first_task": "val/0000",
                                    "last_task": "val/0099"} for m, n in successes.items()]}


def test_the_choice_compares_the_methods_the_shipped_one_was_judged_in(rounds):
    tasks = (0, 100)
    candidate = {"e2e-act": 12, "cgn-imit-act": 33}
    # The shipped one has a hybrid figure only: the hybrid decides (33 < 34: it stays).
    choice = rounds.choose(candidate, _shipped(cgn_imit_act=34), tasks)
    assert not choice["ships"] and choice["compared"] == {"cgn-imit-act": [33, 34]}
    # Both figures: summed (12 + 33 > 5 + 35).
    assert rounds.choose(candidate, _shipped(e2e_act=5, cgn_imit_act=35), tasks)["ships"]
    assert not rounds.choose(candidate, _shipped(e2e_act=10, cgn_imit_act=35), tasks)["ships"]  # a tie stays
    # Figures of other tasks do not count; nothing to compare with: the candidate ships.
    assert rounds.choose(candidate, _shipped(cgn_imit_act=34), (0, 50))["ships"]
    assert rounds.choose(candidate, {}, tasks)["ships"]


def test_a_missing_shipped_checkpoint_stops_the_round_instead_of_shipping_unjudged(rounds, tmp_path, monkeypatch):
    # Every kind ships with the package: without its checkpoint the choice has nothing to
    # compare with, and shipping the candidate unjudged would replace a better one.
    import fetchbench_ms.policies.deploy as deploy

    assert rounds.shipped("act")[0].is_file()
    monkeypatch.setattr(deploy, "default_checkpoint", lambda kind: tmp_path / f"imit_{kind}.pt")
    with pytest.raises(SystemExit, match="imit_act.json is missing"):
        rounds.shipped("act")


def test_a_plateau_is_two_rounds_without_a_better_val_success(rounds):
    def entry(rate):
        return {"kinds": {"mlp": {"val": {"e2e-mlp": {"success_rate": rate}}}}}

    assert not rounds.plateau({"rounds": [entry(0.1), entry(0.2), entry(0.2)]})
    assert rounds.plateau({"rounds": [entry(0.1), entry(0.2), entry(0.2), entry(0.15)]})
    assert not rounds.plateau({"rounds": [entry(0.1), entry(0.2), entry(0.2), entry(0.25)]})


def test_bad_arguments_are_one_line_errors(rounds, tmp_path, capsys):
    record = ["--record", str(tmp_path / "rec"), "--work", str(tmp_path / "w")]
    for argv, words in ((["--kinds", "mlp,rnn"], "distinct kinds"), (["--val-tasks", "0:20"], "at least 100"),
                        (["--steps", "mlp=0"], "KIND=N"), (["--gpus", "x"], "GPU indices")):
        with pytest.raises(SystemExit) as stop:
            rounds.main(record + argv)
        assert stop.value.code != 0
        assert words in str(stop.value.code) + capsys.readouterr().err
    with pytest.raises(SystemExit, match="nothing to plot"):
        rounds.main(["--record", str(tmp_path / "rec"), "--plot", str(tmp_path / "x.png")])
    assert not (tmp_path / "w").exists()  # nothing written before the arguments are checked


def test_a_round_end_to_end_on_the_cpu(rounds, tmp_path, capsys):
    """Two train tasks -> demos -> composed_pointcloud frames -> a tiny MLP -> e2e and hybrid on a
    val task -> the record; the status and the curve come from the record alone."""
    record = tmp_path / "rec"
    argv = ["--record", str(record), "--work", str(tmp_path / "work"), "--tasks", "2", "--per-task", "1",
            "--procs", "2", "--gpus", "cpu", "--kinds", "mlp", "--steps", "mlp=3", "--trainer-args", TINY,
            "--val-tasks", "0:1", "--allow-small-val"]
    assert rounds.main(argv) == 0
    data = json.loads((record / "rounds.json").read_text())
    assert data["obs_mode"] == "composed_pointcloud" and data["frame_stride"] == 3
    (entry,) = data["rounds"]
    assert entry["round"] == 1 and entry["tasks"] == [0, 2] and entry["small_val"]
    assert entry["demos"] >= 1 and entry["frames"] > 0 and len(entry["data_sha256"]) == 64
    assert entry["machine"] == f"{os.cpu_count()} cores"  # a CPU round names no GPU
    mlp = entry["kinds"]["mlp"]
    # The shipped MLP reads composed_pointcloud: the round goes on from it, on its new demos.
    shipped = json.loads((ROOT / "assets/checkpoints/imit_mlp.json").read_text())
    assert mlp["init_from"]["path"] == "assets/checkpoints/imit_mlp.pt.planes.xz"
    assert mlp["steps"] == [shipped["step"], shipped["step"] + 3]
    assert mlp["demos_seen"] == shipped["demos_seen"] + entry["demos"]
    assert set(mlp["val"]) == {"e2e-mlp", "cgn-imit-mlp"} and all(v["tasks"] == 1 for v in mlp["val"].values())
    assert not mlp["shipped"]  # no --ship: the shipped checkpoints stay as they are
    # The shipped checkpoint has no val figures on these tasks: it is judged on them alike.
    assert set(mlp["shipped_val"]) == {"e2e-mlp", "cgn-imit-mlp"}
    assert set(mlp["choice"]["compared"]) == {"e2e-mlp", "cgn-imit-mlp"}
    export = tmp_path / "work/round_01/export/imit_mlp.json"
    assert json.loads(export.read_text())["obs_mode"] == "composed_pointcloud"
    for method in ("e2e-mlp", "cgn-imit-mlp"):  # the runs record the obs mode their policy read
        line = (tmp_path / "work/round_01/val" / method / "results.jsonl").read_text().splitlines()[0]
        assert json.loads(line)["policy_obs_mode"] == "composed_pointcloud", method
    # the hybrid plans its approach with the counts of the earlier rounds' val figures
    hybrid = json.loads((tmp_path / "work/round_01/val/cgn-imit-mlp/run.json").read_text())
    assert hybrid["method_options"]["planner_options"] == {"trajopt_counts": rounds.HYBRID_TRAJOPT_COUNTS}
    # The same round again in the same work folder (a round stopped after its val): nothing is
    # trained or exported again, so the val records still name the exported file's bytes.
    pt = tmp_path / "work/round_01/export/imit_mlp.pt"
    before = pt.read_bytes()
    (record / "rounds.json").rename(record / "first.json")
    assert rounds.main(argv) == 0
    assert pt.read_bytes() == before
    sha = hashlib.sha256(before).hexdigest()
    for method in ("e2e-mlp", "cgn-imit-mlp"):
        lines = (tmp_path / "work/round_01/val" / method / "results.jsonl").read_text().splitlines()
        assert len(lines) == 1 and json.loads(lines[0])["checkpoint_sha256"] == sha, method
    capsys.readouterr()
    assert rounds.main(["--record", str(record), "--status"]) == 0
    out = capsys.readouterr().out
    assert "round 1: train tasks 0:2" in out and "e2e-mlp" in out and "no plateau" in out
    png = tmp_path / "curve.png"
    assert rounds.main(["--record", str(record), "--plot", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    # The next round takes the next tasks.
    assert rounds.next_tasks(data, 5) == (2, 7)


def test_the_cost_tables_of_the_docs_are_their_records(rounds):
    """docs/imitation-rounds.md's cost block is what `imitation_round.py --costs` prints from the
    shipped records (a figure without its record, or a stale one, fails here)."""
    page = (ROOT / "docs/imitation-rounds.md").read_text()
    block = page.split("<!-- imitation-costs:begin -->\n")[1].split("\n<!-- imitation-costs:end -->")[0]
    assert block == rounds.costs_block()
