"""The imitation networks' time per observed step: each kind's default network (untrained
weights: the cost does not depend on them) on one full-size observation (1,024 scene + 512
target + 256 robot points), as ``ImitationPolicy`` calls it at deployment. Prints a table.

    python scripts/bench/bench_policy_step.py [--device cpu|cuda] [--repeats 20] [--threads N]

The network is a small part of an end-to-end step (rendering the cameras and sampling the
points are most of it, docs/imitation.md "Policy stride"); this is what differs between kinds.
"""
from __future__ import annotations

import argparse
import time

import torch

from fetchbench_ms.policies.data import POLICY_SIZES
from fetchbench_ms.method_spec import POLICY_KINDS
from fetchbench_ms.policies.networks import build_policy


def observation(model, device) -> dict:
    n = sum(POLICY_SIZES.values())
    lead = (1,) if model.history == 1 else (1, model.history)
    g = torch.Generator().manual_seed(0)
    obs = {"points": torch.rand(*lead, n, 3, generator=g), "point_label": torch.randint(1, 4, (*lead, n), generator=g,
                                                                                         dtype=torch.uint8),
           "qpos": torch.rand(*lead, 9, generator=g), "tcp": torch.rand(*lead, 9, generator=g),
           "stage": torch.zeros(lead, dtype=torch.long)}
    return {k: v.to(device) for k, v in obs.items()}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"device {args.device}, {torch.get_num_threads()} threads, {args.repeats} repeats after 3 warm-up calls")
    print(f"{'kind':<12} {'parameters':>11} {'ms a step (median)':>19} {'min':>7}")
    for kind in POLICY_KINDS:
        model = build_policy(kind).to(args.device).eval()
        obs = observation(model, args.device)
        times = []
        for k in range(3 + args.repeats):
            t = time.perf_counter()
            model.act(obs)
            if args.device.startswith("cuda"):
                torch.cuda.synchronize()
            if k >= 3:
                times.append(1e3 * (time.perf_counter() - t))
        times.sort()
        params = sum(p.numel() for p in model.parameters())
        print(f"{kind:<12} {params / 1e6:>10.2f}M {times[len(times) // 2]:>19.1f} {times[0]:>7.1f}")


if __name__ == "__main__":
    main()
