"""Imitation baselines: conversion of the shipped demo sample, the trainers (loss falls,
resume), checkpoints acting in the env, the re-grasp state machine, ACT's temporal ensemble,
the eval methods.

The sample is regenerated with the train suite: nothing here depends on its trajectories or
their number (the first 2 demos' first steps are converted, whatever they are)."""
from __future__ import annotations

import hashlib
import json
import os
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from fetchbench_ms.policies import agent as agent_mod
from fetchbench_ms.policies.agent import (APPROACH, CLOSE, DONE, GRIPPER_CLOSED, GRIPPER_OPEN, REOPEN, RETRIEVE,
                                          ImitationPolicy, ReGraspConfig, ReGraspStateMachine, load_model)
from fetchbench_ms.policies.data import (load_training_files, observation_input, segment_slices, select_frames,
                                         source_steps)
from fetchbench_ms.envs.pointcloud import COMPACT_SIZES, LABEL_FURNITURE, LABEL_ROBOT, LABEL_TARGET

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
SIZES = dict(scene=128, target=64, robot=32)
FIRST_STEPS = 12
# Tiny networks so a CPU trains a few steps in seconds; the defaults are the GPU's.
TINY = dict(point_dims=(32, 64), batch_size=16, scene_points=SIZES["scene"], target_points=SIZES["target"],
            robot_points=SIZES["robot"], device="cpu", eval_every=0, val_every=10_000, log_every=5, warmup=1,
            lr=2e-3, lr_final=2e-3, point_jitter=0.0, ckpt_every=10_000)
TRAINER_KW = {"mlp": dict(hidden=64), "transformer": dict(d_model=32, layers=1, heads=2, dropout=0.0),
              "diffusion": dict(unet_dims=(16, 32), pred_horizon=8, act_horizon=4, train_diffusion_steps=20,
                                sample_steps=4),
              "act": dict(chunk=8, latent_dim=8, d_model=32, layers=1, heads=2, dropout=0.0)}
TINY_ACT = dict(chunk=4, latent_dim=8, d_model=32, layers=1, heads=2, dropout=0.0)


_import = import_script


@pytest.fixture(scope="module")
def sample_data(tmp_path_factory) -> Path:
    """The first steps of the sample's first 2 demos, through ManiSkill's replay tool."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    out = tmp_path_factory.mktemp("imit-data")
    assert convert.main(["--traj-path", str(SAMPLE), "--out", str(out), "--count", "2", "--chunk", "2",
                         "--first-steps", str(FIRST_STEPS), "--sizes", "128,64,32"]) == 0
    return out


def test_conversion_writes_the_policies_frames(sample_data):
    data = load_training_files(sample_data, sizes=SIZES)
    n = len(data["qpos"])
    assert len(data["episodes"]) >= 1
    # one or two converted steps per source step (clipped deltas take two)
    for e in data["episodes"]:
        assert FIRST_STEPS <= e["length"] <= 2 * FIRST_STEPS and e["source_length"] == FIRST_STEPS
    assert data["points"].shape == (n, 224, 3) and data["points"].dtype == np.float16
    assert data["action"].shape == (n, 7) and np.abs(data["action"]).max() <= 1.0
    assert set(np.unique(data["stage"])) <= {0, 1, 2}
    label = data["point_label"]
    assert np.isin(label[:, :128], (0, 3, 4)).all()  # scene block: furniture / other objects
    assert np.isin(label[:, 128:192], (0, LABEL_TARGET)).all()
    assert np.isin(label[:, 192:], (0, LABEL_ROBOT)).all() and (label[:, 192:] == LABEL_ROBOT).any()
    # the TCP is in front of the base, within the Panda's reach
    assert (np.linalg.norm(data["tcp"][:, :3], axis=1) < 1.0).all()
    # re-running resumes: nothing is converted again
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    before = sorted((p.name, p.stat().st_mtime_ns) for p in sample_data.glob("*.imit.h5"))
    assert convert.main(["--traj-path", str(SAMPLE), "--out", str(sample_data), "--count", "2", "--chunk", "2",
                         "--first-steps", str(FIRST_STEPS), "--sizes", "128,64,32"]) == 0
    assert sorted((p.name, p.stat().st_mtime_ns) for p in sample_data.glob("*.imit.h5")) == before
    with pytest.raises(SystemExit, match="other settings"):
        convert.main(["--traj-path", str(SAMPLE), "--out", str(sample_data), "--count", "2", "--chunk", "2",
                      "--first-steps", str(FIRST_STEPS), "--sizes", "256,64,32"])


def test_source_steps_pairs_clipped_steps():
    source = np.zeros((3, 8), np.float32)
    source[:, 7] = [1, 1, -1]
    converted = np.zeros((5, 8), np.float32)
    converted[:, 7] = [1, 1, 1, 1, -1]
    converted[0, 2] = 1.0  # clipped: it and the next step make source step 0
    converted[2, 5] = -1.0  # clipped: steps 2, 3 make source step 1
    assert source_steps(converted, source).tolist() == [0, 0, 1, 1, 2]
    converted[4, 7] = 1  # the copied gripper disagrees: not this demo
    assert source_steps(converted, source) is None
    assert source_steps(converted[:4], source) is None  # too few steps


def test_source_steps_with_joints_follow_maniskills_rule():
    """With the converted joints, a step is doubled exactly when ManiSkill doubled it: a
    normalised delta above 1 + 1e-3. A delta in (1, 1.001] is clipped to an action of 1 but
    gets no second step, which the actions alone misread."""
    source = np.zeros((3, 8), np.float32)
    source[:, :7] = [[0.10005, 0, 0, 0, 0, 0, 0], [0.35, 0, 0, 0, 0, 0, 0], [0.36, 0, 0, 0, 0, 0, 0]]
    qpos = np.zeros((5, 9), np.float32)  # the joints before each converted step (+ the last)
    qpos[1:, 0] = [0.1, 0.2, 0.3, 0.36]
    converted = np.zeros((4, 8), np.float32)
    converted[:, 0] = [1.0, 1.0, 0.5, 0.6]  # delta 1.0005 -> 1, no second step; 2.5 -> 1, then 0.5; 0.6
    assert source_steps(converted, source, qpos).tolist() == [0, 1, 1, 2]
    assert source_steps(converted, source).tolist() == [0, 0, 1, 2]  # the actions alone: misaligned
    assert source_steps(converted[:3], source, qpos[:4]) is None  # too few steps


def test_a_failed_replay_leaves_nothing_in_the_next_trajectory(tmp_path):
    """ManiSkill's replay tool keeps a failed replay's steps in its recorder; a later demo of
    the same task (no scene rebuild) would be saved after them. fetchbench_ms.replay_trajectory
    drops them: the saved trajectory is the second demo's own, step for step."""
    import h5py

    from fetchbench_ms import replay_trajectory

    meta = json.loads(SAMPLE.with_suffix(".json").read_text())
    episodes = meta["episodes"]
    pair = next((a, b) for a, b in zip(episodes, episodes[1:]) if a["reset_kwargs"] == b["reset_kwargs"])
    cut = 40  # the first demo stops short of its grasp: its replay fails
    path = tmp_path / "pair.h5"
    with h5py.File(SAMPLE, "r") as src, h5py.File(path, "w") as dst:
        for episode in pair:
            name = f"traj_{episode['episode_id']}"
            src.copy(src[name], dst, name=name)
        first = dst[f"traj_{pair[0]['episode_id']}"]
        actions = first["actions"][:cut]
        del first["actions"]
        first.create_dataset("actions", data=actions)
    episodes_out = [{**pair[0], "elapsed_steps": cut}, pair[1]]
    path.with_suffix(".json").write_text(json.dumps({**meta, "episodes": episodes_out}))
    replay_trajectory.main(["--traj-path", str(path), "-c", "pd_joint_delta_pos", "-o", "state_dict", "--save-traj"])
    out = tmp_path / "pair.state_dict.pd_joint_delta_pos.physx_cpu.h5"
    with h5py.File(out, "r") as f, h5py.File(SAMPLE, "r") as src:
        assert list(f.keys()) == ["traj_0"]  # the failed replay is not saved
        converted = f["traj_0"]
        source_actions = src[f"traj_{pair[1]['episode_id']}"]["actions"][:]
        index = source_steps(converted["actions"][:], source_actions, converted["obs"]["agent"]["qpos"][:])
        assert index is not None and index[-1] == len(source_actions) - 1
        assert converted["obs"]["agent"]["qpos"].shape[0] == len(index) + 1


def _full_loss(module, model, data_dir: Path, args) -> float:
    common = _import(ROOT / "baselines/imitation/common.py", "common")
    frames = common.Frames(load_training_files(data_dir, sizes=SIZES), "cpu", args)
    model.eval()
    with torch.no_grad():
        out = module.batch_loss(model, frames, frames.train_index, torch.Generator().manual_seed(5), args)
    return float(out["loss"])


