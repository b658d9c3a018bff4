"""scripts/build_imitation_data.py: train tasks -> demos -> training files in one resumable
command, the same bytes per seed."""
from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _build():
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        return importlib.import_module("build_imitation_data")
    finally:
        sys.path.remove(str(ROOT / "scripts"))


def test_bad_task_ranges_are_refused(tmp_path):
    build = _build()
    for tasks, message in (("5", "START:END"), ("3:3", "START < END"), ("0:10000000", "valid END")):
        with pytest.raises(SystemExit, match=message):
            build.main(["--root", str(tmp_path), "--tasks", tasks])


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
