"""A compact copy of a demo file for moving it between machines.

    python scripts/maint/demos_transport.py pack SRC.h5 DST.npz        # + DST.json
    python scripts/maint/demos_transport.py unpack DST.npz OUT.h5      # + OUT.json

A dataset of 5,000 demos is ~500 MB: env states, one row per step, and HDF5's per-dataset
overhead (about 25 small datasets a trajectory). The transport keeps, per trajectory, everything but the
env states' middle rows (the actions, the stage labels, success / terminated / truncated,
the first and the last env state), with every array of one name concatenated over the
trajectories in one compressed ``.npz`` (~5 KB a trajectory).

``unpack`` writes it back as a ManiSkill trajectory file that is enough for what a second
machine does with the demos: ManiSkill's replay tool converting to another controller
(``-c pd_joint_delta_pos``, ``-c pd_ee_delta_pose``) resets the env from the recorded
``reset_kwargs`` and replays the actions, and reads env states only with
``--use-env-states`` / ``--use-first-env-state``; the imitation converter pairs a converted
demo with its source by the last env state's joints. It is not a dataset for
``--use-env-states`` (the replay tool would run out of states), except on the first
``--full-states N`` trajectories, which keep every row; its JSON says so under
``fetchbench_transport`` (with the source file's name and sha256). Files are written beside
their final name and renamed.
"""
from __future__ import annotations

import argparse
import io
import json
import os
from pathlib import Path

import h5py
import numpy as np

from fetchbench_ms.utils.io import atomic_write_text, sha256_file

KEPT_ENV_STATES = "env_states rows 1 .. T-1 left out (kept: the first and the last), except in the first full_env_states trajectories"


def _leaves(group: h5py.Group, prefix: str = "", full_states: bool = False):
    for key, item in group.items():
        path = f"{prefix}{key}"
        if isinstance(item, h5py.Group):
            yield from _leaves(item, path + "/", full_states)
        else:
            data = item[()]
            yield path, (data[[0, -1]] if path.startswith("env_states/") and not full_states else data)


def pack(source: Path, out: Path, full_states: int = 0) -> dict:
    """``full_states``: the first N trajectories keep every env-state row (so the replay
    tool's ``--use-env-states`` works on them: ``--count N``)."""
    meta_path = source.with_suffix(".json")
    if not source.is_file() or not meta_path.is_file():
        raise SystemExit(f"no demos at {source} (+ .json)")
    meta = json.loads(meta_path.read_text())
    if "fetchbench_transport" in meta:
        raise SystemExit(f"{source} is already a transport copy (of {meta['fetchbench_transport']['source']})")
    by_path: dict[str, list] = {}  # leaf path -> [(episode index, array)]
    with h5py.File(source, "r") as f:
        for k, episode in enumerate(meta["episodes"]):
            for path, data in _leaves(f[f"traj_{episode['episode_id']}"], full_states=k < full_states):
                by_path.setdefault(path, []).append((k, data))
    arrays = {}
    for path, items in sorted(by_path.items()):
        arrays[f"{path}|data"] = np.concatenate([np.atleast_1d(a) for _, a in items])
        arrays[f"{path}|episode"] = np.array([k for k, _ in items], dtype=np.int32)
        arrays[f"{path}|rows"] = np.array([len(np.atleast_1d(a)) for _, a in items], dtype=np.int32)
    out.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")  # per process: two runs never share one
    tmp.write_bytes(buffer.getvalue())
    meta["fetchbench_transport"] = {"source": source.name, "source_sha256": sha256_file(source),
                                    "left_out": KEPT_ENV_STATES,
                                    "full_env_states": min(full_states, len(meta["episodes"])),
                                    "use": "controller conversion with the replay tool (-c ...); --use-env-states "
                                           "only on the first full_env_states trajectories (--count)"}
    os.replace(tmp, out)
    atomic_write_text(out.with_suffix(".json"), json.dumps(meta, indent=2))
    return {"episodes": len(meta["episodes"]), "source_bytes": source.stat().st_size, "bytes": out.stat().st_size}


def unpack(packed: Path, out: Path) -> dict:
    meta = json.loads(packed.with_suffix(".json").read_text())
    if "fetchbench_transport" not in meta:
        raise SystemExit(f"{packed.with_suffix('.json')} is not a transport copy (no fetchbench_transport key)")
    episodes = meta["episodes"]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")  # per process: two runs never share one
    with np.load(packed) as z, h5py.File(tmp, "w", track_order=True) as f:
        groups = [f.create_group(f"traj_{e['episode_id']}", track_order=True) for e in episodes]
        for key in sorted(k for k in z.files if k.endswith("|data")):
            path = key[: -len("|data")]
            data, owners, rows = z[key], z[f"{path}|episode"], z[f"{path}|rows"]
            starts = np.concatenate([[0], np.cumsum(rows)])
            for k, owner in enumerate(owners):
                part = data[starts[k]:starts[k + 1]]
                big = part.size > 16
                groups[owner].create_dataset(path, data=part, compression="gzip" if big else None,
                                             compression_opts=4 if big else None, shuffle=big)
    os.replace(tmp, out)
    atomic_write_text(out.with_suffix(".json"), json.dumps(meta, indent=2))
    return {"episodes": len(episodes), "bytes": out.stat().st_size}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("pack", help="SRC.h5 -> DST.npz + DST.json")
    p.add_argument("source", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--full-states", type=int, default=0, metavar="N",
                   help="keep every env-state row of the first N trajectories (for --use-env-states)")
    u = sub.add_parser("unpack", help="DST.npz -> OUT.h5 + OUT.json")
    u.add_argument("packed", type=Path)
    u.add_argument("out", type=Path)
    args = ap.parse_args(argv)
    result = pack(args.source, args.out, args.full_states) if args.command == "pack" else unpack(args.packed, args.out)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