@pytest.mark.parametrize("kind", ["mlp", "transformer", "diffusion", "act"])
def test_trainer_loss_falls_and_checkpoint_exports(kind, sample_data, tmp_path):
    module = _import(ROOT / f"baselines/imitation/train_{kind}.py", f"train_{kind}")
    export = tmp_path / f"{kind}.pt"
    args = module.Args(data=str(sample_data), run=str(tmp_path / "run"), steps=30, export=True,
                       export_path=str(export), **TINY, **TRAINER_KW[kind])
    torch.manual_seed(args.seed)
    before = _full_loss(module, module.make_model(args), sample_data, args)  # the trainer's initial weights
    result = module.main(args)
    assert result["step"] == 30 and not result["stopped"]
    model, meta = load_model(export)
    after = _full_loss(module, model, sample_data, args)
    assert after < before, (before, after)
    assert export.stat().st_size < 8e6 and meta["kind"] == kind and len(meta["data_sha256"]) == 64
    assert export.with_suffix(".json").is_file()


def test_trainer_resumes_after_time_limit(sample_data, tmp_path):
    module = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    args = module.Args(data=str(sample_data), run=str(tmp_path / "run"), steps=6, time_limit=1e-9, **TINY,
                       **TRAINER_KW["mlp"])
    first = module.main(args)
    assert first["stopped"] and first["step"] == 1
    args.time_limit = 0.0
    second = module.main(args)
    assert second["step"] == 6 and not second["stopped"]
    log = (tmp_path / "run" / "log.txt").read_text()
    assert "resumed at step 1" in log and "done: 6 steps" in log


def test_training_reports_its_rate_and_eta_from_the_first_steps(sample_data, tmp_path):
    """A slow machine sees the rate and the time left at steps 1, 2, 5, 10, long before the
    first --log-every; the val-success evaluation uses no more workers than cores."""
    module = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    args = module.Args(data=str(sample_data), run=str(tmp_path / "run"), steps=12,
                       **{**TINY, "log_every": 1000}, **TRAINER_KW["mlp"])
    module.main(args)
    lines = [ln for ln in (tmp_path / "run" / "log.txt").read_text().splitlines() if "] step " in ln]
    assert [ln.split("] step ")[1].split()[0] for ln in lines] == ["1/12", "2/12", "5/12", "10/12"]
    assert all(" steps/s, ETA " in ln for ln in lines)
    rate, eta = lines[-1].rstrip(")").split("(")[-1].split(" steps/s, ETA ")
    minutes, seconds = eta.rstrip("s").split("m")
    assert abs(int(minutes) * 60 + int(seconds) - 2 / float(rate)) <= 1  # 2 steps left at 10/12
    assert args.eval_workers == min(16, os.cpu_count())
    assert module.Args().eval_workers == min(16, os.cpu_count())
    common = sys.modules["common"]
    assert common.progress(10, 5.0, 3600, limit_left=60.0) == \
        "2.00 steps/s, ETA 30m00s; --time-limit stops this call in 1m00s"


def test_export_goes_under_the_run_and_ships_only_by_the_separate_step(sample_data, tmp_path, monkeypatch, capsys):
    """``--export`` without ``--export-path`` writes ``<run>/export/imit_<kind>.pt`` + .json and
    leaves the package's checkpoints as they are; an ``--export-path`` in their folder is one
    line and exit 2 before anything is written. ``ship_imitation.py --run RUN`` is the step
    that makes a run's export the shipped checkpoint."""
    from fetchbench_ms.policies.deploy import default_checkpoint

    module = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    shipped = default_checkpoint("mlp").parent
    before = {p.name: p.stat().st_mtime_ns for p in shipped.iterdir()}
    run = tmp_path / "run"
    args = module.Args(data=str(sample_data), run=str(run), steps=3, export=True, **TINY, **TRAINER_KW["mlp"])
    module.main(args)
    assert {p.name: p.stat().st_mtime_ns for p in shipped.iterdir()} == before
    _, meta = load_model(run / "export" / "imit_mlp.pt")
    assert meta["step"] == 3 and (run / "export" / "imit_mlp.json").is_file()

    refused = module.Args(data=str(sample_data), run=str(tmp_path / "run2"), steps=3, export=True,
                          export_path=str(default_checkpoint("mlp")), **TINY, **TRAINER_KW["mlp"])
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        module.main(refused)
    err = capsys.readouterr().err.strip().splitlines()
    assert exit_info.value.code == 2 and len(err) == 1 and "ship_imitation.py" in err[0] and "--export-path" in err[0]
    assert not (tmp_path / "run2").exists()
    assert {p.name: p.stat().st_mtime_ns for p in shipped.iterdir()} == before

    ship = _import(ROOT / "scripts/maint/ship_imitation.py", "ship_imitation")
    target = tmp_path / "assets" / "imit_mlp.pt"
    target.parent.mkdir()
    monkeypatch.setattr(ship, "default_checkpoint", lambda kind: target.with_name(f"imit_{kind}.pt"))
    assert ship.main(["--run", str(run), "--kinds", "mlp", "--retrain", "python baselines/imitation/train_mlp.py"]) == 0
    shipped_meta = json.loads(target.with_suffix(".json").read_text())
    assert shipped_meta["checkpoint_sha256"] == ship.sha256_file(run / "export" / "imit_mlp.pt")
    assert shipped_meta["data_manifest"]["totals"] == json.loads((sample_data / "manifest.json").read_text())["totals"]
    assert target.with_suffix(".log").read_text() == (run / "log.txt").read_text()


def test_a_run_goes_on_over_shards_of_the_data(sample_data, tmp_path):
    """A dataset too large for one run is trained shard by shard: the converter's --start
    numbers a shard's chunks as in the whole, --until-step stops a call, and --new-data
    resumes the checkpoint on the next shard (refused without it); the export records each
    shard's data hash and the step it began at."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    shard = tmp_path / "shard1"
    assert convert.main(["--traj-path", str(SAMPLE), "--out", str(shard), "--start", "2", "--count", "2",
                         "--chunk", "2", "--first-steps", str(FIRST_STEPS), "--sizes", "128,64,32"]) == 0
    assert [p.name for p in shard.glob("chunk_*.imit.h5")] == ["chunk_00001.imit.h5"]
    with pytest.raises(SystemExit, match="multiple of --chunk"):
        convert.main(["--traj-path", str(SAMPLE), "--out", str(tmp_path / "bad"), "--start", "1", "--chunk", "2"])
    module = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    export = tmp_path / "mlp.pt"
    args = module.Args(data=str(sample_data), run=str(tmp_path / "run"), steps=8, until_step=4, export=True,
                       export_path=str(export), **TINY, **TRAINER_KW["mlp"])
    first = module.main(args)
    # A stopped call exports what it has (one shard of a longer run) and says so.
    _, meta = load_model(export)
    assert first["stopped"] and first["step"] == 4 and meta["step"] == 4 and not meta["schedule_complete"]
    args.data, args.until_step = str(shard), 0
    with pytest.raises(ValueError, match="--new-data"):
        module.main(args)
    args.new_data = True
    second = module.main(args)
    assert second["step"] == 8 and not second["stopped"]
    _, meta = load_model(export)
    hashes = [d["data_sha256"] for d in meta["data_history"]]
    assert [d["from_step"] for d in meta["data_history"]] == [0, 4] and hashes[0] != hashes[1] == meta["data_sha256"]
    assert meta["schedule_complete"]
    # The data hash is that of the files loaded, whose sha256s the converter's manifest lists.
    manifest = json.loads((shard / "manifest.json").read_text())
    listed = "".join(f"{c['file']} {c['sha256']}\n" for c in manifest["chunks"])
    assert manifest["complete"] and hashlib.sha256(listed.encode()).hexdigest() == meta["data_sha256"]


def test_a_run_goes_on_from_an_export(sample_data, tmp_path):
    """--init-from: a new run folder starts from an exported checkpoint (the fp16 weights alone,
    what a session can keep of a run): its step, weights and data history go on, the learning
    rate warms up again for the fresh optimiser, and an export of another network is refused
    with the difference named."""
    module = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    first_export = tmp_path / "first.pt"
    args = module.Args(data=str(sample_data), run=str(tmp_path / "run1"), steps=12, until_step=5, export=True,
                       export_path=str(first_export), **{**TINY, "warmup": 3}, **TRAINER_KW["mlp"])
    assert module.main(args)["step"] == 5
    exported, _ = load_model(first_export)
    second_export = tmp_path / "second.pt"
    args.run, args.until_step, args.init_from, args.export_path = (str(tmp_path / "run2"), 0, str(first_export),
                                                                    str(second_export))
    common = sys.modules["common"]
    # The first step taken from the export: the weights are the export's, the rate warms up again.
    seen = {}
    real_lr_at = common.lr_at

    def spy(step, a, restart=0):
        if step == 5 and "weights" not in seen:
            seen["weights"] = {k: v.clone() for k, v in spy.model.state_dict().items()}
        seen.setdefault("lr", []).append((step, real_lr_at(step, a, restart)))
        return real_lr_at(step, a, restart)

    real_make = module.make_model

    def make(a):
        spy.model = real_make(a)
        return spy.model

    common.lr_at, module.make_model = spy, make
    try:
        result = module.main(args)
    finally:
        common.lr_at, module.make_model = real_lr_at, real_make
    assert result["step"] == 12 and not result["stopped"]
    assert all(torch.equal(seen["weights"][k], v) for k, v in exported.state_dict().items())
    rates = dict(seen["lr"])
    schedule = real_lr_at(5, args)
    assert rates[5] == pytest.approx(schedule / 3) and rates[6] == pytest.approx(real_lr_at(6, args) * 2 / 3)
    assert rates[8] == pytest.approx(real_lr_at(8, args))
    _, meta = load_model(second_export)
    assert meta["init_from"]["step"] == 5 and meta["init_from"]["sha256"] == hashlib.sha256(
        first_export.read_bytes()).hexdigest()
    assert [d["from_step"] for d in meta["data_history"]] == [0] and meta["step"] == 12
    assert "from " + str(first_export) + " at step 5" in (tmp_path / "run2" / "log.txt").read_text()
    # Re-running the same command resumes run2's own checkpoint (init_from is not read again).
    args.steps = 14
    assert module.main(args)["step"] == 14
    assert "resumed at step 12" in (tmp_path / "run2" / "log.txt").read_text()
    # Another network, another trainer's export: refused, naming what differs.
    args.run, args.hidden = str(tmp_path / "run3"), 32
    with pytest.raises(ValueError, match="hidden: 64 vs 32"):
        module.main(args)
    transformer = _import(ROOT / "baselines/imitation/train_transformer.py", "train_transformer")
    other = transformer.Args(data=str(sample_data), run=str(tmp_path / "run4"), steps=12, init_from=str(first_export),
                             **TINY, **TRAINER_KW["transformer"])
    with pytest.raises(ValueError, match="is a mlp checkpoint, this trainer trains transformer"):
        transformer.main(other)


# ----------------------------------------------------------------------------- frame stride
FRAME_STRIDE = 3


@pytest.fixture(scope="module")
def sample_data_k3(tmp_path_factory) -> Path:
    """``sample_data``'s demos and steps converted with --frame-stride 3: a replay without
    rendering, then the kept frames rendered from its env states."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    out = tmp_path_factory.mktemp("imit-data-k3")
    assert convert.main(["--traj-path", str(SAMPLE), "--out", str(out), "--count", "2", "--chunk", "2",
                         "--first-steps", str(FIRST_STEPS), "--sizes", "128,64,32",
                         "--frame-stride", str(FRAME_STRIDE)]) == 0
    return out


