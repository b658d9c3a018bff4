#!/usr/bin/env python3
"""Installs the offline bundle (scripts/offline/bundle.py) on an air-gapped node with `pip
--no-index`; standard library only, since nothing else may be there yet (docs/offline-install.md).

The bundle is one part (.whl/1/) or, when made with a size split, several (.whl/1/, .whl/2/,
...) that may arrive one at a time. This script copies the parts present into a staging
folder outside the repository (so parts brought one by one add up), joins split wheels once
all their parts are in and checks every wheel's sha256 against the manifest. While parts are
missing it names them and exits 3. Once every wheel is in,
it installs them all with one `pip install --no-index --no-deps --no-compile --upgrade --target
/tmp/site` (one call: with --target, a second call would replace shared folders such as bin/),
then prints the PYTHONPATH to export. Run again with the same bundle it does nothing.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def say(message: str) -> None:
    print(f"[offline-install] {message}", flush=True)


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bundle", default=".whl", help="folder holding the bundle's parts 1/, 2/, ... (default .whl)")
    ap.add_argument("--stage", default="/tmp/fetchbench-wheels", help="staging folder (default /tmp/fetchbench-wheels)")
    ap.add_argument("--target", default="/tmp/site", help="where the packages go (default /tmp/site)")
    args = ap.parse_args(argv)

    bundle, stage, target = ROOT / args.bundle, Path(args.stage), Path(args.target)
    arrived = sorted((d for d in bundle.glob("*") if (d / "manifest.json").is_file()),
                     key=lambda d: d.name)
    if not arrived:
        say(f"no bundle part in {bundle} (expected {args.bundle}/1/, made by scripts/offline/bundle.py)")
        return 2
    manifest = json.loads((arrived[-1] / "manifest.json").read_text())
    stage.mkdir(parents=True, exist_ok=True)
    staged = stage / "manifest.json"
    if staged.is_file() and json.loads(staged.read_text())["id"] != manifest["id"]:
        say(f"a different bundle was staged before: clearing {stage}")
        shutil.rmtree(stage)
        stage.mkdir(parents=True)
    staged.write_text(json.dumps(manifest))

    for d in arrived:
        if json.loads((d / "manifest.json").read_text())["id"] != manifest["id"]:
            say(f"skipping {d}: it belongs to another bundle (make the bundle again and bring all its parts)")
            continue
        for f in d.iterdir():
            if f.name != "manifest.json" and not (stage / f.name).exists():
                shutil.copyfile(f, stage / f.name)
        say(f"part {d.name} staged")

    waiting = set()
    for name, w in manifest["wheels"].items():
        wheel = stage / name
        if not wheel.exists() and w["parts"]:
            parts = [stage / p["name"] for p in w["parts"]]
            if all(p.exists() for p in parts):
                with open(wheel, "wb") as out:
                    for p in parts:
                        out.write(p.read_bytes())
                for p in parts:
                    p.unlink()
            else:
                waiting |= {p["transfer"] for p in w["parts"] if not (stage / p["name"]).exists()}
                continue
        if not wheel.exists():
            waiting.add(w["transfer"])
        elif wheel.stat().st_size != w["size"] or sha256(wheel) != w["sha256"]:
            wheel.unlink()
            sys.exit(f"[offline-install] {name}: damaged (size or sha256 differ from the manifest); "
                     f"bring part(s) {w.get('transfer') or sorted({p['transfer'] for p in w['parts']})} again")
    if waiting:
        say(f"{len(manifest['wheels'])} wheels in {manifest['transfers']} part(s); still to come: "
            + " ".join(str(n) for n in sorted(waiting))
            + f" (bring them into {args.bundle}/<n> and run this again)")
        return 3

    stamp = target / ".fetchbench-bundle"
    if stamp.is_file() and stamp.read_text().strip() == manifest["id"]:
        say(f"bundle {manifest['id']} is already installed in {target}")
    else:
        wheels = [str(stage / name) for name in sorted(manifest["wheels"])]
        say(f"installing {len(wheels)} wheels into {target}")
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-index", "--no-deps",
                        "--no-compile", "--no-cache-dir", "--upgrade", "--target", str(target), *wheels],
                       check=True)
        stamp.write_text(manifest["id"] + "\n")
    say(f"done; now: export PYTHONPATH={target}:$PWD")
    return 0


if __name__ == "__main__":
    sys.exit(main())
