"""scripts/imitation/build_imitation_data.py: train tasks -> demos -> training files in one resumable
command, the same bytes per seed."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from script_modules import import_script

ROOT = Path(__file__).resolve().parents[1]


def _build():
    return import_script(ROOT / "scripts/imitation/build_imitation_data.py")


def test_bad_task_ranges_are_refused(tmp_path):
    build = _build()
    for tasks, message in (("5", "START:END"), ("3:3", "START < END"), ("0:10000000", "valid END")):
        with pytest.raises(SystemExit, match=message):
            build.main(["--root", str(tmp_path), "--tasks", tasks])


def test_demos_limits_the_conversion_to_the_first_demos(tmp_path):
    """--demos N converts the merged file's first N demos (the converter's --count); a
    non-positive N is refused before anything runs."""
    import argparse

    build = _build()
    args = argparse.Namespace(chunk=256, procs=64, device="cuda", obs_mode="compact_pointcloud", frame_stride=3,
                              render_gpus=4, demos=256, first_steps=None, labels="expert-states")
    out = build.converter_args(args, tmp_path / "train-0-600.h5", tmp_path / "data")
    assert out[out.index("--count") + 1] == "256" and out[out.index("--chunk") + 1] == "256"
    assert out[out.index("--labels") + 1] == "expert-states"
    assert "--count" not in build.converter_args(argparse.Namespace(**{**vars(args), "demos": None}),
                                                 tmp_path / "m.h5", tmp_path / "data")
    with pytest.raises(SystemExit, match="--demos must be >= 1"):
        build.main(["--root", str(tmp_path), "--tasks", "0:2", "--demos", "0"])
    assert not any(tmp_path.iterdir())


def test_one_task_to_training_files_resumes_with_the_same_bytes(tmp_path, capsys):
    """Train task 1 (one trajectory, its first 6 steps converted in policy_pointcloud) in two
    roots: the same parts and training files; the same command again in a finished root keeps
    every file as it is."""
    build = _build()
    args = ["--tasks", "1:2", "--procs", "1", "--per-task", "1", "--chunk", "1", "--first-steps", "6"]
    assert build.main(["--root", str(tmp_path / "a"), *args]) == 0
    out = capsys.readouterr().out
    assert "frames a second" in out and "trajectories a core-hour" in out
    manifest = json.loads((tmp_path / "a/data/manifest.json").read_text())
    assert manifest["complete"] and manifest["settings"]["obs_mode"] == "policy_pointcloud"
    assert manifest["totals"]["frames"] > 0
    files = sorted((tmp_path / "a").rglob("*.h5"))
    before = {p: p.read_bytes() for p in files if ".parts" in str(p) or p.suffix == ".h5" and "data" in p.parts}
    assert build.main(["--root", str(tmp_path / "a"), *args]) == 0  # resumes: nothing left to do
    assert "nothing left to do" in capsys.readouterr().out
    assert all(p.read_bytes() == b for p, b in before.items())
    assert json.loads((tmp_path / "a/data/manifest.json").read_text()) == manifest
    assert build.main(["--root", str(tmp_path / "b"), *args]) == 0
    other = json.loads((tmp_path / "b/data/manifest.json").read_text())
    assert [c["sha256"] for c in other["chunks"]] == [c["sha256"] for c in manifest["chunks"]]