def test_select_frames_on_hand_made_labels():
    """Every K-th step of each stage segment; a kept step's arm action is the mean over its
    window (cut at the segment's end), its gripper action and stage are its own, and a
    segment's last kept step ends the stage exactly when the segment's last step does."""
    stage = np.array([0] * 7 + [1] * 3 + [2] * 5)
    stage_end = np.zeros(15, bool)
    stage_end[[3, 6, 14]] = True  # 3: inside a segment (no stage ends there); the close stage (9) is not marked
    arm = 0.01 * np.arange(15)[:, None] + 0.001 * np.arange(7)[None]
    gripper = np.r_[[1.0] * 8, [-1.0] * 7]  # changes inside the window [7, 10)
    actions = np.c_[arm, gripper].astype(np.float32)
    out = select_frames(stage, stage_end, actions, 3)
    assert out["frame"].tolist() == [0, 3, 6, 7, 10, 13]
    windows = [(0, 3), (3, 6), (6, 7), (7, 10), (10, 13), (13, 15)]
    assert np.allclose(out["action"], [arm[a:b].mean(axis=0) for a, b in windows], atol=1e-6)
    assert out["action"].dtype == np.float32 and out["action"].shape == (6, 7)
    assert out["gripper"].tolist() == [1, 1, 1, 1, -1, -1]
    assert out["stage"].tolist() == [0, 0, 0, 1, 2, 2] and out["stage"].dtype == np.int8
    assert out["stage_end"].tolist() == [False, False, True, False, False, True]
    # A stride longer than every segment: one frame a segment, its action the segment's mean.
    out = select_frames(stage, stage_end, actions, 20)
    assert out["frame"].tolist() == [0, 7, 10] and out["stage_end"].tolist() == [True, False, True]
    assert np.allclose(out["action"], [arm[a:b].mean(axis=0) for a, b in [(0, 7), (7, 10), (10, 15)]], atol=1e-6)
    # Stride 1: every step, its own action.
    out = select_frames(stage, stage_end, actions, 1)
    assert out["frame"].tolist() == list(range(15)) and np.array_equal(out["action"], actions[:, :7])
    assert np.flatnonzero(out["stage_end"]).tolist() == [6, 14]


def test_rendering_a_recorded_state_equals_rendering_in_the_replay():
    """The clouds of --frame-stride K come from recorded env states set into an env
    (``StateRenderer``), not from the replay's own steps. Rendered both ways at the same
    steps of a demo, the camera clouds agree but for a handful of their 153,600 points (the
    Panda's link poses after a state set are its kinematics', ~1e-8 m from the simulated
    ones): the render after a state set is fresh and shows that state."""
    import gymnasium as gym
    import h5py
    from mani_skill.utils.common import to_numpy

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.render_env_states import StateRenderer, render_env_kwargs

    meta = json.loads(SAMPLE.with_suffix(".json").read_text())
    env_id, env_kwargs, episode = meta["env_info"]["env_id"], meta["env_info"]["env_kwargs"], meta["episodes"][0]
    with h5py.File(SAMPLE, "r") as f:
        actions = f[f"traj_{episode['episode_id']}"]["actions"][:8]
    replay = gym.make(env_id, **render_env_kwargs(env_kwargs))
    renderer = StateRenderer(env_id, env_kwargs)
    try:
        replay.reset(**episode["reset_kwargs"])
        renderer.env.reset(**episode["reset_kwargs"])
        clouds = []
        for t in range(len(actions) + 1):
            if t:
                replay.step(actions[t - 1])
            if t % 4:
                continue
            stepped = replay.unwrapped.get_obs()["pointcloud"]
            from_state = renderer.observation(replay.unwrapped.get_state_dict())["pointcloud"]
            (xyz, label), (xyz_s, label_s) = [(to_numpy(c["xyz_base"])[0], to_numpy(c["fetch_label"])[0])
                                              for c in (stepped, from_state)]
            differs = np.abs(xyz - xyz_s).max(axis=1) > 1e-6
            assert differs.sum() <= 30 and (label != label_s).sum() <= 5, (t, differs.sum(), (label != label_s).sum())
            assert np.abs(xyz - xyz_s)[label == label_s].max() < 5e-3, t
            clouds.append(xyz)
        # The arm moved between the steps compared: a stale render would have shown.
        assert (np.abs(clouds[-1] - clouds[0]).max(axis=1) > 1e-3).sum() > 1000
    finally:
        replay.close()
        renderer.close()


