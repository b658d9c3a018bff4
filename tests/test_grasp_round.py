"""scripts/grasp_round.py: one round of our CGN weights and the scene-collision network end to
end on the CPU (two train tasks, one view a task, few queries, a step or three from the shipped
weights, one val task), its record, resume, status, curve, the next slice, the choice rule and
shipping."""
from __future__ import annotations

import json
import lzma
from pathlib import Path

import pytest

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]
# Few points, grasps and queries; a step of the shipped CGN, three of the shipped collision net.
SMALL = ["--procs", "2", "--gpus", "cpu", "--cgn-steps", "1", "--collision-steps", "3", "--val-tasks", "0:1",
         "--allow-small-val", "--skip-pretrained",
         "--views-args", "--num-points 4096 --max-grasps 50 --views-per-task 1", "--labels-args", "--configs 200",
         "--cgn-args", "--batch-size 1 --val-views 2 --warmup-steps 1 --log-every 1",
         "--collision-args", "--scenes 1 --queries 64 --val-queries 100 --log-every 1 --val-every 1000"]


@pytest.fixture(scope="module")
def rounds():
    return import_script(ROOT / "scripts/grasp_round.py")


def test_the_choice_ships_a_strictly_better_val_score(rounds):
    cgn = {"precision_top1": 0.9, "precision_top10": 0.8}
    assert rounds.choose(cgn, {"precision_top1": 0.9, "precision_top10": 0.7}, rounds.cgn_score)["ships"]
    assert not rounds.choose(cgn, dict(cgn), rounds.cgn_score)["ships"]  # a tie keeps the shipped one
    assert rounds.choose(cgn, None, rounds.cgn_score)["ships"]  # nothing shipped to compare with
    assert not rounds.choose({"precision_top1": None}, cgn, rounds.cgn_score)["ships"]  # nothing judged
    # collision: accuracy minus the false-free share (a collision called free costs twice)
    better_acc = {"accuracy": 0.96, "false_free_of_all": 0.03}
    assert not rounds.choose(better_acc, {"accuracy": 0.95, "false_free_of_all": 0.015}, rounds.collision_score)["ships"]
    assert rounds.choose(better_acc, {"accuracy": 0.95, "false_free_of_all": 0.029}, rounds.collision_score)["ships"]


def test_a_plateau_is_two_rounds_without_a_better_val_score(rounds):
    assert not rounds.plateau([0.1, 0.2, 0.2])
    assert rounds.plateau([0.1, 0.2, 0.2, 0.15])
    assert not rounds.plateau([0.1, 0.2, 0.2, 0.25])


def test_ours_is_the_default_only_when_val_puts_both_precisions_at_or_above_pretrained(rounds):
    def record(ours: dict, shipped: bool = True) -> dict:
        pretrained = {"tasks": "0:50", "precision_top1": 0.88, "precision_top10": 0.90}
        cgn = {"shipped": shipped, "val": {"tasks": "0:50", **ours}}
        return {"pretrained_val": [pretrained], "rounds": [{"cgn": cgn}]}

    assert rounds.default_grasp_model(record({"precision_top1": 0.92, "precision_top10": 0.87}))[0] == "pretrained"
    assert rounds.default_grasp_model(record({"precision_top1": 0.88, "precision_top10": 0.90}))[0] == "ours"
    assert rounds.default_grasp_model(record({"precision_top1": 0.9, "precision_top10": 0.95}, shipped=False))[0] \
        == "pretrained"  # a candidate that did not ship is not the shipped weights
    # the CLI's default is the one the shipped record's val says
    shipped = json.loads((ROOT / "results/training/grasp-rounds/rounds.json").read_text())
    import argparse

    from fetchbench_ms.evaluation import cli
    commands = argparse.ArgumentParser().add_subparsers()
    cli.add_commands(commands)
    assert commands.choices["eval"].parse_args([]).grasp_model == rounds.default_grasp_model(shipped)[0]


