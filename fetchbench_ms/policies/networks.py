"""The imitation policies' networks (plain torch; trained by ``baselines/imitation/``).

Every policy embeds one step the same way (``StepEncoder``): a PointNet shared by all
points (base-frame xyz, xyz relative to the TCP, a one-hot of the point's class: furniture,
other object, target, robot) max-pooled per segment (scene, target, robot), an MLP on the
proprioception (9 joint positions, TCP pose), and the stage one-hot (approach, retrieve).
The original used PointNet++ and a voxel CNN here; a segment-pooled PointNet keeps a
checkpoint at a few MB and a step at a few ms on a CPU.

Heads:
- ``MLPPolicy`` (E2EImit-MLP): 3-layer MLP -> Tanh-Gaussian over the 7 normalised arm
  deltas, plus the stage-termination logit;
- ``TransformerPolicy`` (E2EImit-Transformer): the embeddings of the last ``history`` steps
  through a causal GPT-style transformer -> a Tanh-Gaussian mixture, plus the logit;
- ``DiffusionPolicy`` (DP3-style, Chi et al. 2023 / Ze et al. 2024): the embeddings of the last
  ``obs_horizon`` steps condition a 1-D convolutional UNet that denoises a chunk of
  ``pred_horizon`` actions (DDPM training, DDIM sampling); a termination MLP on the same
  condition.
- ``ACTPolicy`` (ACT, Zhao et al. 2023): the step encoder's pieces as tokens (a point segment
  each, proprioception, stage), a CVAE style latent, a transformer encoder-decoder whose
  ``chunk`` learned queries give a chunk of actions (L1 loss, masked past the stage's end).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..envs.pointcloud import COMPACT_OBS_MODE
from ..method_spec import PolicyKind, load, policy_kind
from .data import ARM_DOF, POINT_CLASSES, POLICY_SIZES, POLICY_STAGES, segment_slices

PROPRIO_DIM = 18  # 9 joint positions + TCP position (3) + rotation 6-D (6)
POINT_FEATURES = 6 + len(POINT_CLASSES)
TANH_EPS = 1e-6
ACTION_LIMIT = 0.999  # demo actions are clipped here before atanh (the expert stays below 1)


@dataclass
class EncoderConfig:
    sizes: dict = field(default_factory=lambda: dict(POLICY_SIZES))
    point_dims: tuple = (64, 128, 256)
    point_out: int = 256
    proprio_dims: tuple = (128, 128)
    #: The env obs mode whose points the policy was trained on and reads at deployment
    #: (checkpoints without it: compact_pointcloud, the shipped ones).
    obs_mode: str = COMPACT_OBS_MODE

    @property
    def embed_dim(self) -> int:
        return self.point_out + self.proprio_dims[-1] + len(POLICY_STAGES)


def _mlp(dims, last_activation=True) -> nn.Sequential:
    layers = []
    for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
        layers.append(nn.Linear(a, b))
        if last_activation or i < len(dims) - 2:
            layers += [nn.LayerNorm(b), nn.GELU()]
    return nn.Sequential(*layers)


def stage_one_hot(stage: torch.Tensor) -> torch.Tensor:
    """[...] demo stage ids (approach 0, retrieve 2) -> [..., 2] one-hot."""
    return torch.stack([stage == s for s in POLICY_STAGES], dim=-1).float()


class StepEncoder(nn.Module):
    """One step's observation -> an embedding [..., embed_dim] (any leading batch dims).

    ``embedding=False``: only ``parts`` is used (ACT), so the segments' joint projection that
    ``forward`` needs is not made (no unused weights in the checkpoint)."""

    def __init__(self, cfg: EncoderConfig, embedding: bool = True):
        super().__init__()
        self.cfg = cfg
        self.slices = segment_slices(cfg.sizes)
        self.point_mlp = _mlp((POINT_FEATURES, *cfg.point_dims))
        self.point_proj = _mlp((3 * cfg.point_dims[-1], cfg.point_out)) if embedding else None
        self.proprio_mlp = _mlp((PROPRIO_DIM, *cfg.proprio_dims))
        self.register_buffer("classes", torch.tensor(POINT_CLASSES, dtype=torch.uint8), persistent=False)

    def parts(self, points, point_label, qpos, tcp) -> tuple[torch.Tensor, torch.Tensor]:
        """The pieces the embedding is made of, leading dims flattened to N: the per-segment
        max-pooled point features [N, 3 (scene, target, robot), point_dims[-1]] and the
        proprioception features [N, proprio_dims[-1]] (ACT makes a token of each)."""
        points = points.reshape(-1, *points.shape[-2:]).float()
        point_label = point_label.reshape(-1, point_label.shape[-1])
        tcp_flat = tcp.reshape(-1, tcp.shape[-1]).float()
        one_hot = (point_label[..., None] == self.classes).float()
        x = torch.cat([points, points - tcp_flat[:, None, :3], one_hot], dim=-1)
        per_point = self.point_mlp(x)
        # Filler points (an unseen segment: label none) must not win the max.
        per_point = per_point.masked_fill((one_hot.sum(-1) == 0)[..., None], -1e4)
        pooled = torch.stack([per_point[:, s].max(dim=1).values.clamp(min=-10.0) for s in self.slices.values()], dim=1)
        proprio = self.proprio_mlp(torch.cat([qpos.reshape(-1, qpos.shape[-1]).float(), tcp_flat], dim=-1))
        return pooled, proprio

    def forward(self, points, point_label, qpos, tcp, stage) -> torch.Tensor:
        lead = points.shape[:-2]
        pooled, proprio = self.parts(points, point_label, qpos, tcp)
        cloud = self.point_proj(pooled.flatten(1))  # the segments side by side, as concatenated
        out = torch.cat([cloud, proprio, stage_one_hot(stage.reshape(-1))], dim=-1)
        return out.reshape(*lead, -1)


def tanh_gaussian_log_prob(mean, log_std, action) -> torch.Tensor:
    """log p(action) of a Gaussian squashed by tanh, summed over action dims."""
    action = action.clamp(-ACTION_LIMIT, ACTION_LIMIT)
    pre = torch.atanh(action)
    normal = torch.distributions.Normal(mean, log_std.exp())
    return (normal.log_prob(pre) - torch.log(1 - action.pow(2) + TANH_EPS)).sum(-1)


# ----------------------------------------------------------------------------- MLP
@dataclass
class MLPConfig:
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    hidden: int = 512
    layers: int = 3
    log_std_range: tuple = (-5.0, 1.0)


class MLPPolicy(nn.Module):
    kind = "mlp"
    history = 1

    def __init__(self, cfg: MLPConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = StepEncoder(cfg.encoder)
        self.trunk = _mlp((cfg.encoder.embed_dim, *[cfg.hidden] * cfg.layers))
        self.head = nn.Linear(cfg.hidden, 2 * ARM_DOF + 1)

    def forward(self, obs: dict):
        """obs tensors [B, ...] -> (mean, log_std [B, 7], termination logit [B])."""
        h = self.trunk(self.encoder(obs["points"], obs["point_label"], obs["qpos"], obs["tcp"], obs["stage"]))
        out = self.head(h)
        low, high = self.cfg.log_std_range
        log_std = low + 0.5 * (high - low) * (torch.tanh(out[:, ARM_DOF:2 * ARM_DOF]) + 1)
        return out[:, :ARM_DOF], log_std, out[:, -1]

    def loss(self, obs: dict, action, terminal, term_weight: float = 1.0, term_pos_weight: float = 1.0) -> dict:
        mean, log_std, term = self(obs)
        nll = -tanh_gaussian_log_prob(mean, log_std, action).mean()
        bce = F.binary_cross_entropy_with_logits(term, terminal.float(),
                                                 pos_weight=torch.tensor(term_pos_weight, device=term.device))
        return {"loss": nll + term_weight * bce, "nll": nll, "termination": bce,
                "mse": F.mse_loss(torch.tanh(mean), action)}

    @torch.no_grad()
    def act(self, obs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(actions [B, 1, 7] in [-1, 1], termination probability [B]): the squashed mean."""
        mean, _, term = self(obs)
        return torch.tanh(mean)[:, None], torch.sigmoid(term)