def test_strided_conversion_keeps_the_replays_frames(sample_data, sample_data_k3):
    """--frame-stride 3 against the stride-1 conversion of the same demos and steps: its
    frames are select_frames of the stride-1 frames (the steps, their joints and TCP, the
    window-mean arm actions, gripper, stage and stage_end), and their points are the stride-1
    points at those steps, to the bit in most segments (the rest are another draw of the
    compact cloud from a render that differs in a few camera points, see the test above; a
    wrong step, seed or task would leave none equal)."""
    one, strided = load_training_files(sample_data, sizes=SIZES), load_training_files(sample_data_k3, sizes=SIZES)
    assert one["frame_stride"] == 1 and strided["frame_stride"] == FRAME_STRIDE
    manifest = json.loads((sample_data_k3 / "manifest.json").read_text())
    assert manifest["settings"]["frame_stride"] == FRAME_STRIDE and manifest["complete"]
    assert [e["episode_id"] for e in strided["episodes"]] == [e["episode_id"] for e in one["episodes"]]
    segments = list(segment_slices(SIZES).values())
    same = []
    for e1, e3, s1, s3 in zip(one["episodes"], strided["episodes"], one["episode_start"], strided["episode_start"]):
        assert e3["converted_length"] == e1["length"] and e3["source_length"] == e1["source_length"]
        rows = np.arange(s1, s1 + e1["length"])
        kept = select_frames(one["stage"][rows], one["stage_end"][rows],
                             np.c_[one["action"][rows], one["gripper"][rows]], FRAME_STRIDE)
        frames = s1 + kept.pop("frame")
        assert e3["length"] == len(frames) == -(-e1["length"] // FRAME_STRIDE)  # one stage in the first steps
        mine = np.arange(s3, s3 + e3["length"])
        assert np.array_equal(strided["qpos"][mine], one["qpos"][frames])
        assert np.array_equal(strided["tcp"][mine], one["tcp"][frames])
        for key, value in kept.items():
            assert np.array_equal(strided[key][mine], value), key
        for f1, f3 in zip(frames, mine):
            same.append([np.array_equal(one["points"][f1, s], strided["points"][f3, s])
                         and np.array_equal(one["point_label"][f1, s], strided["point_label"][f3, s])
                         for s in segments])
    same = np.array(same)
    print(f"segments equal to the bit: {same.sum()} of {same.size}")
    assert same.mean() >= 0.6 and same.all(axis=1).any()
    # The folder holds stride 3: another stride is refused before anything runs.
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    with pytest.raises(SystemExit, match="frame_stride"):
        convert.main(["--traj-path", str(SAMPLE), "--out", str(sample_data_k3), "--count", "2", "--chunk", "2",
                      "--first-steps", str(FIRST_STEPS), "--sizes", "128,64,32"])


def test_overlapped_replay_writes_the_same_files(tmp_path, monkeypatch):
    """--overlap-replay (chunk k + 1's state-only replay in the background during chunk k's
    render) writes the sequential conversion's bytes; an error during a chunk stops the
    background replay and removes its work folder, and the same command then resumes."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    common = ["--traj-path", str(SAMPLE), "--count", "2", "--chunk", "1", "--first-steps", str(FIRST_STEPS),
              "--sizes", "128,64,32", "--frame-stride", str(FRAME_STRIDE)]
    with pytest.raises(SystemExit, match="--overlap-replay.*K > 1"):
        convert.main(common[:-2] + ["--out", str(tmp_path / "k1"), "--overlap-replay"])
    assert convert.main(common + ["--out", str(tmp_path / "seq")]) == 0
    # The first try fails in chunk 0's render, its replay of chunk 1 started in the background.
    started, start_replay, convert_episodes = [], convert.start_replay, convert.convert_episodes

    def recorded(*args, **kwargs):
        started.append(start_replay(*args, **kwargs))
        return started[-1]

    def failing(*args, **kwargs):
        raise RuntimeError("a failed render")

    monkeypatch.setattr(convert, "start_replay", recorded)
    monkeypatch.setattr(convert, "convert_episodes", failing)
    with pytest.raises(RuntimeError, match="a failed render"):
        convert.main(common + ["--out", str(tmp_path / "overlap"), "--overlap-replay"])
    assert [(r.chunk, r.background) for r in started] == [(0, False), (1, True)]
    assert started[1].process.poll() is not None and not started[1].work.exists()
    monkeypatch.setattr(convert, "convert_episodes", convert_episodes)
    assert convert.main(common + ["--out", str(tmp_path / "overlap"), "--overlap-replay"]) == 0
    log = (tmp_path / "overlap" / "convert.log").read_text()
    assert "stopped the replay of chunk 1" in log and "the converter waited" in log
    seq, overlap = (sorted((tmp_path / name).glob("chunk_*.imit.h5")) for name in ("seq", "overlap"))
    assert [p.name for p in seq] == [p.name for p in overlap] == ["chunk_00000.imit.h5", "chunk_00001.imit.h5"]
    assert [hashlib.sha256(p.read_bytes()).hexdigest() for p in seq] == \
        [hashlib.sha256(p.read_bytes()).hexdigest() for p in overlap]
    assert (tmp_path / "seq" / "manifest.json").read_text() == (tmp_path / "overlap" / "manifest.json").read_text()
    assert not (tmp_path / "overlap" / "work").exists()


def test_training_files_of_two_frame_strides_are_refused(sample_data, sample_data_k3, tmp_path):
    import shutil

    shutil.copyfile(sample_data / "chunk_00000.imit.h5", tmp_path / "chunk_00000.imit.h5")
    shutil.copyfile(sample_data_k3 / "chunk_00000.imit.h5", tmp_path / "chunk_00001.imit.h5")
    with pytest.raises(ValueError, match="--frame-stride 3.*every 1"):
        load_training_files(tmp_path, sizes=SIZES)


def test_trainer_records_the_frame_stride(sample_data, sample_data_k3, tmp_path):
    """A trainer on stride-3 data records the stride in its checkpoint and export; the run
    refuses data of another stride; the policy warns when deployed at another stride."""
    module = _import(ROOT / "baselines/imitation/train_mlp.py", "train_mlp")
    export = tmp_path / "mlp.pt"
    args = module.Args(data=str(sample_data_k3), run=str(tmp_path / "run"), steps=3, export=True,
                       export_path=str(export), **TINY, **TRAINER_KW["mlp"])
    assert module.main(args)["step"] == 3
    assert torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)["frame_stride"] == FRAME_STRIDE
    assert json.loads(export.with_suffix(".json").read_text())["frame_stride"] == FRAME_STRIDE
    _, meta = load_model(export)
    assert meta["frame_stride"] == FRAME_STRIDE
    args.data, args.new_data, args.steps = str(sample_data), True, 6
    with pytest.raises(ValueError, match="frames every 3 converted steps"):
        module.main(args)
    with pytest.warns(UserWarning, match="trained on data of --frame-stride 3"):
        ImitationPolicy.load(export)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ImitationPolicy.load(export, stride=FRAME_STRIDE)



def test_trainer_val_success_runs_at_the_data_stride(sample_data_k3, tmp_path, monkeypatch):
    """The trainer's val-task evaluation of stride-3 data deploys the policy as it learned:
    policy stride 3, and an evaluation checkpoint whose meta carries frame_stride 3 (which a
    diffusion policy's chunk repeat reads); the figure records the stride."""
    import fetchbench_ms.evaluation.runner as runner

    asked = []

    def fake_evaluate(method, out_dir, **kwargs):
        _, meta = load_model(kwargs["policy_checkpoint"])
        asked.append((method, kwargs["suite"], kwargs["policy_stride"], meta["frame_stride"]))
        return [{"task_id": "val/0000", "category": "on_table", "success": True, "failure": None,
                 "computation_time": 1.0, "cspace_length": 1.0}]

    monkeypatch.setattr(runner, "evaluate", fake_evaluate)
    module = _import(ROOT / "baselines/imitation/train_diffusion.py", "train_diffusion")
    tiny = {**TINY, "eval_every": 2, "eval_tasks": 1, "eval_workers": 1}
    args = module.Args(data=str(sample_data_k3), run=str(tmp_path / "run"), steps=2, **tiny, **TRAINER_KW["diffusion"])
    history = module.main(args)["history"]
    assert asked == [("e2e-diffusion", "val", FRAME_STRIDE, FRAME_STRIDE)]
    assert history["val_success"][-1]["policy_stride"] == FRAME_STRIDE

# ----------------------------------------------------------------------------- deployment
def test_regrasp_state_machine_scripted():
    cfg = ReGraspConfig(close_steps=3, reopen_steps=2, settle_steps=1, min_approach_steps=2, min_retrieve_steps=3,
                        max_regrasps=1)
    m = ReGraspStateMachine(cfg)
    open_gap, closed_gap, holding_gap = 0.08, 0.0, 0.03
    phases = []

    def step(gap, p):
        phase = m.begin_step(gap)
        phases.append((phase, m.gripper, m.acting))
        m.end_step(p if m.acting else None)

    step(open_gap, 0.9)  # fires before min_approach_steps: ignored
    step(open_gap, 0.1)
    step(open_gap, 0.9)  # -> close
    assert m.phase == CLOSE
    for _ in range(3):
        step(open_gap, None)
    step(holding_gap, 0.1)  # retrieval begins
    assert m.phase == RETRIEVE
    step(closed_gap, 0.1)  # fingers met: grasped nothing
    step(closed_gap, 0.1)
    assert m.phase == REOPEN
    step(open_gap, None)
    step(open_gap, None)
    step(open_gap, 0.1)  # back in approach, one re-grasp counted
    assert m.phase == APPROACH and m.regrasps == 1
    step(open_gap, 0.1)
    step(open_gap, 0.95)
    for _ in range(3):
        step(open_gap, None)
    step(closed_gap, 0.1)
    step(closed_gap, 0.99)  # max_regrasps reached: stays in retrieval; fires before min_retrieve_steps: ignored
    assert m.phase == RETRIEVE
    step(closed_gap, 0.99)
    assert m.phase == DONE
    # the gripper follows the phase; the network acts only in approach and retrieval
    gripper = {p: g for p, g, _ in phases}
    assert gripper[APPROACH] == GRIPPER_OPEN and gripper[REOPEN] == GRIPPER_OPEN
    assert gripper[CLOSE] == GRIPPER_CLOSED and gripper[RETRIEVE] == GRIPPER_CLOSED
    assert {p for p, _, acting in phases if acting} == {APPROACH, RETRIEVE}
    assert [t[2] for t in m.log] == [CLOSE, RETRIEVE, REOPEN, APPROACH, CLOSE, RETRIEVE, DONE]
    # two-stage: a closed gripper never re-opens
    two = ReGraspStateMachine(ReGraspConfig(regrasp=False), phase=RETRIEVE)
    for _ in range(20):
        two.begin_step(0.0)
        two.end_step(0.0)
    assert two.phase == RETRIEVE


def _synthetic_obs(rng, finger: float) -> dict:
    n = sum(COMPACT_SIZES.values())
    seg = np.full(n, LABEL_FURNITURE, np.uint8)
    seg[16384:18432], seg[18432:] = LABEL_TARGET, LABEL_ROBOT
    qpos = np.r_[0.0, -1.0, 0.0, -2.2, 0.0, 1.2, 0.5, finger, finger].astype(np.float32)
    return {"pointcloud": {"xyz": rng.uniform(-0.5, 1.0, (1, n, 3)).astype(np.float16), "seg": seg[None]},
            "agent": {"qpos": qpos[None]}}


def test_policy_drives_state_machine_and_resets_history(monkeypatch):
    """A policy whose termination output is scripted: the gripper, the frozen arm while
    closing and the history restarting at each phase."""
    from fetchbench_ms.policies.networks import EncoderConfig, TransformerConfig, TransformerPolicy

    model = TransformerPolicy(TransformerConfig(encoder=EncoderConfig(sizes=SIZES, point_dims=(16, 32), point_out=32),
                                                d_model=32, layers=1, heads=2))
    policy = ImitationPolicy(model, regrasp=ReGraspConfig(close_steps=2, min_approach_steps=1, settle_steps=1))
    script = iter([0.1, 0.9, 0.1, 0.1, 0.1])
    seen_history = []

    def act(self, batch, termination_only=False):
        seen_history.append(len(self.history))
        return np.full((1, 1, 7), 0.5, np.float32), np.array([next(script)])

    monkeypatch.setattr(ImitationPolicy, "_act", act)
    rng = np.random.default_rng(0)
    policy.reset(episode_seed=0)
    actions = [policy.get_action(_synthetic_obs(rng, 0.04)) for _ in range(4)]  # approach x2, close x2
    actions += [policy.get_action(_synthetic_obs(rng, 0.02)) for _ in range(2)]  # retrieve
    actions = np.concatenate(actions)
    assert actions.shape == (6, 8) and actions.dtype == np.float32
    assert actions[:2, 7].tolist() == [GRIPPER_OPEN] * 2 and (actions[2:, 7] == GRIPPER_CLOSED).all()
    assert np.allclose(actions[:2, :7], 0.5) and np.allclose(actions[2:4, :7], 0.0) and np.allclose(actions[4:, :7], 0.5)
    assert seen_history == [1, 2, 1, 2]  # the retrieval history starts afresh


def test_observation_input_from_raw_pointcloud():
    """The hybrids read obs_mode='pointcloud': the compact cloud is made as the env would."""
    rng = np.random.default_rng(1)
    n = 5000
    labels = rng.choice([LABEL_FURNITURE, LABEL_TARGET, LABEL_ROBOT], n).astype(np.uint8)
    raw = {"pointcloud": {"xyz_base": rng.uniform(0.0, 1.0, (1, n, 3)).astype(np.float32), "fetch_label": labels[None]},
           "agent": {"qpos": np.zeros((1, 9), np.float32)}}
    a = observation_input(raw, SIZES, episode_seed=3, step=7)
    b = observation_input(raw, SIZES, episode_seed=3, step=7)
    assert a.points.shape == (1, 224, 3) and np.array_equal(a.points, b.points)
    assert (a.point_label[0, 128:192] == LABEL_TARGET).all() and (a.point_label[0, 192:] == LABEL_ROBOT).all()
    with pytest.raises(ValueError, match="compact_pointcloud"):
        observation_input({"pointcloud": {"rgb": np.zeros(1)}, "agent": {"qpos": np.zeros((1, 9))}}, SIZES)


def test_checkpoints_act_in_the_env(sample_data, tmp_path):
    """Checkpoints saved by the trainers load and act on a smoke task: the eval path (a
    pd_joint_pos env, deltas turned into targets) and get_action's valid actions."""
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.evaluation.methods import resolve_run
    from fetchbench_ms.method_spec import RunSpec, method_spec
    from fetchbench_ms.policies import deploy

    paths = {}
    for kind in ("mlp", "diffusion", "act"):
        module = _import(ROOT / f"baselines/imitation/train_{kind}.py", f"train_{kind}")
        paths[kind] = tmp_path / f"{kind}.pt"
        module.main(module.Args(data=str(sample_data), run=str(tmp_path / kind), steps=2, export=True,
                                export_path=str(paths[kind]), **TINY, **TRAINER_KW[kind]))
    run = resolve_run("e2e-mlp", policy_checkpoint=str(paths["mlp"]))
    assert run.obs_mode == "compact_pointcloud"
    assert resolve_run("cgn-imit-diffusion", policy_checkpoint=str(paths["diffusion"])).obs_mode == "pointcloud"
    assert resolve_run("twostage-mlp", policy_checkpoint=str(paths["mlp"])).obs_mode == "compact_pointcloud"
    assert resolve_run("e2e-act", policy_checkpoint=str(paths["act"])).obs_mode == "compact_pointcloud"
    assert resolve_run("cgn-imit-act", policy_checkpoint=str(paths["act"])).obs_mode == "pointcloud"
    with pytest.raises(FileNotFoundError, match="train_transformer.py"):
        resolve_run("e2e-transformer", policy_checkpoint=str(tmp_path / "missing.pt"))
    with pytest.raises(ValueError, match="e2e-mlp needs a mlp checkpoint"):
        deploy.load_policy(method_spec("e2e-mlp"), str(paths["diffusion"]), device="cpu")

    env = gym.make("FetchBench-v0", obs_mode="compact_pointcloud", control_mode="pd_joint_pos", task_suite="smoke")
    try:
        env.reset(seed=0)
        u = env.unwrapped
        obs = u.get_obs(unflattened=True)
        for method in ("e2e-diffusion", "e2e-act"):  # ACT: a chunk each step, ensembled
            spec = method_spec(method)
            policy = deploy.load_policy(spec, str(paths[spec.policy.name]), device="cpu")
            policy.reset(episode_seed=0)
            for _ in range(2):
                action = policy.get_action(obs)
                assert action.shape == (1, 8) and np.isfinite(action).all() and np.abs(action).max() <= 1.0
                qpos = u.agent.robot.get_qpos()[0].cpu().numpy()
                target = deploy.env_action(env, action)
                assert np.allclose(target[0, :7], qpos[:7] + 0.1 * action[0, :7], atol=1e-6)
                obs, *_ = env.step(target)
        assert policy.model.kind == "act" and len(policy.ensemble.chunks) == 2
        record = deploy.run_e2e(env, 0, RunSpec(method_spec("e2e-mlp"), policy_checkpoint=str(paths["mlp"])), max_steps=3)
        assert record["policy_steps"] == 3 and isinstance(record["success"], bool)
        assert record["cspace_length"] > 0 and record["checkpoint"] == str(paths["mlp"])
    finally:
        env.close()


def test_unknown_phase_and_kind_are_named():
    from fetchbench_ms.policies.networks import build_policy

    with pytest.raises(ValueError, match="valid: mlp, transformer, diffusion"):
        build_policy("gpt")
    policy = ImitationPolicy(build_policy("mlp"))
    with pytest.raises(ValueError, match="valid: approach"):
        policy.reset(phase="grasp")
    assert agent_mod.PHASES[0] == APPROACH


# ----------------------------------------------------------------------------- policy stride
def _tiny_model(kind: str, **act_config):
    from fetchbench_ms.policies.networks import (ACTConfig, ACTPolicy, DiffusionConfig, DiffusionPolicy, EncoderConfig,
                                                 MLPConfig, MLPPolicy, TransformerConfig, TransformerPolicy)

    encoder = EncoderConfig(sizes=SIZES, point_dims=(16, 32), point_out=32)
    if kind == "act":
        return ACTPolicy(ACTConfig(encoder=encoder, **{**TINY_ACT, **act_config}))
    if kind == "mlp":
        return MLPPolicy(MLPConfig(encoder=encoder, hidden=32))
    if kind == "transformer":
        return TransformerPolicy(TransformerConfig(encoder=encoder, d_model=32, layers=1, heads=2))
    return DiffusionPolicy(DiffusionConfig(encoder=encoder, unet_dims=(16, 32), pred_horizon=8, act_horizon=4,
                                           train_steps=20, sample_steps=4))


def _scripted_network(monkeypatch, terminations: dict | None = None, chunk: int = 1) -> list:
    """The network replaced: its i-th call returns the arm actions 0.01 (i + 1) + 0.001 j for
    the chunk's rows j and the termination ``terminations.get(i, 0.1)``. Returns the calls'
    log: (termination only, history length)."""
    calls = []

    def act(self, batch, termination_only=False):
        i = len(calls)
        calls.append((termination_only, len(self.history)))
        rows = 0.01 * (i + 1) + 0.001 * np.arange(chunk, dtype=np.float32)
        return np.repeat(rows[None, :, None], 7, axis=2), np.array([(terminations or {}).get(i, 0.1)])

    monkeypatch.setattr(ImitationPolicy, "_act", act)
    return calls


def _split_steps(policy: ImitationPolicy, gaps, rng) -> tuple[list, np.ndarray]:
    """Drive ``policy`` through begin_step / act, the observation given only when asked for;
    returns (asked, actions [n, 8])."""
    asked, actions = [], []
    for gap in gaps:
        obs = _synthetic_obs(rng, gap / 2)
        asked.append(policy.begin_step(obs["agent"]["qpos"][0]))
        actions.append(policy.act(obs if asked[-1] else None)[0])
    return asked, np.stack(actions)


@pytest.mark.parametrize("kind", ["transformer", "diffusion"])
def test_stride_one_split_steps_are_get_action(kind, monkeypatch):
    """Stride 1 is the trained behaviour: begin_step + act, the observation given only when
    asked for, act as get_action with every observation does (actions, network calls,
    transitions), and every acting step is observed."""
    calls = _scripted_network(monkeypatch, {2: 0.9, 9: 0.9}, chunk=4 if kind == "diffusion" else 1)
    config = ReGraspConfig(close_steps=2, reopen_steps=2, settle_steps=1, min_approach_steps=1, min_retrieve_steps=3)
    # approach x3, close x2, retrieve x4, reopen x2 (fingers met), approach x3, close x2, retrieve x7
    gaps = [0.04] * 6 + [0.02] * 3 + [0.0] * 3 + [0.04] * 5 + [0.02] * 6

    def episode(split: bool):
        calls.clear()
        policy = ImitationPolicy(_tiny_model(kind), regrasp=config)
        policy.reset(episode_seed=0)
        rng = np.random.default_rng(0)
        if split:
            asked, actions = _split_steps(policy, gaps, rng)
        else:
            asked, actions = None, np.concatenate([policy.get_action(_synthetic_obs(rng, g / 2)) for g in gaps])
        return actions, policy.machine.log, list(calls), asked

    actions, log, net, _ = episode(split=False)
    split_actions, split_log, split_net, asked = episode(split=True)
    assert np.array_equal(actions, split_actions) and log == split_log and net == split_net
    assert [to for _, _, to in log] == [CLOSE, RETRIEVE, REOPEN, APPROACH, CLOSE, RETRIEVE]
    closing_or_reopening = [3, 4, 9, 10, 14, 15]
    assert len(net) == sum(asked) == len(gaps) - len(closing_or_reopening)
    assert not any(asked[i] for i in closing_or_reopening)
    if kind == "transformer":  # the network at every acting step
        assert not any(only for only, _ in net)
    else:  # a new chunk when the queue is empty, else a termination-only pass at every step
        assert [only for only, _ in net][:7] == [False, True, True, False, True, True, True]


def test_stride_repeats_the_arm_action_between_observations(monkeypatch):
    """Stride 3: the network reads the 1st, 4th, 7th ... acting step of a phase and its arm
    action is repeated in between, where no observation is asked for and no termination is
    fed; close and reopen never ask; the history holds the observed steps only."""
    calls = _scripted_network(monkeypatch, {2: 0.9})
    fed = []
    end_step = ReGraspStateMachine.end_step
    monkeypatch.setattr(ReGraspStateMachine, "end_step", lambda self, p=None: fed.append(p) or end_step(self, p))
    config = ReGraspConfig(close_steps=2, reopen_steps=2, settle_steps=1, min_approach_steps=1, min_retrieve_steps=50)
    policy = ImitationPolicy(_tiny_model("transformer"), regrasp=config, stride=3)
    policy.reset(episode_seed=0)
    # approach x7 (the 3rd call terminates), close x2, retrieve x4, fingers met: reopen x2, approach x2
    asked, actions = _split_steps(policy, [0.04] * 9 + [0.02] * 4 + [0.0] + [0.04] * 3, np.random.default_rng(0))
    T, F = True, False
    assert asked == [T, F, F, T, F, F, T, F, F, T, F, F, T, F, F, T, F]
    assert [p is not None for p in fed] == asked  # termination only from an evaluated step
    assert [to for _, _, to in policy.machine.log] == [CLOSE, RETRIEVE, REOPEN, APPROACH]
    assert policy.machine.log[0] == (7, APPROACH, CLOSE)
    assert len(calls) == 3 + 2 + 1  # ceil(7 / 3) approach, ceil(4 / 3) retrieval, 1 approach again
    assert [h for _, h in calls] == [1, 2, 3, 1, 2, 1]  # a frame per observed step, afresh each phase
    arm = [0.01] * 3 + [0.02] * 3 + [0.03] + [0.0] * 2 + [0.04] * 3 + [0.05] + [0.0] * 2 + [0.06] * 2
    assert np.allclose(actions[:, :7], np.array(arm)[:, None], atol=1e-6), actions[:, 0]
    assert (actions[:7, 7] == GRIPPER_OPEN).all() and (actions[7:13, 7] == GRIPPER_CLOSED).all()
    assert (actions[13:, 7] == GRIPPER_OPEN).all()


def test_diffusion_stride_runs_chunks_and_checks_termination_every_k_steps(monkeypatch):
    """Stride 3, a diffusion policy: its chunks (4 actions) run as with stride 1; between
    chunks the termination is checked every 3rd step only."""
    calls = _scripted_network(monkeypatch, chunk=4)
    policy = ImitationPolicy(_tiny_model("diffusion"), stride=3)
    policy.reset(episode_seed=0)
    asked, actions = _split_steps(policy, [0.04] * 9, np.random.default_rng(0))
    T, F = True, False
    assert asked == [T, F, F, T, T, F, F, T, T]
    assert [only for only, _ in calls] == [False, True, False, True, False]
    assert np.allclose(actions[:, 0], [0.01, 0.011, 0.012, 0.013, 0.03, 0.031, 0.032, 0.033, 0.05], atol=1e-6)


@pytest.mark.parametrize("kind", ["diffusion", "act"])
def test_open_loop_chunk_trained_on_strided_frames_repeats_each_action(kind, monkeypatch):
    """A diffusion checkpoint (or an ACT one with ``temporal_ensemble=False``) of --frame-stride
    3 data: each of its chunk's actions stood for 3 control steps in training, so each lasts 3
    steps here (a chunk of 4: 12 steps); at policy stride 3 the termination is checked every
    3rd step, and no warning is given."""
    calls = _scripted_network(monkeypatch, chunk=4)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = _tiny_model("act", temporal_ensemble=False) if kind == "act" else _tiny_model(kind)
        policy = ImitationPolicy(model, meta={"frame_stride": 3}, stride=3)
    assert policy.open_loop and policy.ensemble is None
    policy.reset(episode_seed=0)
    asked, actions = _split_steps(policy, [0.04] * 13, np.random.default_rng(0))
    T, F = True, False
    assert asked == [T, F, F, T, F, F, T, F, F, T, F, F, T]
    assert [only for only, _ in calls] == [False, True, True, True, False]
    assert np.allclose(actions[:12, 0], np.repeat([0.01, 0.011, 0.012, 0.013], 3), atol=1e-6)
    assert np.isclose(actions[12, 0], 0.05, atol=1e-6)


def test_invalid_stride_and_misused_steps_are_named(monkeypatch):
    from fetchbench_ms.evaluation.methods import resolve_run

    model = _tiny_model("mlp")
    for stride in (0, -2, 1.5, "2", True, None):
        with pytest.raises(ValueError, match="integer >= 1"):
            ImitationPolicy(model, stride=stride)
    with pytest.raises(ValueError, match="integer >= 1"):  # before any task runs
        resolve_run("e2e-mlp", policy_stride=0)
    _scripted_network(monkeypatch)
    policy = ImitationPolicy(model, stride=np.int64(2))
    assert policy.stride == 2
    qpos = np.r_[np.zeros(7), 0.04, 0.04]
    with pytest.raises(RuntimeError, match="begin_step"):
        policy.act()
    assert policy.begin_step(qpos)
    with pytest.raises(RuntimeError, match="twice"):
        policy.begin_step(qpos)
    with pytest.raises(ValueError, match="needs the observation"):
        policy.act()
    policy.act(_synthetic_obs(np.random.default_rng(0), 0.04))
    assert not policy.begin_step(qpos)  # the repeated step: no observation
    assert policy.act().shape == (1, 8)


def test_policy_stride_reaches_the_episode(monkeypatch):
    """--policy-stride K: the CLI, the runner's spec and the method hand K to the episode."""
    from fetchbench_ms.cli import build_parser
    from fetchbench_ms.evaluation.methods import TaskRunner, resolve_run
    from fetchbench_ms.policies import deploy

    assert build_parser().parse_args(["eval", "--method", "e2e-mlp", "--policy-stride", "3"]).policy_stride == 3
    assert build_parser().parse_args(["eval"]).policy_stride == 1
    seen = {}
    monkeypatch.setattr(deploy, "run_e2e", lambda env, seed, run: seen.update(e2e=run.policy_stride))
    monkeypatch.setattr(deploy, "run_hybrid", lambda env, seed, run: seen.update(hybrid=run.policy_stride))
    TaskRunner(resolve_run("e2e-mlp", policy_stride=3)).method.run(None, 0)
    TaskRunner(resolve_run("cgn-imit-mlp", policy_stride=4)).method.run(None, 0)
    assert seen == {"e2e": 3, "hybrid": 4}


def test_strided_episode_renders_fewer_observations(tmp_path):
    """An e2e episode on a smoke task renders the cameras (the env's get_obs) only at the steps
    the policy reads: every step with stride 1, every other one with stride 2; the records
    say so."""
    import gymnasium as gym

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.method_spec import RunSpec, method_spec
    from fetchbench_ms.policies import deploy

    model = _tiny_model("mlp")
    with torch.no_grad():  # a termination that never fires: every step is an approach step
        model.head.weight[-1].zero_()
        model.head.bias[-1] = -20.0
    path = tmp_path / "mlp.pt"
    agent_mod.save_checkpoint(path, model, {})
    env = gym.make("FetchBench-v0", obs_mode="compact_pointcloud", control_mode="pd_joint_pos", task_suite="smoke")
    try:
        u = env.unwrapped
        get_obs, rendered = u.get_obs, []
        u.get_obs = lambda *args, **kwargs: rendered.append(1) or get_obs(*args, **kwargs)
        records = {}
        for stride in (1, 2):
            env.reset(seed=0)
            rendered.clear()
            run = RunSpec(method_spec("e2e-mlp"), policy_checkpoint=str(path), policy_stride=stride)
            records[stride] = deploy.run_e2e(env, 0, run, max_steps=7)
            assert records[stride]["observations"] == len(rendered)
            assert int(u.elapsed_steps[0]) == 7 and records[stride]["policy_steps"] == 7
            assert records[stride]["policy_stride"] == stride and records[stride]["phase_log"] == []
        assert records[1]["observations"] == 7 and records[2]["observations"] == 4  # steps 1, 3, 5, 7
        assert records[2]["cspace_length"] > 0
    finally:
        env.close()


# ----------------------------------------------------------------------------- ACT
def test_temporal_ensemble_weights_the_oldest_prediction_most():
    """ACT's temporal ensembling on hand-made chunks: frame f's action is the mean of every
    kept chunk's prediction for f, weighted exp(-m i) with i = 0 for the oldest chunk; chunks
    that ended are dropped; clear() starts again at frame 0 with none."""
    from fetchbench_ms.policies.agent import TemporalEnsemble

    ensemble = TemporalEnsemble(m=0.5)
    w = np.exp(-0.5 * np.arange(3))
    assert np.allclose(ensemble.weights(3), w / w.sum()) and ensemble.weights(3)[0] > ensemble.weights(3)[1]
    chunks = [np.full((3, 2), value, np.float32) + np.arange(3)[:, None] for value in (0.0, 10.0, 20.0, 30.0)]
    # chunk k starts at frame k; its prediction for frame f is 10 k + (f - k)
    assert np.allclose(ensemble.push(chunks[0]), [0.0, 0.0])
    assert np.allclose(ensemble.push(chunks[1]), (w[0] * 1 + w[1] * 10) / w[:2].sum())
    assert np.allclose(ensemble.push(chunks[2]), (w[0] * 2 + w[1] * 11 + w[2] * 20) / w.sum())
    # frame 3: chunk 0 (frames 0-2) has ended; chunks 1, 2, 3 predict 12, 21, 30
    assert np.allclose(ensemble.push(chunks[3]), (w[0] * 12 + w[1] * 21 + w[2] * 30) / w.sum())
    assert [start for start, _ in ensemble.chunks] == [1, 2, 3] and ensemble.frame == 4
    ensemble.clear()
    assert ensemble.frame == 0 and not ensemble.chunks
    assert np.allclose(ensemble.push(chunks[3]), [30.0, 30.0])
    assert np.allclose(TemporalEnsemble(m=0.0).weights(4), 0.25)  # m = 0: the plain mean


def test_act_policy_ensembles_its_chunks_and_clears_them_at_a_phase_change(monkeypatch):
    """An ACT policy in deployment: the network at every observed step (stride 2: every 2nd
    step), the arm action the ensemble's for that frame, held over the stride; the chunks of
    the approach are forgotten when retrieval starts. A stride other than the data's is
    warned of, as for the MLP."""
    calls = _scripted_network(monkeypatch, {1: 0.9}, chunk=4)
    config = ReGraspConfig(close_steps=2, min_approach_steps=1, settle_steps=1, min_retrieve_steps=50)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        policy = ImitationPolicy(_tiny_model("act", ensemble_m=0.1), meta={"frame_stride": 2}, regrasp=config,
                                 stride=2)
    policy.reset(episode_seed=0)
    # approach x3 (the 2nd call terminates), close x2, retrieve x5
    asked, actions = _split_steps(policy, [0.04] * 10, np.random.default_rng(0))
    T, F = True, False
    assert asked == [T, F, T, F, F, T, F, T, F, T] and len(calls) == 5
    assert [to for _, _, to in policy.machine.log] == [CLOSE, RETRIEVE]
    w = np.exp(-0.1 * np.arange(3))
    # call k's chunk predicts 0.01 (k + 1) + 0.001 j for its j-th frame
    approach_1 = (w[0] * 0.011 + w[1] * 0.02) / w[:2].sum()  # calls 0 and 1 for frame 1
    retrieve_1 = (w[0] * 0.031 + w[1] * 0.04) / w[:2].sum()  # calls 2 and 3 only: the approach's are gone
    retrieve_2 = (w[0] * 0.032 + w[1] * 0.041 + w[2] * 0.05) / w.sum()
    arm = [0.01, 0.01, approach_1, 0.0, 0.0, 0.03, 0.03, retrieve_1, retrieve_1, retrieve_2]
    assert np.allclose(actions[:, :7], np.array(arm)[:, None], atol=1e-6), actions[:, 0]
    with pytest.warns(UserWarning, match="frame-stride 2"):
        ImitationPolicy(_tiny_model("act"), meta={"frame_stride": 2}, stride=1)


def test_act_loss_ignores_actions_past_the_segment_end(sample_data):
    """ACT's L1 looks at the chunk's steps inside the frame's stage segment only (ACT's
    is_pad): the trainers' chunk mask says where the segment ends, and any targets past it
    leave the loss (the CVAE encoder does not attend to them either) unchanged."""
    common = _import(ROOT / "baselines/imitation/common.py", "common")
    frames = common.Frames(load_training_files(sample_data, sizes=SIZES), "cpu", common.TrainArgs(device="cpu"))
    index = frames.train_index
    chunk, valid = frames.action_chunk(index, 8, with_mask=True)
    assert torch.equal(chunk, frames.action_chunk(index, 8))  # what the diffusion trainer gets
    ends = frames.seg_end[index]
    assert torch.equal(valid, index[:, None] + torch.arange(8) < ends[:, None])
    assert valid[:, 0].all() and not valid.all()  # some chunks run past their segment's end
    model = _tiny_model("act", chunk=8).eval()
    obs = frames.observation(index)
    noisy = torch.where(valid[..., None], chunk, torch.rand(chunk.shape) * 2 - 1)

    def loss(actions):
        with torch.no_grad():
            return model.loss(obs, actions, valid, frames.terminal[index], generator=torch.Generator().manual_seed(0))

    a, b = loss(chunk), loss(noisy)
    assert torch.equal(a["l1"], b["l1"]) and torch.equal(a["loss"], b["loss"])
    shifted = chunk + 0.1 * valid[..., None]  # a change inside the segment does count
    assert not torch.equal(loss(shifted)["l1"], a["l1"])


def test_act_default_checkpoint_fits_in_8_mb(tmp_path):
    """The default ACT (the trainer's defaults) exports an fp16 checkpoint of at most 8 MB, as
    the shipped ones are, and it loads as an ensembling ImitationPolicy."""
    from fetchbench_ms.policies.networks import ACTConfig, ACTPolicy

    model = ACTPolicy(ACTConfig())
    size = agent_mod.save_checkpoint(tmp_path / "act.pt", model, {})
    print(f"default ACT: {sum(p.numel() for p in model.parameters()) / 1e6:.2f} M parameters, {size / 1e6:.2f} MB fp16")
    assert size <= 8e6
    policy = ImitationPolicy.load(tmp_path / "act.pt")
    assert policy.ensemble is not None and policy.ensemble.m == 0.01 and policy.model.cfg.chunk == 16


def test_e2e_act_without_a_checkpoint_says_how_to_train_one(tmp_path, monkeypatch, capsys):
    """Without an ACT checkpoint (the default path made to point at a missing file), ``fetchbench
    eval --method e2e-act`` stops before any task with one line naming the missing file and the
    trainer's command, no traceback."""
    from fetchbench_ms.cli import main
    from fetchbench_ms.policies import deploy

    missing = tmp_path / "imit_act.pt"
    monkeypatch.setattr(deploy, "default_checkpoint", lambda kind: tmp_path / f"imit_{kind}.pt")
    out = tmp_path / "out"
    assert main(["eval", "--method", "e2e-act", "--suite", "val", "--tasks", "0:1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert str(missing) in err and "python baselines/imitation/train_act.py --data" in err and "--export" in err
    assert not (out / "results.jsonl").exists()


# ----------------------------------------------------------------------------- shipped checkpoints
@pytest.fixture(scope="module")
def sample_frames_full_size(tmp_path_factory) -> Path:
    """The first 40 steps of the sample's first 2 demos at the policies' point counts."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    out = tmp_path_factory.mktemp("imit-full")
    assert convert.main(["--traj-path", str(SAMPLE), "--out", str(out), "--count", "2", "--chunk", "2",
                         "--first-steps", "40"]) == 0
    return out


@pytest.fixture(scope="module")
def sample_frames_full_size_k3(tmp_path_factory) -> Path:
    """The same steps at frame stride 3: what a checkpoint trained at that stride reads (its
    history is of frames 3 steps apart, its actions the mean over each window)."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    out = tmp_path_factory.mktemp("imit-full-k3")
    assert convert.main(["--traj-path", str(SAMPLE), "--out", str(out), "--count", "2", "--chunk", "2",
                         "--first-steps", "40", "--frame-stride", "3"]) == 0
    return out


@pytest.fixture(scope="module")
def sample_frames_composed_k3(tmp_path_factory) -> Path:
    """The same steps at frame stride 3 in composed_pointcloud at the demos' own states, as the
    imitation rounds make their frames (--labels expert-states)."""
    convert = _import(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    out = tmp_path_factory.mktemp("imit-composed-k3")
    assert convert.main(["--traj-path", str(SAMPLE), "--out", str(out), "--count", "2", "--chunk", "2",
                         "--first-steps", "40", "--frame-stride", "3", "--obs-mode", "composed_pointcloud",
                         "--labels", "expert-states"]) == 0
    return out


@pytest.fixture(scope="module")
def sample_frames_by_stride(sample_frames_full_size, sample_frames_full_size_k3, sample_frames_composed_k3) -> dict:
    """The sample's frames by (obs mode, frame stride), as the shipped checkpoints were trained on."""
    return {("compact_pointcloud", 1): sample_frames_full_size, ("compact_pointcloud", 3): sample_frames_full_size_k3,
            ("composed_pointcloud", 3): sample_frames_composed_k3}


def _shipped(kind: str, frames_by_stride: dict):
    """A shipped checkpoint, its JSON, and the sample's frames at its frame stride as the
    trainers see them."""
    common = _import(ROOT / "baselines/imitation/common.py", "common")
    from fetchbench_ms.policies.deploy import default_checkpoint
    from fetchbench_ms.utils.packed import content_sha256, packed_or_plain

    path = packed_or_plain(default_checkpoint(kind))  # shipped packed: imit_<kind>.pt.planes.xz
    model, _ = load_model(path)
    record = json.loads(default_checkpoint(kind).with_suffix(".json").read_text())
    frames_dir = frames_by_stride[(record.get("obs_mode") or "compact_pointcloud", int(record.get("frame_stride", 1)))]
    assert path.stat().st_size <= 8e6 and record["checkpoint_sha256"] == content_sha256(path)
    assert record["retrain_command"] and len(record["data_sha256"]) == 64 and record["validation"]["loss"]
    assert record["data_manifest"]["totals"]["demos"] >= 250
    model = model.float().eval()
    raw = load_training_files(frames_dir, sizes=model.cfg.encoder.sizes)
    frames = common.Frames(raw, "cpu", common.TrainArgs(device="cpu"))
    index = torch.cat([frames.train_index, frames.val_index]).sort().values
    return model, frames, index, frames.observation(index, history=getattr(model, "history", 1))


@pytest.mark.parametrize("kind", ["mlp", "transformer", "act"])
def test_shipped_checkpoint_imitates_the_expert(kind, sample_frames_by_stride):
    """The shipped checkpoints (assets/checkpoints/imit_<kind>.pt.planes.xz) load, carry their training
    record (command, data hash, validation) and imitate: on expert frames of the demo sample,
    in the checkpoint's obs mode and frame stride, their actions' squared error to the expert's
    is at most 60 % of holding still's (a zero action; the shipped ones: MLP 56 %, ACT 35 %,
    Transformer 57 %). (The sample's task, train/0001, is among their training demos:
    this checks that the shipped bytes are the trained policy, not how it generalises; that is
    the val and test runs'.)"""
    model, frames, index, obs = _shipped(kind, sample_frames_by_stride)
    with torch.no_grad():
        actions, _ = model.act(obs)
    expert = frames.action[index]
    policy_mse = float(((actions[:, 0] - expert) ** 2).mean())
    still_mse = float((expert ** 2).mean())
    print(f"{kind}: policy MSE {policy_mse:.4f}, zero-action MSE {still_mse:.4f} on {len(index)} frames")
    assert policy_mse < 0.6 * still_mse


def test_shipped_diffusion_checkpoint_reads_its_observation(sample_frames_by_stride):
    """The shipped diffusion policy has learned the expert's action chunks and uses the
    observation: its noise-prediction error on the sample's expert chunks is far below an
    untrained denoiser's (~1) and lower with each frame's own observation than with another
    frame's. Whether its sampled first actions are closer to the expert's than a zero action
    is not claimed (docs/imitation.md, "The shipped checkpoints")."""
    model, frames, index, obs = _shipped("diffusion", sample_frames_by_stride)
    chunk = frames.action_chunk(index, model.cfg.pred_horizon)
    shuffled = {k: v[torch.randperm(len(index), generator=torch.Generator().manual_seed(1))] for k, v in obs.items()}

    def noise_mse(o) -> float:
        with torch.no_grad():
            return sum(float(model.loss(o, chunk, frames.terminal[index],
                                        generator=torch.Generator().manual_seed(s))["noise_mse"]) for s in range(5)) / 5

    own, other = noise_mse(obs), noise_mse(shuffled)
    print(f"diffusion: noise MSE {own:.4f} with its observations, {other:.4f} with shuffled ones")
    assert own < 0.2 and own < 0.95 * other
    actions, _ = model.act(obs, generator=torch.Generator().manual_seed(0))
    assert actions.shape == (len(index), model.cfg.act_horizon, 7) and actions.abs().max() <= 1.0


def test_val_runs_join_the_shipped_checkpoints_by_their_bytes(tmp_path, monkeypatch):
    """``ship_imitation.py --val-runs`` adds a val run (with its policy stride) to the shipped
    checkpoint's JSON only when its records name those exact bytes, and never takes test tasks."""
    import shutil

    ship = _import(ROOT / "scripts/maint/ship_imitation.py", "ship_imitation")
    for kind in ship.KINDS:
        if kind == "act":  # left out here: the case of a kind without a shipped checkpoint, below
            continue
        for suffix in (".pt.planes.xz", ".json"):
            shutil.copyfile(ROOT / f"assets/checkpoints/imit_{kind}{suffix}", tmp_path / f"imit_{kind}{suffix}")
    monkeypatch.setattr(ship, "default_checkpoint", lambda kind: tmp_path / f"imit_{kind}.pt")
    sha = ship.content_sha256(tmp_path / "imit_mlp.pt.planes.xz")  # of the .pt bytes it packs

    def run(name: str, task_prefix: str, checkpoint_sha: str, method: str = "e2e-mlp") -> Path:
        folder = tmp_path / name
        folder.mkdir()
        records = [{"task_id": f"{task_prefix}/000{i}", "method": method, "success": i == 0, "failure": None,
                    "category": "on_table", "scene_type": "Desk", "checkpoint": "imit_mlp.pt",
                    "checkpoint_sha256": checkpoint_sha, "policy_stride": 3} for i in range(2)]
        (folder / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
        return folder

    assert ship.main(["--val-runs", str(run("e2e-mlp-val", "val", sha))]) == 0
    entries = json.loads((tmp_path / "imit_mlp.json").read_text())["validation_success"]
    added = [e for e in entries if e["run"] == "e2e-mlp-val"]
    assert len(added) == 1 and added[0]["successes"] == 1 and added[0]["tasks"] == 2 and added[0]["policy_stride"] == 3
    assert any(e["method"] == "cgn-imit-mlp" for e in entries)  # the earlier val runs stay
    with pytest.raises(SystemExit, match="not the shipped"):
        ship.main(["--val-runs", str(run("other-bytes", "val", "0" * 64))])
    with pytest.raises(SystemExit, match="shipping's val figures refuses the test suite") as refused:
        ship.main(["--val-runs", str(run("on-test", "test", sha))])
    assert refused.value.code == 2
    with pytest.raises(SystemExit, match="kind 'act', and no imit_act.pt is shipped here"):
        ship.main(["--val-runs", str(run("e2e-act-val", "val", sha, method="e2e-act"))])


def _thread_settings(_) -> tuple[str | None, int]:
    import torch

    return os.environ.get("OMP_NUM_THREADS"), torch.get_num_threads()


def test_render_workers_are_spawned_with_one_thread_each(monkeypatch):
    """The render pass's spawned workers get one-thread OpenMP / BLAS pools (16 workers of 69
    threads each starved the 16-core node: a 64-demo chunk went from >5 minutes to 47 s with
    one), the converter's own environment is left as it was, and a caller's setting is kept."""
    import multiprocessing as mp

    from fetchbench_ms.utils.workers import WORKER_THREAD_VARS, one_thread_per_spawned_worker

    for var in WORKER_THREAD_VARS:
        monkeypatch.delenv(var, raising=False)
    with one_thread_per_spawned_worker():
        pool = mp.get_context("spawn").Pool(1)
    with pool:
        assert pool.map(_thread_settings, [0]) == [("1", 1)]
    assert not any(var in os.environ for var in WORKER_THREAD_VARS)
    monkeypatch.setenv("OMP_NUM_THREADS", "2")
    with one_thread_per_spawned_worker():
        assert os.environ["OMP_NUM_THREADS"] == "2" and os.environ["MKL_NUM_THREADS"] == "1"
    assert os.environ["OMP_NUM_THREADS"] == "2" and "MKL_NUM_THREADS" not in os.environ


@pytest.mark.parametrize("kind", sorted(TRAINER_KW))
def test_trainer_flags_show_their_own_help(kind, capsys, monkeypatch):
    """Each trainer flag's --help text is its own: --log-every and --ckpt-every do not repeat
    --init-from's (tyro reads a comment above a field as the help of the fields after it)."""
    import tyro

    module = _import(ROOT / f"baselines/imitation/train_{kind}.py", f"train_{kind}")
    monkeypatch.setenv("COLUMNS", "200")
    with pytest.raises(SystemExit):
        tyro.cli(module.Args, args=["--help"])
    helps, flag = {}, None
    for line in capsys.readouterr().out.splitlines():
        text = line.strip().strip("│").strip()
        if text.startswith("--"):
            flag, _, text = text.partition(" ")  # the text: metavar, then help
            helps[flag.rstrip(",")] = text
        elif flag is not None and text and not text.startswith(("╭", "╰")):
            helps[flag.rstrip(",")] += " " + text
        else:
            flag = None
    helps = {k: " ".join(v.split()) for k, v in helps.items()}
    assert "from an exported checkpoint" in helps["--init-from"]
    assert "steps between progress lines" in helps["--log-every"]
    assert "steps between the run's full checkpoints" in helps["--ckpt-every"]
    texts = [h.split(" (default")[0] for h in helps.values() if len(h) > 40]
    assert len(texts) == len(set(texts)), [t for t in texts if texts.count(t) > 1]
