"""A PPO run's learning curve per 10k environment steps, from its CSV logs
(``baselines/ppo/ppo.py``: ``train.csv``, ``eval.csv``): a markdown table of the training
episodes' return and success per bin, the evaluations, and optionally a PNG.

    PYTHONPATH=. python scripts/rl_curve.py runs/ppo-curriculum [runs/ppo-table ...] --bin 10000 \\
        --png docs/img/rl_learning_curve.png
"""
from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np


def read(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path) as f:
        return list(csv.DictReader(f))


def binned(train: list[dict], size: int) -> list[dict]:
    """Episode-weighted mean return and success of the training episodes that ended in
    each ``size``-step bin of global steps; a bin's ``steps`` is the last step the run
    reached in it (a run shorter than a bin is plotted where it ended, not at the bin's end)."""
    bins: dict[int, list] = {}
    for row in train:
        if not row["episodes"] or int(row["episodes"]) == 0 or row["return"] == "":
            continue
        k = (int(row["global_step"]) - 1) // size
        bins.setdefault(k, []).append((int(row["episodes"]), float(row["return"]), float(row["success_once"] or 0),
                                       int(row["global_step"])))
    out = []
    for k in sorted(bins):
        n = np.array([b[0] for b in bins[k]], dtype=float)
        out.append({"steps": max(b[3] for b in bins[k]), "episodes": int(n.sum()),
                    "return": float(np.dot(n, [b[1] for b in bins[k]]) / n.sum()),
                    "success": float(np.dot(n, [b[2] for b in bins[k]]) / n.sum())})
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("runs", type=Path, nargs="+", help="PPO --out-dir folders")
    p.add_argument("--bin", type=int, default=10_000)
    p.add_argument("--png", type=Path, default=None)
    args = p.parse_args(argv)
    if args.bin < 1:
        p.error(f"--bin must be a positive number of steps, got {args.bin}")
    curves = {}
    for run in args.runs:
        train, evals = read(run / "train.csv"), read(run / "eval.csv")
        if not train and not evals:  # nothing to show is an error, not empty panels
            print(f"rl_curve: error: {run} holds no training iteration (train.csv: "
                  f"{'header only' if (run / 'train.csv').exists() else 'missing'}) and no evaluation; valid: the "
                  "--out-dir of a PPO run that trained", file=sys.stderr)
            return 2
        curves[run.name] = (binned(train, args.bin), evals)
        wall = float(train[-1]["wall_s"]) if train else 0.0
        steps = int(train[-1]["global_step"]) if train else 0
        print(f"\n### {run.name}: {steps:,} steps in {wall:.0f} s of wall time (start-up, updates and "
              f"evaluations included: {steps / max(wall, 1e-9):.0f} steps/s)\n")
        print("| steps up to | training episodes ended | mean return | success |\n| --- | --- | --- | --- |")
        for b in curves[run.name][0]:
            print(f"| {b['steps']:,} | {b['episodes']} | {b['return']:.2f} | {b['success']:.3f} |")
        if evals:
            print("\n| eval at step | episodes | success | return | length |\n| --- | --- | --- | --- | --- |")
            for e in evals:
                print(f"| {int(e['global_step']):,} | {e['episodes']} | {float(e['success_once']):.3f} | "
                      f"{float(e['return']):.2f} | {float(e['episode_len']):.1f} |")
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 3.6))
        for name, (bins, evals) in curves.items():
            x = [b["steps"] for b in bins]
            ax.plot(x, [b["return"] for b in bins], marker=".", label=name)
            ax2.plot(x, [b["success"] for b in bins], marker=".", label=f"{name} (train)")
            if evals:
                ax2.plot([int(e["global_step"]) for e in evals], [float(e["success_once"]) for e in evals],
                         marker="o", ls="--", label=f"{name} (eval)")
        ax.set_xlabel("environment steps")
        ax.set_ylabel(f"episode return (per {args.bin:,}-step bin)")
        ax2.set_xlabel("environment steps")
        ax2.set_ylabel("success rate")
        ax2.set_ylim(-0.02, 1.02)
        ax.legend(fontsize=7)
        ax2.legend(fontsize=7)
        fig.tight_layout()
        args.png.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.png.with_name(args.png.stem + ".tmp.png")
        fig.savefig(tmp, dpi=110)
        tmp.replace(args.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
