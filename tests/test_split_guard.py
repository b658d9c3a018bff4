"""The test split never trains and never chooses (``fetchbench_ms.tasks.splits``).

Every script that trains, makes training data or selects refuses the test suite (by name,
or a suite file of its tasks or objects, such as ``smoke``) with one line on stderr and exit
status 2, before it writes anything; given train or val it gets past the guard (each case
stops at the first error after it). ``scripts/imitation/select_checkpoint.py`` chooses the candidate
with the best val success (ties: the earlier step) and records every candidate's figures.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from fetchbench_ms.tasks import splits
from fetchbench_ms.tasks.splits import RefusalExit, TestSplitRefused
from fetchbench_ms.tasks.suite import load_suite, shipped_suite_file

from script_modules import load_script

ROOT = Path(__file__).resolve().parents[1]
MESSAGE = "refuses the test suite"
RULE = "test tasks are never used for training or selection; use train (learning) or val (choices)"
TINY_SIZES = {"scene": 8, "target": 4, "robot": 4}


_import = load_script  # a fresh copy each time (its folder on sys.path: ``from common import``)


def _refused(excinfo, capsys, purpose: str) -> None:
    """A script's refusal: exit status 2 and its one line on stderr."""
    assert isinstance(excinfo.value, RefusalExit) and excinfo.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and purpose in err[0] and MESSAGE in err[0] and RULE in err[0], err


def _a_test_object() -> str:
    smoke = load_suite("smoke")
    return next(o.object_id for t in smoke.tasks.values() for o in t.objects)


def _train_objects(n: int = 2) -> list[str]:
    val = load_suite("val")
    return sorted({o.object_id for t in list(val.tasks.values())[:3] for o in t.objects})[:n]


# ----------------------------------------------------------------------------- the guard
def test_the_guard_knows_the_test_suite_and_what_is_made_of_it(tmp_path):
    for suite in ("test", "smoke", shipped_suite_file("smoke"), load_suite("smoke")):
        assert splits.suite_is_test(suite), suite
    for suite in ("train", "val", shipped_suite_file("val"), None, "no-such-suite"):
        assert not splits.suite_is_test(suite), suite
    # a renamed copy of test tasks is still test: by its objects (and where it came from)
    val, smoke = load_suite("val"), load_suite("smoke")
    mixed = smoke.subset("mine", smoke.ids()[:2], info={"what": "a hand-made suite"})
    assert splits.suite_is_test(mixed)
    for name in ("mine.json.gz", "mine.suite.xz"):
        mixed.save(tmp_path / name)
        assert splits.suite_is_test(tmp_path / name)
    assert not splits.suite_is_test(val.subset("few", val.ids()[:3]))
    assert {"test", "smoke"} <= splits.test_suite_names()

    with pytest.raises(TestSplitRefused) as refused:
        splits.refuse_test("test", "demonstration generation")
    assert str(refused.value) == f"demonstration generation {MESSAGE}: {RULE}"
    with pytest.raises(TestSplitRefused, match="object_split='test'"):
        splits.refuse_test_env_kwargs({"task_suite": None, "object_split": "test"}, "x")
    with pytest.raises(TestSplitRefused, match="smoke/0003"):
        splits.refuse_test_task_ids(["train/0001", "smoke/0003"], "x")
    with pytest.raises(TestSplitRefused, match="test-split objects"):
        splits.refuse_test_objects([*_train_objects(), _a_test_object()], "x")
    splits.refuse_test("val", "x")
    splits.refuse_test_env_kwargs({"task_suite": "train", "object_split": "train"}, "x")
    splits.refuse_test_task_ids(["train/0001", "val/0002", None], "x")
    splits.refuse_test_objects(_train_objects(), "x")


def test_an_eval_folder_of_test_tasks_is_refused(tmp_path):
    def run(name: str, manifest: dict, task: str) -> Path:
        folder = tmp_path / name
        folder.mkdir()
        (folder / "run.json").write_text(json.dumps(manifest))
        (folder / "results.jsonl").write_text(json.dumps({"task_id": task, "success": True}) + "\n")
        return folder

    test_sha = splits.test_suite_hashes()
    assert len(test_sha) >= 2
    for folder in (run("by-name", {"selection": {"suite": "smoke"}}, "val/0000"),
                   run("by-hash", {"selection": {"suite": "x"}, "source_sha256": sorted(test_sha)[0]}, "x/0000"),
                   run("by-ids", {"selection": {"suite": "x"}}, "test/0042"),
                   run("sampled", {"selection": {"object_split": "test"}}, "seed/0")):
        with pytest.raises(TestSplitRefused):
            splits.refuse_test_results(folder, "x")
    splits.refuse_test_results(run("val", {"selection": {"suite": "val"}}, "val/0000"), "x")