def test_bad_arguments_are_one_line_errors_and_write_nothing(rounds, tmp_path):
    base = ["--record", str(tmp_path / "rec"), "--work", str(tmp_path / "w")]
    for argv, words in ((["--val-tasks", "0:20"], "at least 50"), (["--val-tasks", "5:2"], "START"),
                        (["--gpus", "x"], "GPU indices"), (["--tasks", "0"], ">= 1"),
                        (["--tasks", str(10**7)], "run past the train suite")):
        with pytest.raises(SystemExit) as stop:
            rounds.main(base + argv)
        message = str(stop.value.code)
        assert words in message and "\n" not in message and message.startswith("error:"), message
    with pytest.raises(SystemExit, match="nothing to plot"):
        rounds.main(["--record", str(tmp_path / "rec"), "--plot", str(tmp_path / "x.png")])
    assert not (tmp_path / "w").exists() and not (tmp_path / "rec").exists()


def test_a_round_end_to_end_on_the_cpu(rounds, tmp_path, capsys, monkeypatch):
    """Two train tasks -> CGN views and collision labels (and one val task's) -> both models a few
    steps on from the shipped weights -> physics-judged CGN precision and collision figures on
    the val task -> the record; resuming redoes no stage; the next round takes the next tasks."""
    record, work = tmp_path / "rec", tmp_path / "work"
    argv = ["--record", str(record), "--work", str(work), "--tasks", "2", *SMALL]
    assert rounds.main(argv) == 0
    data = json.loads((record / "rounds.json").read_text())
    (entry,) = data["rounds"]
    assert entry["round"] == 1 and entry["tasks"] == [0, 2] and entry["small_val"] and entry["gpus"] == "cpu"
    labels = entry["labels"]
    assert labels["cgn_views"]["tasks"] == 2 and labels["cgn_views"]["views"] >= 1
    assert labels["collision"]["queries"] == 400 and labels["collision_val"]["queries"] == 200
    assert all(len(labels[k]["sha256"]) == 64 and labels[k]["per_core_minute"] for k in labels)
    for name, source in (("cgn-views", "cgn_views"), ("collision-labels", "collision"),
                         ("collision-val", "collision_val")):  # the data manifests beside the record
        kept = json.loads(lzma.decompress((record / "round_01" / f"{name}-manifest.json.xz").read_bytes()))
        full = json.loads((work / "round_01" / source / "manifest.json").read_text())
        assert kept["sha256"] == full["sha256"] and len(kept["sha256"]) == 64  # whole
        entries = kept.get("files") or kept["shards"]  # each file's hash cut, the rest as made
        assert [e["sha256"] for e in entries] == [e["sha256"][:16] for e in full.get("files") or full["shards"]]
    # the CGN val runs' per-task rows beside the record, where the entry's `run` names them
    for judged in ("val", "shipped_val"):
        rows = lzma.decompress((record / (entry["cgn"][judged]["run"] + ".xz")).read_bytes()).decode().splitlines()
        assert len(rows) == 1 and json.loads(rows[0])
    assert set(entry["seconds"]["labels"]) == {"cgn_views", "collision", "collision_val"} and entry["seconds"]["total"]
    cgn, net = entry["cgn"], entry["collision_net"]
    # both go on from the shipped weights; the tasks seen are the lineage's train-suite tasks
    shipped_cgn = json.loads((ROOT / "assets/checkpoints/cgn_ours.json").read_text())
    shipped_net = json.loads((ROOT / "assets/checkpoints/collision_net.json").read_text())
    assert cgn["init_from"]["checkpoint"] == "assets/checkpoints/cgn_ours.pt.planes.xz"
    assert cgn["steps"] == [shipped_cgn["steps"], shipped_cgn["steps"] + 1]
    assert net["steps"] == [shipped_net["steps"], shipped_net["steps"] + 3]
    assert cgn["tasks_seen"] == shipped_cgn.get("train_tasks_seen", 0) + 2
    assert net["tasks_seen"] == shipped_net.get("train_tasks_seen", shipped_net["train_tasks"]) + 2
    # val: the candidate and the shipped weights judged alike on the same val task
    for figures in (cgn["val"], cgn["shipped_val"]):
        assert figures["tasks"] == "0:1" and figures["tasks_run"] == 1 and "precision_top10" in figures
    assert cgn["shipped_val"]["checkpoint_sha256"] == shipped_cgn["checkpoint_sha256"]
    assert net["val"]["n"] == net["shipped_val"]["n"] == 200 and 0 <= net["val"]["false_free_of_all"] <= 1
    assert "val score" in cgn["choice"]["why"] and not cgn["shipped"] and not net["shipped"]  # no --ship
    # what the round went on from is kept in its work folder (a resumed round names it still)
    kept = json.loads((work / "round_01/stages/shipped.json").read_text())
    assert kept["cgn"]["sha256"] == cgn["init_from"]["sha256"] == shipped_cgn["checkpoint_sha256"]

    # The same command after a stop past the val stage: no stage runs again (same exports).
    export = work / "round_01/export"
    before = {f.name: f.read_bytes() for f in export.glob("*.pt")}
    (record / "rounds.json").rename(record / "first.json")
    capsys.readouterr()
    assert rounds.main(argv) == 0
    out = capsys.readouterr().out
    assert all(f"{stage}: finished before" in out for stage in ("labels", "training", "val")), out
    assert {f.name: f.read_bytes() for f in export.glob("*.pt")} == before
    assert json.loads((record / "rounds.json").read_text())["rounds"][0]["labels"] == labels

    assert rounds.main(["--record", str(record), "--status"]) == 0
    out = capsys.readouterr().out
    assert "round 1: train tasks 0:2" in out and "no plateau" in out
    assert rounds.main(["--record", str(record), "--costs", "--cores", "16"]) == 0
    assert "core-minutes of labels" in capsys.readouterr().out
    png = tmp_path / "curve.png"
    assert rounds.main(["--record", str(record), "--plot", str(png)]) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    # The next round takes the next tasks, and goes on from round 1's candidate, which did not
    # ship but is still in the work folder: the lineage's steps, tasks and rounds carry on.
    from fetchbench_ms.utils.packed import content_sha256

    assert rounds.main(argv) == 0
    second = json.loads((record / "rounds.json").read_text())["rounds"][1]
    assert second["round"] == 2 and second["tasks"] == [2, 4]
    for model, name, added in (("cgn", "cgn_ours", 1), ("collision_net", "collision_net", 3)):
        start_from, first = second[model]["init_from"], entry[model]
        assert start_from["checkpoint"] == str(export / f"{name}.pt") and start_from["candidate_of_round"] == 1
        assert start_from["sha256"] == content_sha256(export / f"{name}.pt")
        assert second[model]["steps"] == [first["steps"][1], first["steps"][1] + added]
        assert second[model]["tasks_seen"] == first["tasks_seen"] + 2
        assert start_from["rounds"] == first["init_from"]["rounds"] + [1]
    assert second["cgn"]["shipped_val"]["checkpoint_sha256"] == shipped_cgn["checkpoint_sha256"]  # judged against
    # the val tasks' collision labels (same tasks, same labeller flags) are round 1's, not made again
    val_labels = second["labels"]["collision_val"]
    assert val_labels["copied_from_round"] == 1 and val_labels["sha256"] == labels["collision_val"]["sha256"]
    assert "copied_from_round" not in labels["collision_val"]
    # Past the suite's end: refused before anything runs.
    with pytest.raises(SystemExit, match=r"train tasks 4:\d+ run past"):
        rounds.main(["--record", str(record), "--work", str(work), "--tasks", str(10**7), *SMALL])
    assert not (work / "round_03").exists()

    # Shipping (into a copy of the checkpoints folder): the packed weights are the export's bytes
    # and the JSON counts the lineage's train-suite tasks.
    from fetchbench_ms.grasp_prediction.predict import load_checkpoint
    from fetchbench_ms.utils.packed import file_bytes

    monkeypatch.setattr(rounds, "ROOT", tmp_path)
    shipped_entry = {"meta": shipped_cgn, "sha256": shipped_cgn["checkpoint_sha256"]}
    meta = rounds.ship_meta(export / "cgn_ours.json", shipped_entry, entry, "cgn", 1, {"rounds": []}, "python x")
    rounds.ship_checkpoint(export / "cgn_ours.pt", meta, export / "cgn_ours.log", "cgn_ours", print)
    packed = tmp_path / "assets/checkpoints/cgn_ours.pt.planes.xz"
    assert file_bytes(packed) == before["cgn_ours.pt"] and not load_checkpoint(packed).training
    shipped_meta = json.loads((tmp_path / "assets/checkpoints/cgn_ours.json").read_text())
    assert shipped_meta["train_tasks_seen"] == cgn["tasks_seen"] and shipped_meta["rounds"] == shipped_cgn["rounds"] + [1]
    assert shipped_meta["steps"] == shipped_cgn["steps"] + 1 and shipped_meta["round_steps"] == 1
    assert shipped_meta["data_manifests"]["cgn_views"]["sha256"] == labels["cgn_views"]["sha256"]
