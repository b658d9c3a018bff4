"""A diffusion policy on point clouds (DP3-style; Chi et al. 2023, Ze et al. 2024).

Not in the paper; what ManiSkill users expect next to BC (ManiSkill's
``examples/baselines/diffusion_policy``). The step embeddings of the last ``--obs-horizon``
steps (the same point encoder, proprioception MLP and stage one-hot as E2EImit) condition
a small 1-D convolutional UNet (FiLM) that denoises a chunk of ``--pred-horizon`` normalised
arm deltas from the newest step on (DDPM, epsilon prediction, squared-cosine schedule);
deployment samples with DDIM in ``--sample-steps`` and executes ``--act-horizon`` of them.
Past the end of its stage a chunk is padded with zeros (the arm holds, as it does while the
gripper closes). A termination MLP on the same condition ends the stages. The network is
``fetchbench_ms.policies.networks.DiffusionPolicy``; the loop is ``common.py``'s.

    python baselines/imitation/train_diffusion.py --data data/imit --run runs/imit/diffusion \\
        --steps 30000 --time-limit 540 --export
    python baselines/imitation/train_diffusion.py --data /tmp/imit-sample --run /tmp/dp --device cpu \\
        --steps 20 --batch-size 16 --scene-points 128 --target-points 64 --robot-points 32 --eval-every 0
"""
from __future__ import annotations

from dataclasses import dataclass

import tyro

from common import Frames, TrainArgs, train
from fetchbench_ms.policies.networks import DiffusionConfig, DiffusionPolicy


@dataclass
class Args(TrainArgs):
    obs_horizon: int = 2
    pred_horizon: int = 16
    act_horizon: int = 8
    unet_dims: tuple[int, ...] = (48, 96, 192)
    train_diffusion_steps: int = 100
    sample_steps: int = 10
    lr: float = 1e-4


def batch_loss(model: DiffusionPolicy, frames: Frames, index, generator, args: Args) -> dict:
    obs = frames.observation(index, history=args.obs_horizon, jitter=args.point_jitter if model.training else 0.0,
                             generator=generator)
    return model.loss(obs, frames.action_chunk(index, args.pred_horizon), frames.terminal[index],
                      args.termination_weight, args.termination_pos_weight, generator=generator)


def make_model(args: Args):
    return DiffusionPolicy(DiffusionConfig(encoder=args.encoder(), obs_horizon=args.obs_horizon,
                                           pred_horizon=args.pred_horizon, act_horizon=args.act_horizon,
                                           unet_dims=tuple(args.unet_dims), train_steps=args.train_diffusion_steps,
                                           sample_steps=args.sample_steps))


def main(args: Args) -> dict:
    return train(args, "diffusion", lambda: make_model(args), lambda m, f, i, g: batch_loss(m, f, i, g, args))


if __name__ == "__main__":
    main(tyro.cli(Args))
