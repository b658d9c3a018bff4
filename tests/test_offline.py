"""The offline install for an air-gapped node (scripts/offline/, docs/offline-install.md): a
bundle packed with a size split (a wheel cut into pieces over two parts) installs with pip
--no-index once every part is in, says which parts are missing before, and refuses a damaged
wheel. No network: the wheel is made here."""
import base64
import hashlib
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

from script_modules import load_script

ROOT = Path(__file__).resolve().parents[1]


def _load(path: Path, name: str):
    return load_script(path, name)


def _wheel(folder: Path) -> Path:
    """A pure wheel of a module `fb_offline_probe` with a large incompressible payload."""
    path = folder / "fb_offline_probe-1.0-py3-none-any.whl"
    payload = hashlib.sha256(b"seed").digest() * 8192             # 256 KiB
    files = {"fb_offline_probe/__init__.py": b"VALUE = 42\n",
             "fb_offline_probe/blob.bin": payload,
             "fb_offline_probe-1.0.dist-info/METADATA": b"Metadata-Version: 2.1\nName: fb-offline-probe\nVersion: 1.0\n",
             "fb_offline_probe-1.0.dist-info/WHEEL": b"Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n"}
    record = "".join(f"{n},sha256={base64.urlsafe_b64encode(hashlib.sha256(d).digest()).rstrip(b'=').decode()},{len(d)}\n"
                     for n, d in files.items()) + "fb_offline_probe-1.0.dist-info/RECORD,,\n"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as z:
        for n, d in files.items():
            z.writestr(n, d)
        z.writestr("fb_offline_probe-1.0.dist-info/RECORD", record)
    return path


def _install(bundle: Path, stage: Path, target: Path):
    return subprocess.run([sys.executable, str(ROOT / "scripts/offline/install.py"), "--bundle", str(bundle),
                           "--stage", str(stage), "--target", str(target)], capture_output=True, text=True)


def test_a_split_bundle_installs_once_every_part_is_in(tmp_path):
    pack = _load(ROOT / "scripts/offline/bundle.py", "offline_bundle").pack
    cache, bundle = tmp_path / "cache", tmp_path / "whl"
    cache.mkdir()
    bundle.mkdir()
    wheel = _wheel(cache)
    # pieces of 100 KiB, parts of 200 KiB: the ~260 KiB wheel is cut into 3 pieces over 2 parts
    parts = pack([wheel], bundle, 100 * 1024, 200 * 1024)
    assert len(parts) == 2
    held = tmp_path / "held"
    shutil.move(str(bundle / "2"), held)                       # part 2 has not arrived yet
    stage, target = tmp_path / "stage", tmp_path / "site"
    first = _install(bundle, stage, target)
    assert first.returncode == 3 and "still to come: 2" in first.stdout, first.stdout + first.stderr
    shutil.move(str(held), bundle / "2")
    done = _install(bundle, stage, target)
    assert done.returncode == 0, done.stdout + done.stderr
    probe = subprocess.run([sys.executable, "-c", "import fb_offline_probe; print(fb_offline_probe.VALUE)"],
                           env={"PYTHONPATH": str(target)}, capture_output=True, text=True)
    assert probe.stdout.strip() == "42"
    again = _install(bundle, stage, target)                    # nothing twice
    assert again.returncode == 0 and "already installed" in again.stdout


def test_without_a_split_the_bundle_is_one_part_and_a_damaged_wheel_is_refused(tmp_path):
    pack = _load(ROOT / "scripts/offline/bundle.py", "offline_bundle").pack
    cache, bundle = tmp_path / "cache", tmp_path / "whl"
    cache.mkdir()
    bundle.mkdir()
    wheel = _wheel(cache)
    assert len(pack([wheel], bundle, 1 << 62, 1 << 62)) == 1
    (bundle / "1" / wheel.name).unlink()
    (bundle / "1" / wheel.name).write_bytes(b"not a wheel")
    bad = _install(bundle, tmp_path / "stage", tmp_path / "site")
    assert bad.returncode != 0 and "damaged" in bad.stderr
    assert not (tmp_path / "site").exists()


def test_no_bundle_is_an_error_naming_the_tool(tmp_path):
    out = _install(tmp_path / "none", tmp_path / "stage", tmp_path / "site")
    assert out.returncode == 2 and "scripts/offline/bundle.py" in out.stdout
