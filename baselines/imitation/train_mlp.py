"""E2EImit-MLP: behaviour cloning of the Fetch dataset with a Tanh-Gaussian MLP policy.

The paper's E2EImit-MLP (FetchBench, CoRL 2024, appendix "Imitation Learning"): the
segmented point clouds (scene / target / robot) through a point encoder, the proprioception
through an MLP, the stage one-hot (approach, retrieve); a 3-layer MLP on the current step's
embedding outputs a Tanh-Gaussian over the 7 normalised arm deltas (``pd_joint_delta_pos``)
and the stage-termination logit. Loss: action negative log-likelihood + weighted
termination BCE; AdamW with warm-up and cosine decay. The network is the package's
(``fetchbench_ms.policies.networks.MLPPolicy``); the loop, the run folder and the validation
are ``common.py``'s.

    # data: scripts/imitation/convert_demos_for_imitation.py (docs/imitation.md); the H100 run, ~10 min a
    # call, resumed by the same command; the last call evaluates on val tasks and exports
    python baselines/imitation/train_mlp.py --data data/imit --run runs/imit/mlp --steps 30000 \\
        --time-limit 540 --export
    # a CPU smoke run on small clouds
    python baselines/imitation/train_mlp.py --data /tmp/imit-sample --run /tmp/mlp --device cpu \\
        --steps 20 --batch-size 16 --scene-points 128 --target-points 64 --robot-points 32 --eval-every 0
"""
from __future__ import annotations

from dataclasses import dataclass

import tyro

from common import Frames, TrainArgs, train
from fetchbench_ms.policies.networks import MLPConfig, MLPPolicy


@dataclass
class Args(TrainArgs):
    hidden: int = 512
    layers: int = 3


def batch_loss(model: MLPPolicy, frames: Frames, index, generator, args: Args) -> dict:
    obs = frames.observation(index, history=1, jitter=args.point_jitter if model.training else 0.0,
                             generator=generator)
    return model.loss(obs, frames.action[index], frames.terminal[index], args.termination_weight,
                      args.termination_pos_weight)


def make_model(args: Args):
    return MLPPolicy(MLPConfig(encoder=args.encoder(), hidden=args.hidden, layers=args.layers))


def main(args: Args) -> dict:
    return train(args, "mlp", lambda: make_model(args), lambda m, f, i, g: batch_loss(m, f, i, g, args))


if __name__ == "__main__":
    main(tyro.cli(Args))
