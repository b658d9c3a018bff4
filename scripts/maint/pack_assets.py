"""Pack the shipped assets into their compact lossless forms, in place (maintainer).

    python scripts/maint/pack_assets.py            # pack what is not packed yet; report what changed
    python scripts/maint/pack_assets.py --check    # exit 1 if anything is left to pack

What it packs (the readers accept the old forms too; ``fetchbench_ms.utils.packed``):

- ``assets/checkpoints/*.pt`` -> ``*.pt.planes.xz``: the file's even and odd bytes (the fp16
  weights' low and high bytes) apart, xz; unpacks to the same bytes (checked before the
  ``.pt`` is removed), so the sha256 that records and the checkpoints' JSON name holds.
- ``assets/grasps/shard_NN.npz`` -> ``shard_NN.arrays.xz`` (the same arrays, byte planes, xz;
  ``fetchbench_ms.grasp_labels.store``) and ``manifest.json`` -> ``manifest.json.xz`` (its JSON, xz),
  whose entries name the new files and their sha256; nothing else in it changes.
- ``assets/suites/<name>.json.gz`` -> ``<name>.suite.xz`` (``fetchbench_ms.tasks.suite_packed``):
  the same canonical JSON text, floats in columns; its header keeps the ``.json.gz`` file's
  sha256, the suite's identity in run records (``suite_file_sha256``).
- ``assets/objects/catalog.json.gz`` -> ``catalog.json.xz`` (the same JSON, xz), and the
  objects' ``manifest.json`` names it with its sha256 and size.
- ``results/**/results.jsonl.gz`` (packed evaluation runs) -> ``results.jsonl.xz``: the same
  JSON lines, as ``fetchbench results pack`` writes them.

Each packed file is checked to unpack to what it replaces before the old file goes. The
output is byte-reproducible (fixed xz settings, no timestamps), and a second run finds
nothing to do.
"""
from __future__ import annotations

import argparse
import gzip
import json
import sys
from pathlib import Path

import numpy as np

from fetchbench_ms.evaluation.results_table import packed_bytes
from fetchbench_ms.evaluation.store import LEGACY_PACKED_RESULTS_FILE, PACKED_RESULTS_FILE, ResultsStore
from fetchbench_ms.grasp_labels import store as grasp_store
from fetchbench_ms.objects import catalog
from fetchbench_ms.tasks import suite_packed
from fetchbench_ms.tasks.suite import load_suite, suite_file_sha256
from fetchbench_ms.utils.io import atomic_write_bytes, canonical_json, sha256_bytes
from fetchbench_ms.utils.packed import PLANES_SUFFIX, pack_planes, unpack_planes, unxz_bytes, xz_bytes

ROOT = Path(__file__).resolve().parents[2]
PARTS = ("checkpoints", "grasps", "suites", "catalog", "results")


def pack_checkpoints(assets: Path, write: bool) -> list[str]:
    """Every ``checkpoints/*.pt`` into ``*.pt.planes.xz``; returns what changed (or would)."""
    done = []
    for path in sorted((assets / "checkpoints").glob("*.pt")):
        target = path.with_name(path.name + PLANES_SUFFIX)
        if write:
            raw = path.read_bytes()
            packed = pack_planes(raw)
            if unpack_planes(packed, target) != raw:
                raise SystemExit(f"{path}: its packed form does not unpack to the same bytes; nothing written")
            atomic_write_bytes(target, packed)
            path.unlink()
            done.append(f"{path.relative_to(assets)}: {len(raw)} -> {target.name} {len(packed)} bytes")
        else:
            done.append(f"{path.relative_to(assets)}: not packed")
    return done


