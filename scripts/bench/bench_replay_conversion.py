"""Time ManiSkill's pd_joint_pos -> pd_joint_delta_pos conversion as it ships (the source env
stepped beside the recorded one) against the replay module's (the source env unstepped, the
same file; ``fetchbench_ms/replay_trajectory.py``), state-only, on the shipped demo sample.

    python scripts/bench/bench_replay_conversion.py --count 20
"""
from __future__ import annotations

import argparse
import contextlib
import shutil
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

from fetchbench_ms import replay_trajectory

SAMPLE = Path("assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5")


def convert(source: Path, folder: Path, count: int, stock: bool) -> tuple[float, Path]:
    """Seconds of one state-only conversion of ``count`` demos (in this process, one env)."""
    folder.mkdir()
    for suffix in (".h5", ".json"):
        shutil.copy(source.with_suffix(suffix), folder / f"demos{suffix}")
    with replay_trajectory.stock_action_conversion() if stock else contextlib.nullcontext():
        t = time.perf_counter()
        replay_trajectory.main(["--traj-path", str(folder / "demos.h5"), "-c", "pd_joint_delta_pos", "-o", "state",
                                "--save-traj", "--count", str(count)])
        return time.perf_counter() - t, folder / "demos.state.pd_joint_delta_pos.physx_cpu.h5"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--traj-path", type=Path, default=SAMPLE)
    p.add_argument("--count", type=int, default=20)
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        seconds, files = {}, {}
        for name in ("stock", "unstepped"):
            seconds[name], files[name] = convert(args.traj_path, Path(tmp) / name, args.count, name == "stock")
        with h5py.File(files["stock"], "r") as a, h5py.File(files["unstepped"], "r") as b:
            steps = sum(len(a[k]["actions"]) for k in a)
            same = all(np.array_equal(a[k]["actions"][:], b[k]["actions"][:]) for k in a) and set(a) == set(b)
    print(f"{args.count} demos, {steps} converted steps, one process (start-up included):")
    for name, s in seconds.items():
        print(f"  {name:9s} {s:6.1f} s  {steps / s:6.1f} steps/s")
    print(f"  speed-up {seconds['stock'] / seconds['unstepped']:.2f}x; same actions: {same}")


if __name__ == "__main__":
    main()
