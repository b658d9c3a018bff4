"""ACT: Action Chunking with Transformers (Zhao et al. 2023), on point clouds.

The paper's E2EImit-ACT row (0.093, its appendix). The shared step encoder's pieces become
tokens: one per point segment (scene, target, robot: the max-pooled PointNet features), one
for the proprioception, one for the stage. A CVAE encoder (a transformer over [CLS,
proprioception, the demo's chunk of ``--chunk`` normalised arm deltas]) gives a style latent
z (``--latent-dim``, sampled with reparameterisation; 0 at run time); a transformer encoder
reads [z, observation tokens] and a decoder's ``--chunk`` learned queries give the chunk.
Loss: L1 over the chunk (steps past the frame's stage segment ignored: ACT's is_pad)
+ ``--kl-weight`` x KL + the weighted termination BCE of the other policies. Deployment
ensembles the overlapping chunks (ACT's temporal ensembling, ``agent.TemporalEnsemble``).
The network is ``fetchbench_ms.policies.networks.ACTPolicy``; the loop is ``common.py``'s.

    python baselines/imitation/train_act.py --data data/imit --run runs/imit/act \\
        --steps 30000 --time-limit 540 --export
    python baselines/imitation/train_act.py --data /tmp/imit-sample --run /tmp/act --device cpu \\
        --steps 20 --batch-size 16 --scene-points 128 --target-points 64 --robot-points 32 --eval-every 0
"""
from __future__ import annotations

from dataclasses import dataclass

import tyro

from common import Frames, TrainArgs, train
from fetchbench_ms.policies.networks import ACTConfig, ACTPolicy


@dataclass
class Args(TrainArgs):
    chunk: int = 16  # frames of actions predicted at once
    kl_weight: float = 10.0  # the KL term's weight (ACT's 10)
    latent_dim: int = 32
    d_model: int = 192
    layers: int = 2  # of each transformer (CVAE encoder, observation encoder, decoder)
    heads: int = 6
    dropout: float = 0.1
    temporal_ensemble: bool = True  # deployment: ensemble overlapping chunks (else run each chunk open-loop)
    ensemble_m: float = 0.01  # the ensemble's weights exp(-m i), i = 0 for the oldest prediction
    lr: float = 1e-4  # ACT's


def batch_loss(model: ACTPolicy, frames: Frames, index, generator, args: Args) -> dict:
    obs = frames.observation(index, jitter=args.point_jitter if model.training else 0.0, generator=generator)
    actions, valid = frames.action_chunk(index, args.chunk, with_mask=True)
    return model.loss(obs, actions, valid, frames.terminal[index], args.kl_weight, args.termination_weight,
                      args.termination_pos_weight, generator=generator)


def make_model(args: Args):
    return ACTPolicy(ACTConfig(encoder=args.encoder(), chunk=args.chunk, latent_dim=args.latent_dim,
                               d_model=args.d_model, layers=args.layers, heads=args.heads, dropout=args.dropout,
                               temporal_ensemble=args.temporal_ensemble, ensemble_m=args.ensemble_m))


def main(args: Args) -> dict:
    return train(args, "act", lambda: make_model(args), lambda m, f, i, g: batch_loss(m, f, i, g, args))


if __name__ == "__main__":
    main(tyro.cli(Args))
