"""A grasp directory written in the earlier form (``manifest.json`` + ``shard_NN.npz``), made
from a packed one: what a user who built labels before the packed form holds."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from fetchbench_ms.grasp_labels import store


def write_npz_form(packed_dir: Path, target: Path, shards=None) -> None:
    """``target`` holds ``packed_dir``'s labels (only ``shards``, when given) as .npz shards."""
    manifest = store.read_manifest(packed_dir)
    manifest["shards"] = {k: e for k, e in manifest["shards"].items() if shards is None or int(k) in shards}
    target.mkdir(parents=True)
    for entry in manifest["shards"].values():
        path = target / entry["file"].replace(store.ARRAYS_SUFFIX, store.LEGACY_SHARD_SUFFIX)
        np.savez_compressed(path, **store.read_shard_arrays(packed_dir / entry["file"]))
        entry.update(file=path.name, sha256=store.sha256_file(path))
    (target / store.LEGACY_MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