# ----------------------------------------------------------------------------- Transformer
@dataclass
class TransformerConfig:
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    history: int = 4
    d_model: int = 256
    layers: int = 3
    heads: int = 4
    dropout: float = 0.1
    modes: int = 5  # Gaussian-mixture components
    min_std: float = 1e-4


class TransformerPolicy(nn.Module):
    kind = "transformer"

    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        self.cfg = cfg
        self.history = cfg.history
        self.encoder = StepEncoder(cfg.encoder)
        self.proj = nn.Linear(cfg.encoder.embed_dim, cfg.d_model)
        self.position = nn.Parameter(torch.zeros(cfg.history, cfg.d_model))
        layer = nn.TransformerEncoderLayer(cfg.d_model, cfg.heads, 4 * cfg.d_model, cfg.dropout,
                                           activation="gelu", batch_first=True, norm_first=True)
        self.blocks = nn.TransformerEncoder(layer, cfg.layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(cfg.d_model)
        self.head = nn.Linear(cfg.d_model, cfg.modes * (1 + 2 * ARM_DOF) + 1)
        self.register_buffer("causal", torch.triu(torch.full((cfg.history, cfg.history), float("-inf")), 1),
                             persistent=False)

    def forward(self, obs: dict):
        """obs tensors [B, H, ...] (oldest first) -> (mixture logits [B, K], means, stds [B, K, 7],
        termination logit [B]) at the newest step."""
        e = self.encoder(obs["points"], obs["point_label"], obs["qpos"], obs["tcp"], obs["stage"])
        h = self.proj(e) + self.position[: e.shape[1]]
        h = self.norm(self.blocks(h, mask=self.causal[: e.shape[1], : e.shape[1]], is_causal=True))[:, -1]
        out = self.head(h)
        K = self.cfg.modes
        logits = out[:, :K]
        means = out[:, K:K + K * ARM_DOF].reshape(-1, K, ARM_DOF)
        stds = F.softplus(out[:, K + K * ARM_DOF:K + 2 * K * ARM_DOF].reshape(-1, K, ARM_DOF)) + self.cfg.min_std
        return logits, means, stds, out[:, -1]

    def loss(self, obs: dict, action, terminal, term_weight: float = 1.0, term_pos_weight: float = 1.0) -> dict:
        logits, means, stds, term = self(obs)
        a = action.clamp(-ACTION_LIMIT, ACTION_LIMIT)
        pre = torch.atanh(a)
        comp = torch.distributions.Independent(torch.distributions.Normal(means, stds), 1)
        mix = torch.distributions.MixtureSameFamily(torch.distributions.Categorical(logits=logits), comp)
        log_prob = mix.log_prob(pre) - torch.log(1 - a.pow(2) + TANH_EPS).sum(-1)
        nll = -log_prob.mean()
        bce = F.binary_cross_entropy_with_logits(term, terminal.float(),
                                                 pos_weight=torch.tensor(term_pos_weight, device=term.device))
        best = means[torch.arange(len(means)), logits.argmax(-1)]
        return {"loss": nll + term_weight * bce, "nll": nll, "termination": bce,
                "mse": F.mse_loss(torch.tanh(best), action)}

    @torch.no_grad()
    def act(self, obs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(actions [B, 1, 7], termination probability [B]): the most likely mode's mean, squashed."""
        logits, means, _, term = self(obs)
        best = means[torch.arange(len(means)), logits.argmax(-1)]
        return torch.tanh(best)[:, None], torch.sigmoid(term)


# ----------------------------------------------------------------------------- Diffusion
@dataclass
class DiffusionConfig:
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    obs_horizon: int = 2
    pred_horizon: int = 16  # actions denoised at once, starting at the newest observed step
    act_horizon: int = 8  # of which executed before the next denoising
    unet_dims: tuple = (48, 96, 192)  # ~3.5M parameters in all: a 7 MB fp16 checkpoint
    kernel: int = 5
    groups: int = 8
    step_embed: int = 64
    cond_dim: int = 256  # the observation condition is projected to this before FiLM
    train_steps: int = 100  # DDPM noise levels
    sample_steps: int = 10  # DDIM steps at inference


class SinusoidalEmbedding(nn.Module):
    def __init__(self, dim: int):
        super().__init__()
        self.dim = dim

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        half = self.dim // 2
        freq = torch.exp(-math.log(10000) * torch.arange(half, device=t.device) / (half - 1))
        x = t.float()[:, None] * freq[None]
        return torch.cat([x.sin(), x.cos()], dim=-1)


class ConvBlock(nn.Sequential):
    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int):
        super().__init__(nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), nn.GroupNorm(groups, c_out), nn.Mish())


