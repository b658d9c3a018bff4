"""``--labels expert-states``: imitation frames at the demos' own recorded states, no replay; each
frame's action is the ``pd_joint_delta_pos`` action that sets the expert's arm targets there."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from fetchbench_ms.envs.pointcloud import COMPOSED_OBS_MODE
from fetchbench_ms.policies.data import (ARM_DOF, EXPERT_STATE_LABELS, expert_state_actions, load_training_files,
                                         select_frames, state_qpos, write_training_file)

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
STEPS = 40  # the first demo's first steps: its arm starts to move, some deltas within 0.1 rad, some beyond


def _source(episode: int = 0):
    import h5py
    from mani_skill.trajectory.utils import index_dict

    meta = json.loads(SAMPLE.with_suffix(".json").read_text())
    entry = meta["episodes"][episode]
    with h5py.File(SAMPLE, "r") as f:
        traj = f[f"traj_{entry['episode_id']}"]
        states = index_dict(traj["env_states"], slice(None))
        return meta, entry, traj["actions"][:], states, state_qpos(traj["env_states"])


def test_the_label_sets_the_experts_arm_targets_at_its_state():
    """Stepped from a recorded state with its label, the delta controller's arm targets are the
    expert's own targets there (to float32) wherever the expert's target is within 0.1 rad of
    the joints; beyond, 0.1 rad towards it on each joint that far; the gripper's is copied."""
    import gymnasium as gym
    from mani_skill.trajectory.utils import index_dict

    import fetchbench_ms  # noqa: F401

    meta, entry, actions, states, qpos = _source()
    labels = expert_state_actions(actions[:STEPS], qpos)
    assert labels.shape == (STEPS, ARM_DOF + 1) and labels.dtype == np.float32
    assert np.abs(labels[:, :ARM_DOF]).max() <= 1 and np.array_equal(labels[:, ARM_DOF], actions[:STEPS, ARM_DOF])
    kwargs = {k: v for k, v in meta["env_info"]["env_kwargs"].items() if k not in ("obs_mode", "control_mode")}
    env = gym.make(meta["env_info"]["env_id"], **kwargs, obs_mode="state", control_mode="pd_joint_delta_pos")
    within = beyond = 0
    try:
        env.reset(**entry["reset_kwargs"])
        arm = env.unwrapped.agent.controller.controllers["arm"]
        for t in range(0, STEPS, 3):
            env.unwrapped.set_state_dict(index_dict(states, slice(t, t + 1)))
            env.step(torch.as_tensor(labels[t:t + 1]))
            target = arm._target_qpos[0].numpy()
            gap = actions[t, :ARM_DOF] - qpos[t, :ARM_DOF]
            reached = np.abs(gap) <= 0.1
            assert np.allclose(target[reached], actions[t, :ARM_DOF][reached], atol=1e-6), t
            assert np.allclose(target[~reached], (qpos[t, :ARM_DOF] + 0.1 * np.sign(gap))[~reached], atol=1e-6), t
            within += int(reached.all())
            beyond += int(not reached.all())
    finally:
        env.close()
    assert within and beyond  # both cases were seen


def test_converter_writes_the_obs_mode_at_the_recorded_states(tmp_path):
    """The converter's frames: the recorded states' joints and the obs mode's points there (a
    fresh env set to each state), the labels ``select_frames`` of ``expert_state_actions``; the
    file and the manifest say how the actions were labelled; a second run resumes (nothing to do)."""
    import gymnasium as gym
    import h5py
    from mani_skill.trajectory.utils import index_dict

    convert = import_script(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    out = tmp_path / "data"
    argv = ["--traj-path", str(SAMPLE), "--out", str(out), "--count", "2", "--chunk", "1", "--first-steps",
            "12", "--obs-mode", COMPOSED_OBS_MODE, "--frame-stride", "3", "--labels", "expert-states"]
    assert convert.main(argv) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] and manifest["settings"]["labels"] == EXPERT_STATE_LABELS
    with h5py.File(out / "chunk_00000.imit.h5", "r") as f:
        assert f.attrs["labels"] == EXPERT_STATE_LABELS and f.attrs["obs_mode"] == COMPOSED_OBS_MODE
    data = load_training_files(out)
    assert data["labels"] == EXPERT_STATE_LABELS and len(data["episodes"]) == 2
    meta, entry, actions, states, qpos = _source()
    with h5py.File(SAMPLE, "r") as f:
        traj = f[f"traj_{entry['episode_id']}"]
        expected = select_frames(traj["stage"][:12], traj["stage_end"][:12],
                                 expert_state_actions(actions[:12], qpos), 3)
    n = int(data["episode_length"][0])
    assert n == len(expected["frame"])
    assert np.array_equal(data["action"][:n], expected["action"])
    assert np.array_equal(data["qpos"][:n], qpos[expected["frame"]])
    kwargs = {k: v for k, v in meta["env_info"]["env_kwargs"].items() if k not in ("obs_mode", "render_backend")}
    env = gym.make(meta["env_info"]["env_id"], **kwargs, obs_mode=COMPOSED_OBS_MODE)
    try:
        env.reset(**entry["reset_kwargs"])
        for i, t in enumerate(expected["frame"]):
            env.unwrapped.set_state_dict(index_dict(states, slice(t, t + 1)))
            env.unwrapped._elapsed_steps[:] = t
            obs = env.unwrapped.get_obs()
            assert np.array_equal(obs["pointcloud"]["points"][0].numpy(), data["points"][i]), t
    finally:
        env.close()
    before = (out / "chunk_00000.imit.h5").stat().st_mtime_ns
    assert convert.main(argv) == 0
    assert (out / "chunk_00000.imit.h5").stat().st_mtime_ns == before


def test_expert_states_take_a_points_obs_mode(tmp_path, capsys):
    convert = import_script(ROOT / "scripts/imitation/convert_demos_for_imitation.py", "convert_demos_for_imitation")
    with pytest.raises(SystemExit, match="points obs modes"):
        convert.main(["--traj-path", str(SAMPLE), "--out", str(tmp_path / "x"), "--labels", "expert-states"])
    assert not (tmp_path / "x").exists()


def test_files_of_two_labellings_are_not_one_training_set(tmp_path):
    frame = {"points": np.zeros((1, 4, 3), np.float16), "point_label": np.zeros((1, 4), np.uint8),
             "qpos": np.zeros((1, 9), np.float32), "tcp": np.zeros((1, 9), np.float32),
             "action": np.zeros((1, 7), np.float32), "gripper": np.ones(1, np.float32),
             "stage": np.zeros(1, np.int8), "stage_end": np.zeros(1, bool),
             "episode_start": np.zeros(1, np.int64), "episode_length": np.ones(1, np.int64),
             "episodes": [{"task_id": "train/0001"}], "sizes": {"scene": 4, "target": 0, "robot": 0}}
    write_training_file(tmp_path / "a.imit.h5", frame)
    write_training_file(tmp_path / "b.imit.h5", {**frame, "labels": EXPERT_STATE_LABELS})
    assert load_training_files(tmp_path / "a.imit.h5")["labels"] == "replay"  # absent: the replay's
    with pytest.raises(ValueError, match="one conversion"):
        load_training_files(tmp_path)
