"""Training on policy_pointcloud frames and deploying what was trained: the four trainers from
one launcher (scripts/imitation/train_imitation_gpus.py, on the CPU here), the obs mode recorded in the
checkpoint and read back by the eval methods."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from fetchbench_ms.envs.pointcloud import POLICY_OBS_MODE

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
TINY = "--batch-size 8 --point-dims 16 32 --warmup 1 --eval-every 0 --val-every 10000 --log-every 1 --ckpt-every 10000"
KIND_ARGS = {"mlp": "--hidden 32", "transformer": "--d-model 32 --layers 1 --heads 2",
             "diffusion": "--unet-dims 16 32 --pred-horizon 8 --act-horizon 4 --train-diffusion-steps 20 --sample-steps 4",
             "act": "--chunk 4 --latent-dim 8 --d-model 32 --layers 1 --heads 2"}


def _script(name: str):
    return import_script(ROOT / "scripts" / "imitation" / f"{name}.py")


@pytest.fixture(scope="module")
def policy_data(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("policy-data")
    assert _script("convert_demos_for_imitation").main(
        ["--traj-path", str(SAMPLE), "--out", str(out), "--count", "2", "--chunk", "2", "--first-steps", "8",
         "--obs-mode", POLICY_OBS_MODE]) == 0
    return out


def test_other_settings_than_the_folders_are_refused(policy_data):
    with pytest.raises(SystemExit, match="obs_mode"):
        _script("convert_demos_for_imitation").main(
            ["--traj-path", str(SAMPLE), "--out", str(policy_data), "--count", "2", "--chunk", "2",
             "--first-steps", "8"])


def test_training_files_of_two_obs_modes_are_refused(policy_data, tmp_path):
    import shutil

    from fetchbench_ms.policies.data import load_training_files, write_training_file

    data = load_training_files(policy_data)
    shutil.copy(next(policy_data.glob("*.imit.h5")), tmp_path / "a.imit.h5")
    write_training_file(tmp_path / "b.imit.h5", {**data, "obs_mode": "compact_pointcloud"})
    with pytest.raises(ValueError, match="one obs mode"):
        load_training_files(tmp_path)


def test_four_trainers_from_one_launcher_and_the_policy_deploys(policy_data, tmp_path):
    import gymnasium as gym
    import numpy as np

    import fetchbench_ms  # noqa: F401
    from fetchbench_ms.method_spec import RunSpec, method_spec
    from fetchbench_ms.policies import deploy
    from fetchbench_ms.policies.agent import ImitationPolicy, checkpoint_obs_mode

    launcher = _script("train_imitation_gpus")
    with pytest.raises(SystemExit):
        launcher.main(["--data", str(policy_data), "--runs", str(tmp_path), "--gpus", "0,1"])  # 4 kinds, 2 GPUs
    runs = tmp_path / "runs"
    kind_args = [f"{k}={v} --export --export-path {runs / k / 'export.pt'}" for k, v in KIND_ARGS.items()]
    argv = ["--data", str(policy_data), "--runs", str(runs), "--gpus", "cpu", "--steps", "3", "--trainer-args", TINY]
    assert launcher.main(argv + [a for item in kind_args for a in ("--kind-args", item)]) == 0
    for kind in KIND_ARGS:
        export = runs / kind / "export.pt"
        assert checkpoint_obs_mode(export) == POLICY_OBS_MODE, kind
        assert json.loads(export.with_suffix(".json").read_text())["step"] == 3
    export = runs / "mlp" / "export.pt"
    assert deploy.policy_obs_mode(method_spec("e2e-mlp"), str(export)) == POLICY_OBS_MODE
    with pytest.raises(ValueError, match="end-to-end"):
        deploy.policy_obs_mode(method_spec("cgn-imit-mlp"), str(export))
    # The shipped checkpoints keep theirs.
    assert deploy.policy_obs_mode(method_spec("e2e-act")) == "compact_pointcloud"
    env = gym.make("FetchBench-v0", obs_mode=POLICY_OBS_MODE, control_mode="pd_joint_pos", task_suite="val")
    try:
        env.reset(seed=0)
        record = deploy.run_e2e(env, 0, RunSpec(method_spec("e2e-mlp"), policy_checkpoint=str(export)), max_steps=2)
        assert record["policy_steps"] == 2 and record["observations"] >= 1
        # A compact cloud is not what this policy was trained on.
        policy = ImitationPolicy.load(export)
        policy.reset(episode_seed=0)
        policy.begin_step(np.zeros(9))
        raw = {"pointcloud": {"xyz": np.zeros((1, 22528, 3), np.float16), "seg": np.zeros((1, 22528), np.uint8)},
               "agent": {"qpos": np.zeros((1, 9), np.float32)}}
        with pytest.raises(ValueError, match=POLICY_OBS_MODE):
            policy.act(raw)
    finally:
        env.close()