def _same_arrays(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return list(a) == list(b) and all(a[k].dtype == b[k].dtype and a[k].shape == b[k].shape
                                      and a[k].tobytes() == b[k].tobytes() for k in a)


def pack_grasps(assets: Path, write: bool) -> list[str]:
    """The grasp directory's ``.npz`` shards and ``manifest.json`` into their packed forms."""
    directory = assets / "grasps"
    legacy_manifest = directory / grasp_store.LEGACY_MANIFEST
    if not legacy_manifest.exists():
        return []
    if not write:
        return [f"{legacy_manifest.relative_to(assets)} and its shards: not packed"]
    manifest = json.loads(legacy_manifest.read_text())
    done, sources = [], []
    for entry in manifest["shards"].values():
        source = directory / entry["file"]
        if not source.name.endswith(grasp_store.LEGACY_SHARD_SUFFIX):
            continue
        arrays = grasp_store.read_shard_arrays(source)
        data = grasp_store.encode_shard_arrays(arrays)
        target = source.with_name(source.name[: -len(grasp_store.LEGACY_SHARD_SUFFIX)] + grasp_store.ARRAYS_SUFFIX)
        if not _same_arrays(grasp_store.decode_shard(data, target), arrays):
            raise SystemExit(f"{source}: its packed form does not decode to the same arrays; nothing written")
        atomic_write_bytes(target, data)
        entry.update(file=target.name, sha256=sha256_bytes(data))
        sources.append(source)
        done.append(f"{source.relative_to(assets)}: {source.stat().st_size} -> {target.name} {len(data)} bytes")
    text = json.dumps(manifest, indent=1, sort_keys=True) + "\n"
    target = directory / grasp_store.MANIFEST
    atomic_write_bytes(target, xz_bytes(text.encode()))
    done.append(f"{legacy_manifest.relative_to(assets)}: {legacy_manifest.stat().st_size} -> {target.name} "
                f"{target.stat().st_size} bytes")
    for path in [legacy_manifest, *sources]:  # only once the new manifest names the packed shards
        path.unlink()
    return done


def pack_suites(assets: Path, write: bool) -> list[str]:
    """Every ``suites/<name>.json.gz`` into ``<name>.suite.xz``."""
    done = []
    for path in sorted((assets / "suites").glob("*.json.gz")):
        target = path.with_name(path.name[: -len(".json.gz")] + suite_packed.SUFFIX)
        if not write:
            done.append(f"{path.relative_to(assets)}: not packed")
            continue
        raw = path.read_bytes()
        data = suite_packed.pack(gzip.decompress(raw), sha256_bytes(raw))  # checks its own round trip
        atomic_write_bytes(target, data)
        same = canonical_json(load_suite(target).to_body()) == canonical_json(load_suite(path).to_body())
        if suite_file_sha256(target) != sha256_bytes(raw) or not same:
            target.unlink()
            raise SystemExit(f"{path}: its packed form is another suite; nothing written")
        path.unlink()
        done.append(f"{path.relative_to(assets)}: {len(raw)} -> {target.name} {len(data)} bytes")
    return done


def pack_catalog(assets: Path, write: bool) -> list[str]:
    """The object index ``catalog.json.gz`` into ``catalog.json.xz``, renamed in the manifest."""
    directory = assets / "objects"
    source, target = directory / catalog.LEGACY_INDEX_NAME, directory / catalog.INDEX_NAME
    if not source.exists():
        return []
    if not write:
        return [f"{source.relative_to(assets)}: not packed"]
    raw = source.read_bytes()
    data = xz_bytes(gzip.decompress(raw))
    manifest_path = directory / catalog.MANIFEST_NAME
    manifest = json.loads(manifest_path.read_text())
    if manifest["files"].get(source.name, {}).get("sha256") != sha256_bytes(raw):
        raise SystemExit(f"{source} is not the index its manifest names; nothing written")
    atomic_write_bytes(target, data)
    del manifest["files"][source.name]
    manifest["files"][target.name] = {"bytes": len(data), "sha256": sha256_bytes(data)}
    atomic_write_bytes(manifest_path, (json.dumps(manifest, indent=1, sort_keys=True) + "\n").encode())
    source.unlink()
    return [f"{source.relative_to(assets)}: {len(raw)} -> {target.name} {len(data)} bytes"]


def pack_results(results: Path, write: bool) -> list[str]:
    """Every packed run's ``results.jsonl.gz`` under ``results`` into ``results.jsonl.xz``."""
    done = []
    for path in sorted(results.rglob(LEGACY_PACKED_RESULTS_FILE)):
        if path.parent.is_symlink() or not (path.parent / "run.json").is_file():
            continue  # a link to a run packed where it lies; not a packed run
        if not write:
            done.append(f"{path.relative_to(results.parent)}: not packed")
            continue
        store = ResultsStore(path.parent)
        records = store.records()
        manifest_bytes, data = packed_bytes(store.manifest(), records)
        if manifest_bytes != (path.parent / "run.json").read_bytes() or gzip.decompress(path.read_bytes()) != \
                unxz_bytes(data):
            raise SystemExit(f"{path}: not a run as `fetchbench results pack` writes it; nothing written")
        atomic_write_bytes(path.with_name(PACKED_RESULTS_FILE), data)
        path.unlink()
        done.append(f"{path.relative_to(results.parent)}: {path.with_name(PACKED_RESULTS_FILE).name} {len(data)} bytes")
    return done


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--assets", default=str(ROOT / "assets"), help="the assets folder (default: the checkout's)")
    p.add_argument("--results", default=str(ROOT / "results"), help="the records folder (default: the checkout's)")
    p.add_argument("--only", default=",".join(PARTS), help=f"comma-separated parts (default all: {', '.join(PARTS)})")
    p.add_argument("--check", action="store_true", help="change nothing; exit 1 if anything is left to pack")
    args = p.parse_args(argv)
    parts = [x for x in args.only.split(",") if x]
    unknown = sorted(set(parts) - set(PARTS))
    if unknown or not parts:
        p.error(f"--only {args.only!r}: unknown {', '.join(unknown) or '(none given)'}; valid: {', '.join(PARTS)}")
    assets, write = Path(args.assets), not args.check
    steps = {"checkpoints": lambda: pack_checkpoints(assets, write), "grasps": lambda: pack_grasps(assets, write),
             "suites": lambda: pack_suites(assets, write), "catalog": lambda: pack_catalog(assets, write),
             "results": lambda: pack_results(Path(args.results), write)}
    changed = [line for part in parts for line in steps[part]()]
    print("\n".join(changed) if changed else "nothing to pack")
    return 1 if changed and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
