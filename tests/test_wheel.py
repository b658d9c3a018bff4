"""The package as a user installs it: a wheel built from the checkout and installed into a
fresh virtual environment finds its shipped assets (suites, grasps, checkpoints) inside the
wheel, not in a checkout, and an env resets on a shipped suite's task from any folder.

The new environment borrows this interpreter's installed dependencies through a .pth line
(no download, no second copy of torch and SAPIEN); the editable install's own path hook is
not read from there, so the only fetchbench_ms it sees is the wheel's."""
from __future__ import annotations

import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

CHECK = r"""
import sys
from pathlib import Path
import fetchbench_ms, gymnasium as gym
from fetchbench_ms.utils.paths import assets_root
from fetchbench_ms.tasks.suite import shipped_suite_file, shipped_suites
from fetchbench_ms.grasp_labels.store import load_grasps
from fetchbench_ms.policies.deploy import default_checkpoint
package = Path(fetchbench_ms.__file__).resolve().parent
site = Path(sys.argv[1]).resolve()
assert package.parent == site, (package, site)
assert assets_root() == package / "_assets", assets_root()
assert {"test", "val", "train", "smoke"} <= set(shipped_suites()), shipped_suites()
assert shipped_suite_file("test").resolve().is_relative_to(site), shipped_suite_file("test")
assert load_grasps("blob/233").success.any()
checkpoint = default_checkpoint("mlp")
assert Path(checkpoint).resolve().is_relative_to(site), checkpoint
env = gym.make("FetchBench-v0", task_suite="val")
obs, info = env.reset(seed=0)
print("wheel ok", obs.shape[-1])
"""


@pytest.fixture(scope="module")
def wheel_env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation", "-q",
                    "-w", str(tmp / "dist")], check=True, capture_output=True, timeout=600)
    wheel = next((tmp / "dist").glob("fetchbench_ms-*.whl"))
    env_dir = tmp / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    python = env_dir / "bin" / "python"
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               check=True, capture_output=True, text=True).stdout.strip())
    (site / "zz_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps", "-q", str(wheel)],
                   check=True, capture_output=True, timeout=600)
    return python, site, tmp


def test_an_installed_wheel_finds_its_assets_and_resets_an_env(wheel_env):
    python, site, tmp = wheel_env
    run = tmp / "elsewhere"
    run.mkdir()
    out = subprocess.run([str(python), "-c", CHECK, str(site)], cwd=run, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "wheel ok" in out.stdout