class FiLMResBlock(nn.Module):
    """Two conv blocks; the condition scales and shifts the first one's output (FiLM)."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int, kernel: int, groups: int):
        super().__init__()
        self.block1, self.block2 = ConvBlock(c_in, c_out, kernel, groups), ConvBlock(c_out, c_out, kernel, groups)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * c_out))
        self.skip = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x, cond):
        scale, shift = self.film(cond)[..., None].chunk(2, dim=1)
        h = self.block1(x) * scale + shift
        return self.block2(h) + self.skip(x)


class ConditionalUnet1D(nn.Module):
    """The diffusion policy's denoiser (Chi et al. 2023), small: noisy actions [B, T, A] ->
    predicted noise [B, T, A], conditioned on the diffusion step and the observation."""

    def __init__(self, action_dim: int, cond_dim: int, dims=(64, 128, 256), kernel: int = 5, groups: int = 8,
                 step_embed: int = 64):
        super().__init__()
        self.step = nn.Sequential(SinusoidalEmbedding(step_embed), nn.Linear(step_embed, 4 * step_embed), nn.Mish(),
                                  nn.Linear(4 * step_embed, step_embed))
        cond_dim = cond_dim + step_embed
        channels = (action_dim, *dims)
        self.down = nn.ModuleList()
        for i, (a, b) in enumerate(zip(channels[:-1], channels[1:])):
            last = i == len(dims) - 1
            self.down.append(nn.ModuleList([FiLMResBlock(a, b, cond_dim, kernel, groups),
                                            FiLMResBlock(b, b, cond_dim, kernel, groups),
                                            nn.Conv1d(b, b, 3, 2, 1) if not last else nn.Identity()]))
        self.mid = nn.ModuleList([FiLMResBlock(dims[-1], dims[-1], cond_dim, kernel, groups) for _ in range(2)])
        self.up = nn.ModuleList()
        for i, (a, b) in enumerate(zip(reversed(dims[1:]), reversed(dims[:-1]))):
            self.up.append(nn.ModuleList([FiLMResBlock(2 * a, b, cond_dim, kernel, groups),
                                          FiLMResBlock(b, b, cond_dim, kernel, groups),
                                          nn.ConvTranspose1d(b, b, 4, 2, 1)]))
        self.out = nn.Sequential(ConvBlock(dims[0], dims[0], kernel, groups), nn.Conv1d(dims[0], action_dim, 1))

    def forward(self, x, t, cond):
        cond = torch.cat([self.step(t), cond], dim=-1)
        h = x.transpose(1, 2)
        skips = []
        for res1, res2, down in self.down:
            h = res2(res1(h, cond), cond)
            skips.append(h)
            h = down(h)
        for res in self.mid:
            h = res(h, cond)
        for res1, res2, up in self.up:
            h = res2(res1(torch.cat([h, skips.pop()], dim=1), cond), cond)
            h = up(h)
        return self.out(h).transpose(1, 2)


def cosine_alphas_cumprod(steps: int) -> torch.Tensor:
    """The squared-cosine noise schedule (``squaredcos_cap_v2``), as ᾱ_t for t = 0..steps-1."""
    t = torch.arange(steps + 1, dtype=torch.float64) / steps
    f = torch.cos((t + 0.008) / 1.008 * math.pi / 2) ** 2
    betas = (1 - f[1:] / f[:-1]).clamp(max=0.999)
    return torch.cumprod(1 - betas, dim=0).float()


class DiffusionPolicy(nn.Module):
    kind = "diffusion"

    def __init__(self, cfg: DiffusionConfig):
        super().__init__()
        if cfg.pred_horizon % (2 ** (len(cfg.unet_dims) - 1)):
            raise ValueError(f"pred_horizon {cfg.pred_horizon} must be a multiple of {2 ** (len(cfg.unet_dims) - 1)} "
                             f"(the UNet halves it {len(cfg.unet_dims) - 1} times)")
        self.cfg = cfg
        self.history = cfg.obs_horizon
        self.encoder = StepEncoder(cfg.encoder)
        cond_dim = cfg.obs_horizon * cfg.encoder.embed_dim
        self.cond_proj = _mlp((cond_dim, cfg.cond_dim))
        self.denoiser = ConditionalUnet1D(ARM_DOF, cfg.cond_dim, cfg.unet_dims, cfg.kernel, cfg.groups, cfg.step_embed)
        self.termination = _mlp((cfg.cond_dim, 128, 1), last_activation=False)
        self.register_buffer("alphas_cumprod", cosine_alphas_cumprod(cfg.train_steps), persistent=False)

    def condition(self, obs: dict) -> torch.Tensor:
        e = self.encoder(obs["points"], obs["point_label"], obs["qpos"], obs["tcp"], obs["stage"])
        return self.cond_proj(e.flatten(1))

    def loss(self, obs: dict, actions, terminal, term_weight: float = 1.0, term_pos_weight: float = 1.0,
             generator: torch.Generator | None = None) -> dict:
        """``actions`` [B, pred_horizon, 7]: the chunk from the newest observed step on."""
        cond = self.condition(obs)
        noise = torch.randn(actions.shape, device=actions.device, generator=generator)
        t = torch.randint(0, self.cfg.train_steps, (len(actions),), device=actions.device, generator=generator)
        a_bar = self.alphas_cumprod[t][:, None, None]
        noisy = a_bar.sqrt() * actions + (1 - a_bar).sqrt() * noise
        mse = F.mse_loss(self.denoiser(noisy, t, cond), noise)
        term = self.termination(cond)[:, 0]
        bce = F.binary_cross_entropy_with_logits(term, terminal.float(),
                                                 pos_weight=torch.tensor(term_pos_weight, device=term.device))
        return {"loss": mse + term_weight * bce, "noise_mse": mse, "termination": bce}

    def termination_prob(self, obs: dict) -> torch.Tensor:
        """[B]: the termination probability alone (no denoising)."""
        return torch.sigmoid(self.termination(self.condition(obs))[:, 0])

    @torch.no_grad()
    def act(self, obs: dict, generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(action chunk [B, act_horizon, 7] in [-1, 1], termination probability [B]): DDIM
        (deterministic, eta 0) from seeded noise."""
        cond = self.condition(obs)
        B, device = len(cond), cond.device
        x = torch.randn((B, self.cfg.pred_horizon, ARM_DOF), device=device, generator=generator)
        steps = torch.linspace(self.cfg.train_steps - 1, 0, self.cfg.sample_steps, device=device).round().long()
        for i, t in enumerate(steps):
            a_bar = self.alphas_cumprod[t]
            a_prev = self.alphas_cumprod[steps[i + 1]] if i + 1 < len(steps) else torch.tensor(1.0, device=device)
            eps = self.denoiser(x, t.expand(B), cond)
            x0 = ((x - (1 - a_bar).sqrt() * eps) / a_bar.sqrt()).clamp(-1, 1)
            eps = (x - a_bar.sqrt() * x0) / (1 - a_bar).sqrt()
            x = a_prev.sqrt() * x0 + (1 - a_prev).sqrt() * eps
        return x[:, : self.cfg.act_horizon].clamp(-1, 1), torch.sigmoid(self.termination(cond)[:, 0])