def test_cli_guard_exits_2_with_one_line(capsys):
    with pytest.raises(SystemExit) as excinfo:
        splits.cli_guard(splits.refuse_test, "test", "PPO training")
    _refused(excinfo, capsys, "PPO training")
    assert splits.cli_guard(lambda: 7) == 7


# ----------------------------------------------------------------------------- demos
def test_demo_generation_refuses_test(tmp_path, capsys):
    from fetchbench_ms.cli import main

    for suite in ("test", "smoke"):
        out = tmp_path / suite
        assert main(["demos", "run", "--task-suite", suite, "--record-dir", str(out), "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "demonstration generation " + MESSAGE in err and RULE in err
        assert not out.exists()
    # val gets past the guard (stopped by a start seed past its tasks)
    assert main(["demos", "run", "--task-suite", "val", "--start-seed", "100000", "--record-dir",
                 str(tmp_path / "val"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "start_seed 100000 is outside" in err and MESSAGE not in err


def test_merging_demos_of_test_tasks_is_refused(tmp_path):
    from fetchbench_ms.demos.generate import merge_runs

    def run(name: str, suite: str, first: int) -> Path:
        meta = {"env_info": {"env_id": "FetchBench-v0", "env_kwargs": {"task_suite": suite}},
                "episodes": [{"episode_id": 0, "task_id": f"{suite}/{first:04d}"}],
                "fetchbench": {"first_seed": first, "tasks": 1}}
        (tmp_path / f"{name}.json").write_text(json.dumps(meta))
        return tmp_path / f"{name}.h5"

    with pytest.raises(TestSplitRefused, match="merging demonstrations " + MESSAGE):
        merge_runs([run("a", "test", 0), run("b", "test", 1)], tmp_path / "out" / "merged")
    assert not (tmp_path / "out").exists()


def _demos(folder: Path, suite: str, task: str | None, target: str | None = None) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    h5 = folder / "demos.h5"
    h5py.File(h5, "w").close()
    meta = {"env_info": {"env_id": "FetchBench-v0", "env_kwargs": {"task_suite": suite}},
            "episodes": [] if task is None else [{"episode_id": 0, "task_id": task, "target_object": target}]}
    h5.with_suffix(".json").write_text(json.dumps(meta))
    return h5


def test_demo_conversion_refuses_test(tmp_path, capsys):
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    train_object = _train_objects(1)[0]
    cases = [("test", "test/0001", train_object), ("train", "smoke/0003", train_object),
             ("train", "train/0001", _a_test_object())]
    for k, (suite, task, target) in enumerate(cases):
        source = _demos(tmp_path / f"src{k}", suite, task, target)
        out = tmp_path / f"out{k}"
        with pytest.raises(SystemExit) as excinfo:
            convert.main(["--traj-path", str(source), "--out", str(out)])
        _refused(excinfo, capsys, "demo conversion for imitation")
        assert not out.exists()
    # train demos get past the guard (stopped: the file holds no demo to start from)
    source = _demos(tmp_path / "train", "train", None)
    with pytest.raises(SystemExit, match="--start must be a multiple"):
        convert.main(["--traj-path", str(source), "--out", str(tmp_path / "out-train")])


# ----------------------------------------------------------------------------- imitation trainers
def _training_file(folder: Path, task_ids: list[str], frames_per_demo: int = 12) -> Path:
    """A tiny synthetic training file (the converter's format) of one demo per task id."""
    from fetchbench_ms.policies.data import write_training_file

    rng = np.random.default_rng(0)
    folder.mkdir(parents=True, exist_ok=True)
    n, F = sum(TINY_SIZES.values()), frames_per_demo * len(task_ids)
    stage = np.tile(np.r_[np.zeros(frames_per_demo // 2), np.full(frames_per_demo - frames_per_demo // 2, 2)],
                    len(task_ids)).astype(np.int8)
    stage_end = np.zeros(F, bool)
    stage_end[frames_per_demo // 2 - 1::frames_per_demo] = True
    stage_end[frames_per_demo - 1::frames_per_demo] = True
    data = {"sizes": TINY_SIZES, "points": rng.normal(size=(F, n, 3)).astype(np.float16),
            "point_label": np.tile(np.r_[np.ones(8), np.full(4, 3), np.full(4, 4)].astype(np.uint8), (F, 1)),
            "qpos": rng.normal(size=(F, 9)).astype(np.float32), "tcp": rng.normal(size=(F, 9)).astype(np.float32),
            "action": rng.uniform(-1, 1, size=(F, 7)).astype(np.float32), "gripper": np.ones(F, np.float32),
            "stage": stage, "stage_end": stage_end,
            "episode_start": np.arange(0, F, frames_per_demo),
            "episode_length": np.full(len(task_ids), frames_per_demo),
            "episodes": [{"source": "demos.h5", "episode_id": k, "task_id": t, "length": frames_per_demo}
                         for k, t in enumerate(task_ids)]}
    write_training_file(folder / "chunk_00000.imit.h5", data)
    return folder


def _mlp_args(module, data: Path, run: Path, **kw):
    return module.Args(data=str(data), run=str(run), device="cpu", steps=4, batch_size=8, point_dims=(8, 8),
                       scene_points=8, target_points=4, robot_points=4, hidden=16, eval_every=0, val_every=10_000,
                       log_every=100, ckpt_every=10_000, warmup=1, **kw)


def test_imitation_training_refuses_test_tasks(tmp_path, capsys):
    mlp = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    for prefix in ("test", "smoke"):
        data = _training_file(tmp_path / f"data-{prefix}", ["train/0001", f"{prefix}/0002"])
        run = tmp_path / f"run-{prefix}"
        with pytest.raises(SystemExit) as excinfo:
            mlp.main(_mlp_args(mlp, data, run))
        _refused(excinfo, capsys, "mlp imitation training")
        assert not run.exists()


def test_imitation_trainer_cli_exits_2_on_test_tasks(tmp_path):
    data = _training_file(tmp_path / "data", ["test/0001"])
    done = subprocess.run([sys.executable, str(ROOT / "baselines/imitation/train_transformer.py"), "--data", str(data),
                           "--run", str(tmp_path / "run"), "--device", "cpu"], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "transformer imitation training " + MESSAGE in lines[0]
    assert not (tmp_path / "run").exists()


@pytest.fixture(scope="module")
def candidates(tmp_path_factory) -> Path:
    """A tiny MLP run on train tasks with ``--save-every 2``: candidates at steps 2 and 4."""
    root = tmp_path_factory.mktemp("select")
    mlp = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    data = _training_file(root / "data", ["train/0001", "train/0002", "train/0003"])
    result = mlp.main(_mlp_args(mlp, data, root / "run", save_every=2))
    assert result["step"] == 4
    return root / "run" / "candidates"


def test_save_every_exports_candidates(candidates):
    from fetchbench_ms.policies.agent import load_model

    assert sorted(p.name for p in candidates.glob("*.pt")) == ["step_0000002.pt", "step_0000004.pt"]
    for step in (2, 4):
        meta = json.loads((candidates / f"step_{step:07d}.json").read_text())
        assert meta["kind"] == "mlp" and meta["step"] == step
        assert load_model(candidates / f"step_{step:07d}.pt")[1]["step"] == step


# ----------------------------------------------------------------------------- checkpoint selection
def _fake_evaluate(successes_by_step: dict, calls: list):
    """Stands in for `fetchbench eval`: records of the asked val tasks, the first k succeed."""
    def evaluate(candidate: dict, out_dir: Path, settings: dict) -> list[dict]:
        calls.append((candidate["step"], settings))
        suite = load_suite(settings["suite"])
        a, b = (int(x) for x in settings["tasks"].split(":"))
        k = successes_by_step[candidate["step"]]
        return [{"task_id": t, "success": i < k, "checkpoint_sha256": candidate["sha256"]}
                for i, t in enumerate(suite.ids()[a:b])]
    return evaluate


def test_selection_picks_the_val_best_and_records_every_candidate(candidates, tmp_path):
    from fetchbench_ms.utils.io import sha256_file

    select = _import(ROOT / "scripts/imitation/select_checkpoint.py", "select_checkpoint")
    export = tmp_path / "export" / "imit_mlp.pt"
    calls: list = []
    assert select.main(["--candidates", str(candidates), "--out", str(tmp_path / "sel"),
                        "--export-path", str(export)], evaluate=_fake_evaluate({2: 31, 4: 40}, calls)) == 0
    assert [(step, s["suite"], s["tasks"], s["method"]) for step, s in calls] == \
        [(2, "val", "0:100", "e2e-mlp"), (4, "val", "0:100", "e2e-mlp")]
    assert sha256_file(export) == sha256_file(candidates / "step_0000004.pt")  # the chosen bytes
    meta = json.loads(export.with_suffix(".json").read_text())
    selection = meta["selection"]
    assert meta["step"] == 4 and meta["checkpoint_sha256"] == sha256_file(export)
    assert selection["chosen_step"] == 4 and selection["suite"] == "val" and selection["task_count"] == 100
    assert [(c["step"], c["successes"], c["tasks"], c["success_rate"]) for c in selection["candidates"]] == \
        [(2, 31, 100, 0.31), (4, 40, 100, 0.4)]
    assert "warning" not in selection
    assert json.loads((tmp_path / "sel" / "selection.json").read_text()) == selection

    # a tie: the earlier step
    assert select.main(["--candidates", str(candidates), "--out", str(tmp_path / "sel2"),
                        "--export-path", str(export)], evaluate=_fake_evaluate({2: 40, 4: 40}, [])) == 0
    assert json.loads(export.with_suffix(".json").read_text())["selection"]["chosen_step"] == 2
    assert sha256_file(export) == sha256_file(candidates / "step_0000002.pt")


def test_selection_runs_fetchbench_eval_on_val(candidates, tmp_path, monkeypatch):
    """The default evaluator's command: `fetchbench eval` of the candidate on the val tasks."""
    select = _import(ROOT / "scripts/imitation/select_checkpoint.py", "select_checkpoint")
    commands = []

    def call(command):
        commands.append(command)
        out = Path(command[command.index("--out") + 1])
        out.mkdir(parents=True)
        (out / "results.jsonl").write_text(json.dumps({"task_id": "val/0000", "success": True}) + "\n")
        return 0

    monkeypatch.setattr(select.subprocess, "call", call)
    candidate = select.candidate_info(candidates / "step_0000002.pt")
    settings = {"method": "cgn-imit-mlp", "suite": "val", "tasks": "0:100", "workers": 3, "policy_stride": 1,
                "eval_args": "--pipeline ours"}
    records = select.run_fetchbench_eval(candidate, tmp_path / "step_0000002", settings)
    assert records == [{"task_id": "val/0000", "success": True}]
    assert commands == [[sys.executable, "-m", "fetchbench_ms", "eval", "--method", "cgn-imit-mlp", "--suite", "val",
                         "--tasks", "0:100", "--workers", "3",
                         "--policy-checkpoint", str(candidates / "step_0000002.pt"), "--policy-stride", "1",
                         "--out", str(tmp_path / "step_0000002"), "--pipeline", "ours"]]


def test_selection_refuses_test_and_small_val_sets(candidates, tmp_path, capsys):
    select = _import(ROOT / "scripts/imitation/select_checkpoint.py", "select_checkpoint")
    export = tmp_path / "imit_mlp.pt"
    for suite in ("test", "smoke", str(shipped_suite_file("test"))):
        with pytest.raises(SystemExit) as excinfo:
            select.main(["--candidates", str(candidates), "--suite", suite, "--out", str(tmp_path / "sel"),
                         "--export-path", str(export)], evaluate=_fake_evaluate({}, []))
        _refused(excinfo, capsys, "checkpoint selection")
    assert not export.exists() and not (tmp_path / "sel").exists()
    # fewer than 100 val tasks: refused (usage error) unless --allow-small, then recorded
    with pytest.raises(SystemExit) as excinfo:
        select.main(["--candidates", str(candidates), "--tasks", "0:16", "--export-path", str(export)],
                    evaluate=_fake_evaluate({}, []))
    assert excinfo.value.code == 2 and "--allow-small" in capsys.readouterr().err
    assert not export.exists()
    assert select.main(["--candidates", str(candidates), "--tasks", "0:16", "--allow-small", "--out",
                        str(tmp_path / "sel"), "--export-path", str(export)],
                       evaluate=_fake_evaluate({2: 3, 4: 1}, [])) == 0
    assert "warning: chosen on 16 val tasks" in capsys.readouterr().err
    selection = json.loads(export.with_suffix(".json").read_text())["selection"]
    assert selection["chosen_step"] == 2 and "16 val tasks" in selection["warning"]


def test_selection_cli_exits_2_on_test(tmp_path):
    done = subprocess.run([sys.executable, str(ROOT / "scripts/imitation/select_checkpoint.py"), "--candidates", str(tmp_path),
                           "--suite", "test", "--out", str(tmp_path / "sel")], capture_output=True, text=True,
                          timeout=120, cwd=tmp_path)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert lines == [f"error: checkpoint selection {MESSAGE}: {RULE}"]
    assert list(tmp_path.iterdir()) == []


def test_shipping_refuses_a_test_val_run(tmp_path, capsys, monkeypatch):
    ship = _import(ROOT / "scripts/maint/ship_imitation.py", "ship_imitation")
    monkeypatch.setattr(ship, "default_checkpoint", lambda kind: tmp_path / "none" / f"imit_{kind}.pt")
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "run.json").write_text(json.dumps({"selection": {"suite": "smoke", "tasks": "0:2"}}))
    (folder / "results.jsonl").write_text(json.dumps({"task_id": "smoke/0000", "method": "e2e-mlp"}) + "\n")
    with pytest.raises(SystemExit) as excinfo:
        ship.main(["--val-runs", str(folder)])
    _refused(excinfo, capsys, "shipping's val figures")
    # a val run gets past the guard (stopped: no checkpoint of its kind is shipped here)
    (folder / "run.json").write_text(json.dumps({"selection": {"suite": "val", "tasks": "0:2"}}))
    (folder / "results.jsonl").write_text(json.dumps({"task_id": "val/0000", "method": "e2e-mlp"}) + "\n")
    with pytest.raises(SystemExit, match="no imit_mlp.pt is shipped here"):
        ship.main(["--val-runs", str(folder)])


# ----------------------------------------------------------------------------- other trainers and data
_load_script = load_script


def test_collision_net_labels_refuse_test(tmp_path, capsys):
    labels = _import(ROOT / "baselines/mppi_collision/labels.py", "labels")
    for suite in ("test", "smoke"):
        with pytest.raises(SystemExit) as excinfo:
            labels.main(labels.Args(suite=suite, tasks="0:0", out=str(tmp_path / suite)))
        _refused(excinfo, capsys, "collision-net labelling")
        assert not (tmp_path / suite).exists()
    # val passes the guard; an empty slice then fails as a run that would do nothing
    with pytest.raises(SystemExit) as excinfo:
        labels.main(labels.Args(suite="val", tasks="0:0", out=str(tmp_path / "val")))
    assert "selects none of the" in str(excinfo.value) and "val" in str(excinfo.value)
    assert not (tmp_path / "val").exists()


def test_collision_net_training_refuses_test_labels(tmp_path, capsys):
    training = _import(ROOT / "baselines/mppi_collision/train.py", "train")

    def labels(folder: Path, suite: str, task: str) -> Path:
        folder.mkdir(parents=True, exist_ok=True)
        np.savez(folder / f"{task.replace('/', '_')}.npz", suite=suite, task_id=task,
                 grid=np.zeros((2, 2, 2), np.uint8), q=np.zeros((4, 7), np.float32), clearance_mm=np.zeros((4, 3), np.int8), label=np.zeros(4, bool),
                 checked=np.ones(3, bool), radii=np.ones(3, np.float32), att_centers_hand=np.zeros((0, 3), np.float32))
        return folder

    for suite, task in (("test", "test/0001"), ("val", "smoke/0002")):
        data = labels(tmp_path / f"data-{suite}", "train", "train/0001")
        val = labels(tmp_path / f"val-{suite}", suite, task)
        with pytest.raises(SystemExit) as excinfo:
            training.main(training.Args(data=str(data), val=str(val), run=str(tmp_path / "run"), device="cpu"))
        _refused(excinfo, capsys, "collision-net training")
        assert not (tmp_path / "run").exists()
    # train and val labels get past the guard (stopped: the val folder is empty)
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit, match="no labelled tasks"):
        training.main(training.Args(data=str(labels(tmp_path / "d", "train", "train/0001")),
                                    val=str(tmp_path / "empty"), run=str(tmp_path / "run"), device="cpu"))


def test_ppo_refuses_test_tasks(tmp_path, capsys):
    ppo = _load_script(ROOT / "baselines/ppo/ppo.py", "ppo")
    for kw in ({"task_suite": "test"}, {"eval_task_suite": "smoke"}):
        with pytest.raises(SystemExit) as excinfo:
            ppo.main(ppo.Args(out_dir=str(tmp_path / "out"), **kw))
        _refused(excinfo, capsys, "PPO")
        assert not (tmp_path / "out").exists()
    with pytest.raises(ValueError, match="--num-envs"):  # train / val: past the guard
        ppo.main(ppo.Args(out_dir=str(tmp_path / "out"), task_suite="train", eval_task_suite="val", num_envs=0))


def test_bench_cgn_quality_refuses_test_unless_report_only(tmp_path, capsys):
    bench = _load_script(ROOT / "scripts/bench/bench_cgn.py", "bench_cgn")
    for suite in ("test", "smoke"):
        with pytest.raises(SystemExit) as excinfo:
            bench.main(["quality", "--suite", suite, "--json", str(tmp_path / "q.json")])
        _refused(excinfo, capsys, "grasp-quality comparison")
    assert not (tmp_path / "q.json").exists()
    # val, and test with --report-only, get past the guard (stopped by an empty task range)
    for argv in (["--suite", "val"], ["--suite", "test", "--report-only"]):
        with pytest.raises(ValueError, match="--tasks"):
            bench.main(["quality", *argv, "--tasks", "5:1"])


@pytest.fixture
def test_objects_in_the_catalog(monkeypatch):
    """The train split as the catalog would list it if a test-split object slipped in."""
    import fetchbench_ms.grasp_labels
    import fetchbench_ms.objects.loading

    ids = [*_train_objects(), _a_test_object()]
    monkeypatch.setattr(fetchbench_ms.objects.loading, "object_ids", lambda split="test": ids)
    monkeypatch.setattr(fetchbench_ms.grasp_labels, "objects_with_grasps", lambda: ids)


def test_cgn_training_data_refuses_test_objects(tmp_path, capsys, test_objects_in_the_catalog):
    train = _load_script(ROOT / "baselines/contact_graspnet/train.py", "cgn_train_guard")
    with pytest.raises(SystemExit) as excinfo:
        train.main(train.Args(run=str(tmp_path / "run"), device="cpu", tiny=True))
    _refused(excinfo, capsys, "Contact-GraspNet training data")
    assert not (tmp_path / "run").exists()


def test_cgn_label_check_refuses_test_objects(capsys, monkeypatch, test_objects_in_the_catalog):
    check = _load_script(ROOT / "scripts/bench/check_cgn_labels.py", "check_cgn_labels")
    monkeypatch.setattr(sys, "argv", ["check_cgn_labels.py", "--views", "1"])
    with pytest.raises(SystemExit) as excinfo:
        check.main()
    _refused(excinfo, capsys, "Contact-GraspNet training data")


def test_cgn_training_gets_past_the_guard_on_train_objects(tmp_path, monkeypatch):
    train = _load_script(ROOT / "baselines/contact_graspnet/train.py", "cgn_train_guard")
    with pytest.raises(ValueError, match="--init 'bogus'"):  # the first check after the guard
        train.main(train.Args(run=str(tmp_path / "run"), device="cpu", tiny=True, init="bogus"))
    check = _load_script(ROOT / "scripts/bench/check_cgn_labels.py", "check_cgn_labels")
    monkeypatch.setattr(sys, "argv", ["check_cgn_labels.py", "--model", str(tmp_path / "none.pt")])
    with pytest.raises(FileNotFoundError):  # past the guard: the model is loaded next
        check.main()
