"""The scene-collision network's figures on TEST-split scenes (reporting only: nothing here
chooses anything; the checkpoint was fixed before), and its query throughput.

1. Labels for ``--suite test --tasks a:b`` exactly as for training
   (``baselines/mppi_collision/labels.py``: the env's camera clouds, the mix of queries,
   exact clearances to the oracle meshes) into ``--labels`` (resumable).
2. Accuracy, precision and recall of "collides", the false-free rates, for the network
   and for the cloud-only distance field (``distance - radius < 0``: what the Ptd planners
   see) on all of those queries.
3. Queries per second against one encoded scene (``--batch`` queries a call, the arm's 77
   spheres; with FK from joint angles and without), and the scene encoding time.

    python scripts/bench/bench_collision_net.py --suite test --tasks 0:60 --labels /tmp/mppi/test --device cuda --workers 4 \\
        --json runs/bench_collision_net.json
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "baselines" / "mppi_collision"))


@dataclass
class Args:
    suite: str = "test"
    tasks: str = "0:60"
    labels: str = "/tmp/mppi/test"
    configs: int = 4000
    workers: int = 1
    label_device: str = "cpu"  # where the exact labels are computed
    device: str = "cuda" if torch.cuda.is_available() else "cpu"
    checkpoint: str = ""  # default: assets/checkpoints/collision_net.pt
    batch: int = 20_000  # queries per throughput call (77 spheres each: 1.5 M spheres, ~2 GB of gathered features)
    threads: int = 1  # CPU threads for the CPU throughput figure
    json: str = ""  # write the figures here too


def throughput(model, spheres, grid, device, batch: int, repeats: int = 10) -> dict:
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    with torch.no_grad():
        model.encode(grid.to(device))  # warm-up (cuDNN picks its algorithms)
        sync()
        t = time.perf_counter()
        scene = model.encode(grid.to(device))
        sync()
        encode_s = time.perf_counter() - t
        q = torch.rand(batch, 7, device=device) * 2 - 1
        centers = spheres.centers(q)
        out = {}

        def bf16(fn):
            def run():
                with torch.autocast(device.type, dtype=torch.bfloat16):
                    return fn()
            return run

        variants = [("spheres_in", lambda: model.probability(scene, centers, spheres.radii)),
                    ("joints_in", lambda: model.probability(scene, spheres.centers(q), spheres.radii))]
        if device.type == "cuda":
            variants.append(("joints_in_bf16", bf16(variants[1][1])))
        for name, fn in variants:
            fn()
            sync()
            t = time.perf_counter()
            for _ in range(repeats):
                fn()
            sync()
            out[f"queries_per_s_{name}"] = batch * repeats / (time.perf_counter() - t)
        out["encode_s"] = encode_s
        return out


def main(args: Args) -> None:
    import labels as labelling
    from train import Tasks, evaluate

    from fetchbench_ms.planning.collision_net import RobotSpheres, grid_from_uint8, load_collision_net

    labelling.main(labelling.Args(suite=args.suite, tasks=args.tasks, out=args.labels, configs=args.configs,
                                  workers=args.workers, device=args.label_device), reporting_only=True)
    device = torch.device(args.device)
    model = load_collision_net(args.checkpoint or None, str(device))
    spheres = RobotSpheres(device)
    data = Tasks.__new__(Tasks)
    # Tasks refuses test files for training; here they are read for reporting only.
    data_files = sorted(Path(args.labels).glob("*.npz"))
    data_files = [f for f in data_files if not f.name.endswith(".tmp.npz")]
    z = [np.load(f) for f in data_files]
    k = min(len(x["q"]) for x in z)
    data.grids = torch.as_tensor(np.stack([x["grid"] for x in z]), device=device)
    data.q = torch.as_tensor(np.stack([x["q"][:k] for x in z]), device=device)
    data.mm = torch.as_tensor(np.stack([x["clearance_mm"][:k] for x in z]), device=device)
    data.label = torch.as_tensor(np.stack([x["label"][:k] for x in z]), device=device).bool()
    data.checked = torch.as_tensor(np.stack([x["checked"] for x in z]), device=device).bool()
    data.radii = torch.as_tensor(np.stack([x["radii"] for x in z]), device=device, dtype=torch.float32)
    data.att = torch.as_tensor(np.stack([x["att_centers_hand"] for x in z]), device=device, dtype=torch.float32)
    data.n, data.k, data.ids = len(z), k, [str(x["task_id"]) for x in z]
    figures = dict(suite=args.suite, tasks=data.n, queries_per_task=k, carry_tasks=int(sum(bool(x["carry"]) for x in z)))
    figures.update(evaluate(model, spheres, data, k))
    grid = grid_from_uint8(z[0]["grid"])
    figures["throughput_" + device.type] = throughput(model, spheres, grid, device, args.batch)
    torch.set_num_threads(args.threads)
    cpu_model = load_collision_net(args.checkpoint or None, "cpu")
    figures[f"throughput_cpu_{args.threads}_threads"] = throughput(cpu_model, RobotSpheres("cpu"), grid,
                                                                   torch.device("cpu"), min(args.batch, 5000), 2)
    text = json.dumps(figures, indent=1)
    print(text)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(args.json + ".tmp")
        tmp.write_text(text)
        tmp.replace(args.json)


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))