# ----------------------------------------------------------------------------- ACT
@dataclass
class ACTConfig:
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    chunk: int = 16  # actions predicted at once, from the observed frame on
    latent_dim: int = 32  # the CVAE's style variable z
    d_model: int = 192  # 3.26M parameters in all: a 6.6 MB fp16 checkpoint (<= 8 MB)
    layers: int = 2  # of each transformer: the CVAE encoder, the observation encoder, the decoder
    heads: int = 6
    dropout: float = 0.1
    # Deployment (agent.ImitationPolicy): ACT's temporal ensembling, or the chunk open-loop.
    temporal_ensemble: bool = True
    ensemble_m: float = 0.01  # weights exp(-m i), i = 0 for the oldest prediction of a frame


def _encoder_stack(cfg: ACTConfig, layers: int) -> nn.TransformerEncoder:
    layer = nn.TransformerEncoderLayer(cfg.d_model, cfg.heads, 4 * cfg.d_model, cfg.dropout, activation="gelu",
                                       batch_first=True, norm_first=True)
    return nn.TransformerEncoder(layer, layers, norm=nn.LayerNorm(cfg.d_model), enable_nested_tensor=False)


class ACTPolicy(nn.Module):
    """Action Chunking with Transformers (Zhao et al. 2023) on the shared step encoder.

    Observation tokens: one per point segment (its pooled PointNet feature), one for the
    proprioception, one for the stage. A CVAE encoder (transformer over [CLS, proprioception,
    the demo's action chunk]) gives the style latent z in training; at run time z = 0. The
    encoder reads [z, observation tokens]; the decoder's ``chunk`` learned queries read its
    output and give the chunk of normalised arm deltas (tanh)."""

    kind = "act"
    history = 1  # ACT conditions on the current observation only

    def __init__(self, cfg: ACTConfig):
        super().__init__()
        self.cfg = cfg
        d, enc = cfg.d_model, cfg.encoder
        self.encoder = StepEncoder(enc, embedding=False)
        self.segment_token = nn.Linear(enc.point_dims[-1], d)
        self.proprio_token = nn.Linear(enc.proprio_dims[-1], d)
        self.stage_token = nn.Linear(len(POLICY_STAGES), d)
        n_obs = len(self.encoder.slices) + 2
        # CVAE encoder (training only): [CLS, raw proprioception, actions].
        self.cls = nn.Parameter(torch.zeros(1, 1, d))
        self.cvae_proprio = nn.Linear(PROPRIO_DIM, d)
        self.cvae_action = nn.Linear(ARM_DOF, d)
        self.cvae_position = nn.Parameter(torch.zeros(2 + cfg.chunk, d))
        self.cvae = _encoder_stack(cfg, cfg.layers)
        self.latent_stats = nn.Linear(d, 2 * cfg.latent_dim)
        self.latent_token = nn.Linear(cfg.latent_dim, d)
        # Observation encoder over [z, observation tokens]; decoder with the chunk's queries.
        self.position = nn.Parameter(torch.zeros(1 + n_obs, d))
        self.obs_encoder = _encoder_stack(cfg, cfg.layers)
        self.queries = nn.Parameter(torch.zeros(cfg.chunk, d))
        layer = nn.TransformerDecoderLayer(d, cfg.heads, 4 * d, cfg.dropout, activation="gelu", batch_first=True,
                                           norm_first=True)
        self.decoder = nn.TransformerDecoder(layer, cfg.layers, norm=nn.LayerNorm(d))
        self.action_head = nn.Linear(d, ARM_DOF)
        # The termination reads the observation tokens before the encoder mixes z in: in
        # training z comes from the demo's own chunk, whose padding tells how near the stage
        # ends, and at run time z = 0, so a head after the encoder would learn from a cue
        # that deployment never gives.
        self.termination = _mlp((n_obs * d, 128, 1), last_activation=False)
        for p in (self.cls, self.cvae_position, self.position, self.queries):
            nn.init.normal_(p, std=0.02)

    def observation_tokens(self, obs: dict) -> torch.Tensor:
        """[B, 5, d]: scene, target, robot, proprioception, stage."""
        pooled, proprio = self.encoder.parts(obs["points"], obs["point_label"], obs["qpos"], obs["tcp"])
        return torch.cat([self.segment_token(pooled), self.proprio_token(proprio)[:, None],
                          self.stage_token(stage_one_hot(obs["stage"].reshape(-1)))[:, None]], dim=1)

    def latent(self, obs: dict, actions, valid) -> tuple[torch.Tensor, torch.Tensor]:
        """The CVAE posterior's (mean, log-variance) [B, latent_dim] of the chunk ``actions``
        [B, chunk, 7], ``valid`` [B, chunk] (False past the segment's end: not attended to)."""
        B = len(actions)
        proprio = torch.cat([obs["qpos"].float(), obs["tcp"].float()], dim=-1)
        tokens = torch.cat([self.cls.expand(B, -1, -1), self.cvae_proprio(proprio)[:, None],
                            self.cvae_action(actions)], dim=1) + self.cvae_position
        ignore = torch.cat([torch.zeros(B, 2, dtype=torch.bool, device=actions.device), ~valid], dim=1)
        h = self.cvae(tokens, src_key_padding_mask=ignore)[:, 0]
        mean, log_var = self.latent_stats(h).chunk(2, dim=-1)
        return mean, log_var

    def forward(self, obs: dict, z: torch.Tensor | None = None):
        """obs tensors [B, ...], z [B, latent_dim] (None: 0) -> (actions [B, chunk, 7] in
        [-1, 1], termination logit [B])."""
        tokens = self.observation_tokens(obs)
        if z is None:
            z = tokens.new_zeros(len(tokens), self.cfg.latent_dim)
        memory = self.obs_encoder(torch.cat([self.latent_token(z)[:, None], tokens], dim=1) + self.position)
        h = self.decoder(self.queries.expand(len(tokens), -1, -1), memory)
        return torch.tanh(self.action_head(h)), self.termination(tokens.flatten(1))[:, 0]

    def loss(self, obs: dict, actions, valid, terminal, kl_weight: float = 10.0, term_weight: float = 1.0,
             term_pos_weight: float = 1.0, generator: torch.Generator | None = None) -> dict:
        """``actions`` [B, chunk, 7] from the frame on, ``valid`` [B, chunk]: False past the
        frame's segment end (ACT's is_pad), where the L1 does not look."""
        mean, log_var = self.latent(obs, actions, valid)
        eps = torch.randn(mean.shape, device=mean.device, generator=generator)
        predicted, term = self(obs, mean + (0.5 * log_var).exp() * eps)
        l1 = masked_l1(predicted, actions, valid)
        kl = (-0.5 * (1 + log_var - mean.pow(2) - log_var.exp())).sum(-1).mean()
        bce = F.binary_cross_entropy_with_logits(term, terminal.float(),
                                                 pos_weight=torch.tensor(term_pos_weight, device=term.device))
        return {"loss": l1 + kl_weight * kl + term_weight * bce, "l1": l1, "kl": kl, "termination": bce}

    def termination_prob(self, obs: dict) -> torch.Tensor:
        """[B]: the termination probability alone (no transformer)."""
        return torch.sigmoid(self.termination(self.observation_tokens(obs).flatten(1))[:, 0])

    @torch.no_grad()
    def act(self, obs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(action chunk [B, chunk, 7] in [-1, 1], termination probability [B]), z = 0."""
        actions, term = self(obs)
        return actions, torch.sigmoid(term)


def masked_l1(predicted, target, valid) -> torch.Tensor:
    """The mean |predicted - target| over the valid steps [B, T] of chunks [B, T, A]."""
    weight = valid[..., None].float()
    return ((predicted - target).abs() * weight).sum() / (weight.sum() * target.shape[-1]).clamp(min=1.0)


def policy_classes(kind: PolicyKind | str) -> tuple[type, type]:
    """A policy kind's network and config classes (its row of ``method_spec.POLICY_KINDS``,
    or the row itself)."""
    row = kind if isinstance(kind, PolicyKind) else policy_kind(kind)
    return load(row.network), load(row.config)


def config_to_dict(cfg) -> dict:
    return asdict(cfg)


def config_from_dict(kind: PolicyKind | str, d: dict):
    _, Config = policy_classes(kind)
    d = dict(d)
    enc = EncoderConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.pop("encoder").items()})
    return Config(encoder=enc, **{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})


def build_policy(kind: PolicyKind | str, cfg=None) -> nn.Module:
    Policy, Config = policy_classes(kind)
    return Policy(cfg if cfg is not None else Config())
