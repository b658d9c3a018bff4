"""E2EImit-Transformer: behaviour cloning with a GPT-style policy over the last steps.

The paper's E2EImit-Transformer: the same step embeddings as E2EImit-MLP (point encoder on
the segmented clouds, proprioception MLP, stage one-hot) for the last ``--history`` steps
(4), a causal transformer (an Optimus-style head), and a Tanh-Gaussian mixture over the 7
normalised arm deltas plus the stage-termination logit at the newest step. A step's history
stays inside its stage (padded with the stage's first frame), as at deployment, where the
history restarts when the phase changes. The network is
``fetchbench_ms.policies.networks.TransformerPolicy``; the loop is ``common.py``'s.

    python baselines/imitation/train_transformer.py --data data/imit --run runs/imit/transformer \\
        --steps 30000 --time-limit 540 --export
    python baselines/imitation/train_transformer.py --data /tmp/imit-sample --run /tmp/tf --device cpu \\
        --steps 20 --batch-size 16 --scene-points 128 --target-points 64 --robot-points 32 --eval-every 0
"""
from __future__ import annotations

from dataclasses import dataclass

import tyro

from common import Frames, TrainArgs, train
from fetchbench_ms.policies.networks import TransformerConfig, TransformerPolicy


@dataclass
class Args(TrainArgs):
    history: int = 4
    d_model: int = 256
    layers: int = 3
    heads: int = 4
    dropout: float = 0.1
    modes: int = 5  # mixture components
    lr: float = 1e-4
    batch_size: int = 128


def batch_loss(model: TransformerPolicy, frames: Frames, index, generator, args: Args) -> dict:
    obs = frames.observation(index, history=args.history, jitter=args.point_jitter if model.training else 0.0,
                             generator=generator)
    return model.loss(obs, frames.action[index], frames.terminal[index], args.termination_weight,
                      args.termination_pos_weight)


def make_model(args: Args):
    return TransformerPolicy(TransformerConfig(encoder=args.encoder(), history=args.history,
                                               d_model=args.d_model, layers=args.layers, heads=args.heads,
                                               dropout=args.dropout, modes=args.modes))


def main(args: Args) -> dict:
    return train(args, "transformer", lambda: make_model(args), lambda m, f, i, g: batch_loss(m, f, i, g, args))


if __name__ == "__main__":
    main(tyro.cli(Args))
