"""PPO on FetchBench: one file, in the style of CleanRL and ManiSkill's
``examples/baselines/ppo/ppo.py`` (docs/rl.md).

Two ways to run many environments, one training loop:

- CPU (``--sim-backend cpu``, the default): a ``gymnasium.vector.AsyncVectorEnv`` of
  ManiSkill ``CPUGymWrapper`` envs, one process per env (``fetchbench_ms.envs.make_vec_env``),
  reset in the same step they finish (gymnasium's SAME_STEP autoreset);
- GPU simulation (``--sim-backend physx_cuda``): one batched env wrapped in ManiSkill's
  ``ManiSkillVectorEnv``. Both hand the loop torch tensors and the same ``final_info``
  / ``final_observation`` on episode ends (``CPUVectorEnv`` below adapts the CPU one).
  ``--vector-env maniskill`` runs that path on the CPU too (with ``--num-envs 1``: the CPU
  simulates one sub-scene), which is how it is tested here: no machine of ours can run
  PhysX on a GPU (SAPIEN downloads its GPU runtime on first use; there is no internet).

Observations: the env's state vector (``--obs state``), normalised by running statistics
kept in the checkpoint; or (``--obs pointcloud``) the robot's proprioception and the
compact segmented point cloud of the cameras (``obs_mode="compact_pointcloud"``: scene
and target points in the base frame, ``--points`` of them) through a PointNet encoder.
Actions: ``pd_joint_delta_pos`` by default. Reward: ``normalized_dense`` (in [0, 1]).

Logs: ``<out-dir>/train.csv`` (one row per iteration: steps, episode return and success of
the episodes that ended, losses, steps per second) and ``<out-dir>/eval.csv`` (periodic
evaluation on the ``val`` task suite by default: success rate, return, length), plus
TensorBoard event files when ``tensorboard`` is installed. ``<out-dir>/checkpoint.pt``
is written at every evaluation and when ``--time-limit`` seconds are up; the same command
then resumes from it (``--no-resume`` starts over).

    PYTHONPATH=. python baselines/ppo/ppo.py --env-id FetchBench-Table-v0 --curriculum table-near-pregrasp \\
        --num-envs 16 --time-limit 600 --out-dir runs/ppo-curriculum
"""
from __future__ import annotations

import csv
import json
import math
import os
import random
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal, Optional

import tyro

from fetchbench_ms.tasks.splits import cli_guard, refuse_test


@dataclass
class Args:
    # experiment
    out_dir: str = "runs/ppo"
    """CSV logs, TensorBoard events and checkpoint.pt go here"""
    seed: int = 1
    cuda: bool = True
    """the policy on the GPU when there is one"""
    time_limit: float = 0.0
    """seconds of training, then a checkpoint and a clean exit (0: none); the same command resumes.
    Counted from the first iteration: start-up (curriculum tasks, env workers) is not training"""
    resume: bool = True
    """resume from <out-dir>/checkpoint.pt when it exists"""
    tensorboard: bool = True
    """also write TensorBoard events (when the package is installed)"""
    torch_threads: int = 1
    """torch threads of the learner process (the env workers use one each). More only on
    idle cores: with every core busy stepping envs, a thread pool makes each tiny MLP op
    wait for a time slice (measured: 6 ms a tanh with 2 threads on 2 busy cores)"""

    # environment
    env_id: str = "FetchBench-Table-v0"
    curriculum: Optional[str] = None
    """an env curriculum preset (fetchbench_ms.envs.curriculum.CURRICULA), e.g. table-near-pregrasp"""
    task_suite: Optional[str] = None
    """the suite training tasks come from (None: the env's default, train)"""
    eval_task_suite: Optional[str] = "val"
    """the suite evaluation tasks come from (never test; None: the env's default)"""
    control_mode: str = "pd_joint_delta_pos"
    reward_mode: str = "normalized_dense"
    obs: Literal["state", "pointcloud"] = "state"
    points: int = 1024
    """points of the cloud the PointNet sees (--obs pointcloud): 3/4 scene, 1/4 target"""
    max_episode_steps: Optional[int] = None
    """episode length (None: the env's, 400)"""
    sim_backend: str = "cpu"
    """cpu: one process per env; physx_cuda: GPU simulation of all envs in one process"""
    vector_env: Optional[Literal["async", "maniskill"]] = None
    """async: gymnasium AsyncVectorEnv of CPUGymWrapper envs; maniskill: ManiSkillVectorEnv (None: by backend)"""
    num_envs: int = 16
    num_eval_envs: int = 4
    num_eval_episodes: int = 16
    eval_freq: int = 6
    """evaluate (and checkpoint) every this many iterations (0: only at the end)"""
    partial_reset: bool = True
    """an episode ends at success (else only at the time limit)"""

    # algorithm
    total_timesteps: int = 10_000_000
    num_steps: int = 100
    """steps per env per rollout"""
    learning_rate: float = 3e-4
    anneal_lr: bool = False
    gamma: float = 0.8
    gae_lambda: float = 0.9
    num_minibatches: int = 4
    update_epochs: int = 4
    norm_adv: bool = True
    clip_coef: float = 0.2
    clip_vloss: bool = False
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float = 0.1
    reward_scale: float = 1.0
    bootstrap_at_done: Literal["always", "truncated"] = "always"
    """bootstrap the value at every episode end (ManiSkill's default) or only at truncations"""
    hidden: int = 256


def check_args(args: Args) -> None:
    """The flags' own errors (ValueError, one line) and the test-split guard (exit 2), before
    torch and the simulator load: a bad flag is answered at once."""
    cli_guard(refuse_test, args.task_suite, "PPO training")
    cli_guard(refuse_test, args.eval_task_suite, "PPO evaluation")
    if args.num_envs < 1 or args.num_eval_envs < 1:
        raise ValueError(f"--num-envs and --num-eval-envs must be >= 1, got {args.num_envs}, {args.num_eval_envs}")
    batch_size = args.num_envs * args.num_steps
    if batch_size % args.num_minibatches:
        raise ValueError(f"num_envs x num_steps = {batch_size} is not divisible by num_minibatches "
                         f"{args.num_minibatches}; valid: a divisor of {batch_size}")
    if args.time_limit < 0:
        raise ValueError(f"--time-limit must be >= 0 (0: none), got {args.time_limit}")


if __name__ == "__main__":
    ARGS = tyro.cli(Args)
    try:
        check_args(ARGS)
    except ValueError as error:
        print(f"ppo.py: error: {error}", file=sys.stderr)
        sys.exit(2)

import gymnasium as gym  # noqa: E402  (after the flags: see check_args)
import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn as nn  # noqa: E402
from torch.distributions.normal import Normal  # noqa: E402

import fetchbench_ms  # noqa: E402,F401  (registers FetchBench-*-v0)
from fetchbench_ms.envs import make_vec_env  # noqa: E402
from fetchbench_ms.envs.curriculum import prepare as prepare_curriculum  # noqa: E402
from fetchbench_ms.envs.wrappers import PointCloudStateObs  # noqa: E402


# ---------------------------------------------------------------------------- observations
def pointcloud_wrapper(points: int):
    """A picklable wrapper factory for make_vec_env's worker processes."""
    import functools

    return functools.partial(PointCloudStateObs, points=points)


# ---------------------------------------------------------------------------- vector envs
class CPUVectorEnv:
    """An AsyncVectorEnv of CPUGymWrapper envs (SAME_STEP autoreset, episode metrics) with
    ManiSkillVectorEnv's interface: torch tensors in and out, and on episode ends
    ``info["final_info"]["episode"]`` (return, episode_len, success_once), the mask
    ``info["_final_info"]`` and ``info["final_observation"]`` [N, D] (rows of finished envs)."""

    def __init__(self, vec: gym.vector.VectorEnv, device: torch.device):
        self.vec, self.device = vec, device
        self.num_envs = vec.num_envs
        self.single_observation_space = vec.single_observation_space
        self.single_action_space = vec.single_action_space

    def _t(self, x, dtype=torch.float32):
        return torch.as_tensor(np.asarray(x), dtype=dtype, device=self.device)

    def reset(self, seed=None):
        obs, _ = self.vec.reset(seed=seed)
        return self._t(obs), {}

    def step(self, action: torch.Tensor):
        obs, reward, terminated, truncated, info = self.vec.step(action.detach().cpu().numpy())
        out = {}
        if "final_info" in info:
            done = np.asarray(info["_final_info"], dtype=bool)
            episode = info["final_info"]["episode"]
            out["final_info"] = {"episode": {k: self._t(np.asarray(v, dtype=np.float32)) for k, v in episode.items()
                                             if not k.startswith("_")}}
            out["_final_info"] = torch.as_tensor(done, device=self.device)
            final = np.zeros((self.num_envs, *self.single_observation_space.shape), dtype=np.float32)
            for i in np.flatnonzero(done):
                final[i] = info["final_obs"][i]
            out["final_observation"] = self._t(final)
        return (self._t(obs), self._t(reward), self._t(terminated, torch.bool), self._t(truncated, torch.bool), out)

    def close(self):
        self.vec.close()


def make_envs(args: Args, num_envs: int, task_suite: Optional[str], device: torch.device, ignore_terminations: bool):
    """The training or evaluation vector env for ``args`` (see the module docstring)."""
    env_kwargs = dict(obs_mode="compact_pointcloud" if args.obs == "pointcloud" else "state",
                      control_mode=args.control_mode, reward_mode=args.reward_mode)
    if args.obs == "state":
        env_kwargs["render_backend"] = "none"
    if args.curriculum is not None:
        env_kwargs["curriculum"] = args.curriculum
    if task_suite is not None:
        env_kwargs["task_suite"] = task_suite
    if args.max_episode_steps is not None:
        env_kwargs["max_episode_steps"] = args.max_episode_steps
    wrappers = (pointcloud_wrapper(args.points),) if args.obs == "pointcloud" else ()
    vector_env = args.vector_env or ("async" if args.sim_backend == "cpu" else "maniskill")
    if vector_env == "async":
        if args.sim_backend != "cpu":
            raise ValueError(f"--vector-env async runs CPU envs; valid with it: --sim-backend cpu "
                             f"(got {args.sim_backend!r})")
        vec = make_vec_env(args.env_id, num_envs, wrappers=wrappers, record_metrics=True,
                           ignore_terminations=ignore_terminations,
                           autoreset_mode=gym.vector.AutoresetMode.SAME_STEP, **env_kwargs)
        return CPUVectorEnv(vec, device)
    from mani_skill.vector.wrappers.gymnasium import ManiSkillVectorEnv

    env = gym.make(args.env_id, num_envs=num_envs, sim_backend=args.sim_backend, **env_kwargs)
    for wrapper in wrappers:
        env = wrapper(env)
    return ManiSkillVectorEnv(env, num_envs, ignore_terminations=ignore_terminations, record_metrics=True)


# ---------------------------------------------------------------------------- agent
class RunningMeanStd(nn.Module):
    """Running mean / variance of observations (parallel-variance update), as buffers so
    they travel in the checkpoint."""

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim))
        self.register_buffer("var", torch.ones(dim))
        self.register_buffer("count", torch.tensor(1e-4))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        batch_mean, batch_var, n = x.mean(0), x.var(0, unbiased=False), x.shape[0]
        delta, total = batch_mean - self.mean, self.count + n
        self.mean += delta * n / total
        self.var.copy_((self.var * self.count + batch_var * n + delta**2 * self.count * n / total) / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.clamp((x - self.mean) / torch.sqrt(self.var + 1e-8), -10.0, 10.0)


def layer_init(layer, std=math.sqrt(2), bias_const=0.0):
    torch.nn.init.orthogonal_(layer.weight, std)
    torch.nn.init.constant_(layer.bias, bias_const)
    return layer


class PointNet(nn.Module):
    """Shared per-point MLP and a max-pool: [B, P, 4] -> [B, out]."""

    def __init__(self, out: int = 256):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(4, 64), nn.ReLU(), nn.Linear(64, 128), nn.ReLU(), nn.Linear(128, out))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.mlp(points).max(dim=1).values


class Agent(nn.Module):
    """Actor (Gaussian, state-independent log std) and critic MLPs on the normalised
    state, with a point cloud on [normalised state, PointNet features]."""

    def __init__(self, obs_dim: int, act_dim: int, hidden: int = 256, points: int = 0):
        super().__init__()
        self.points = points
        self.state_dim = obs_dim - 4 * points
        self.obs_rms = RunningMeanStd(self.state_dim)
        feat = self.state_dim
        if points:
            self.encoder = PointNet(hidden)
            feat = self.state_dim + hidden

        def mlp(out, std):
            return nn.Sequential(layer_init(nn.Linear(feat, hidden)), nn.Tanh(), layer_init(nn.Linear(hidden, hidden)),
                                 nn.Tanh(), layer_init(nn.Linear(hidden, hidden)), nn.Tanh(),
                                 layer_init(nn.Linear(hidden, out), std=std))

        self.critic = mlp(1, 1.0)
        self.actor_mean = mlp(act_dim, 0.01 * math.sqrt(2))
        self.actor_logstd = nn.Parameter(torch.ones(1, act_dim) * -0.5)

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        state = self.obs_rms(obs[:, : self.state_dim])
        if not self.points:
            return state
        cloud = obs[:, self.state_dim:].reshape(obs.shape[0], self.points, 4)
        return torch.cat([state, self.encoder(cloud)], dim=1)

    def get_value(self, obs):
        return self.critic(self.features(obs))

    def get_action(self, obs, deterministic: bool = False):
        mean = self.actor_mean(self.features(obs))
        if deterministic:
            return mean
        return Normal(mean, self.actor_logstd.expand_as(mean).exp()).sample()

    def get_action_and_value(self, obs, action=None):
        x = self.features(obs)
        mean = self.actor_mean(x)
        dist = Normal(mean, self.actor_logstd.expand_as(mean).exp())
        if action is None:
            action = dist.sample()
        return action, dist.log_prob(action).sum(1), dist.entropy().sum(1), self.critic(x)


# ---------------------------------------------------------------------------- logging
class CSVLog:
    """Rows appended to a CSV file (flushed each row, header once); a resumed run appends."""

    def __init__(self, path: Path, fields: list[str]):
        self.path, self.fields = path, fields
        new = not path.exists()
        self.file = open(path, "a", newline="")
        self.writer = csv.DictWriter(self.file, fieldnames=fields, extrasaction="ignore")
        if new:
            self.writer.writeheader()

    def write(self, row: dict) -> None:
        self.writer.writerow({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()})
        self.file.flush()

    def close(self):
        self.file.close()


def tensorboard_writer(args: Args, out: Path):
    if not args.tensorboard:
        return None
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard is not installed: the CSV logs carry everything
        return None
    return SummaryWriter(str(out / "tb"))


TRAIN_FIELDS = ["iteration", "global_step", "wall_s", "sps", "episodes", "return", "success_once", "episode_len",
                "reward_per_step", "value_loss", "policy_loss", "entropy", "approx_kl", "clipfrac", "learning_rate"]
EVAL_FIELDS = ["iteration", "global_step", "wall_s", "episodes", "success_once", "return", "episode_len"]


# ---------------------------------------------------------------------------- evaluation
@torch.no_grad()
def evaluate(agent: Agent, envs, num_episodes: int, seed: int) -> dict:
    """Deterministic-policy episodes until ``num_episodes`` have ended: their success rate
    (success at any step), mean return and length."""
    obs, _ = envs.reset(seed=seed)
    low, high = (torch.as_tensor(b, device=obs.device) for b in (envs.single_action_space.low,
                                                                   envs.single_action_space.high))
    done_metrics: dict[str, list] = {"success_once": [], "return": [], "episode_len": []}
    while len(done_metrics["return"]) < num_episodes:
        obs, _, _, _, info = envs.step(torch.clamp(agent.get_action(obs, deterministic=True), low, high))
        if "final_info" in info:
            mask = info["_final_info"]
            for key in done_metrics:
                value = info["final_info"]["episode"].get(key)
                if value is not None:
                    done_metrics[key] += value[mask].float().cpu().tolist()
    return {k: float(np.mean(v[:num_episodes])) if v else float("nan") for k, v in done_metrics.items()} | {
        "episodes": num_episodes}


# ---------------------------------------------------------------------------- checkpoints
def save_checkpoint(path: Path, agent: Agent, optimizer, state: dict, args: Args) -> None:
    """Written to a temporary file and renamed: a kill leaves the previous checkpoint."""
    tmp = path.with_name(path.name + ".tmp")
    torch.save({"agent": agent.state_dict(), "optimizer": optimizer.state_dict(), "state": state,
                "args": asdict(args)}, tmp)
    os.replace(tmp, path)


def main(args: Args) -> dict:
    # Training tasks and the evaluation that picks the best checkpoint: never test (exit 2,
    # before anything is written).
    check_args(args)
    out = Path(args.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    start = time.time()
    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.torch_threads)
    gpu_sim = args.sim_backend.split(":")[0] in ("physx_cuda", "gpu", "cuda")
    # GPU simulation hands out CUDA tensors: the policy goes where they are.
    device = torch.device("cuda" if (args.cuda or gpu_sim) and torch.cuda.is_available() else "cpu")
    batch_size = args.num_envs * args.num_steps
    minibatch_size = batch_size // args.num_minibatches
    num_iterations = max(1, args.total_timesteps // batch_size)
    ckpt_path = out / "checkpoint.pt"
    if args.resume and ckpt_path.exists():  # before any env starts: a finished run has nothing to do
        done = torch.load(ckpt_path, map_location="cpu", weights_only=False)["state"]
        if done["iteration"] >= num_iterations:
            print(f"trained 0 iterations: {ckpt_path} is already at iteration {done['iteration']} of "
                  f"{num_iterations} (--total-timesteps {args.total_timesteps}); valid: a larger --total-timesteps "
                  "to train on, or --no-resume to start over", file=sys.stderr, flush=True)
            return {"state": done, "final_eval": None, "stopped_by_time": False, "trained_iterations": 0}

    if args.curriculum is not None and args.sim_backend == "cpu":
        # Make the curriculum's tasks once, in parallel, before the env workers start
        # (each would otherwise make every task it meets: seconds of IK a task).
        for suite in (args.task_suite, args.eval_task_suite):
            n = prepare_curriculum(args.env_id, args.curriculum, suite, processes=min(args.num_envs, os.cpu_count()))
            print(f"curriculum {args.curriculum}: {n} tasks of suite {suite or 'train'} ready ({time.time() - start:.0f} s)",
                  flush=True)
    print(f"starting {args.num_envs} training and {args.num_eval_envs} evaluation envs "
          f"({'one process each' if args.sim_backend == 'cpu' and args.vector_env != 'maniskill' else 'batched'}) ...",
          flush=True)
    envs = make_envs(args, args.num_envs, args.task_suite, device, ignore_terminations=not args.partial_reset)
    eval_envs = make_envs(args, args.num_eval_envs, args.eval_task_suite, device, ignore_terminations=False)
    obs_dim = int(np.prod(envs.single_observation_space.shape))
    act_dim = int(np.prod(envs.single_action_space.shape))
    agent = Agent(obs_dim, act_dim, args.hidden, args.points if args.obs == "pointcloud" else 0).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=args.learning_rate, eps=1e-5)
    state = {"iteration": 0, "global_step": 0, "wall_s": 0.0, "best_success": -1.0}
    if args.resume and ckpt_path.exists():
        ckpt = torch.load(ckpt_path, map_location=device, weights_only=False)
        agent.load_state_dict(ckpt["agent"])
        optimizer.load_state_dict(ckpt["optimizer"])
        state = ckpt["state"]
        print(f"resumed from {ckpt_path} at step {state['global_step']}", flush=True)
    elif ckpt_path.exists():
        ckpt_path.unlink()
        for name in ("train.csv", "eval.csv"):
            (out / name).unlink(missing_ok=True)
    (out / "args.json").write_text(json.dumps(asdict(args), indent=1) + "\n")
    train_log, eval_log = CSVLog(out / "train.csv", TRAIN_FIELDS), CSVLog(out / "eval.csv", EVAL_FIELDS)
    tb = tensorboard_writer(args, out)
    wall_before = state["wall_s"]

    obs_buf = torch.zeros((args.num_steps, args.num_envs, obs_dim), device=device)
    actions = torch.zeros((args.num_steps, args.num_envs, act_dim), device=device)
    logprobs = torch.zeros((args.num_steps, args.num_envs), device=device)
    rewards = torch.zeros((args.num_steps, args.num_envs), device=device)
    dones = torch.zeros((args.num_steps, args.num_envs), device=device)
    values = torch.zeros((args.num_steps, args.num_envs), device=device)
    final_values = torch.zeros((args.num_steps, args.num_envs), device=device)
    action_low = torch.as_tensor(envs.single_action_space.low, device=device)
    action_high = torch.as_tensor(envs.single_action_space.high, device=device)

    # A resumed run continues with fresh episodes from a seed it has not used.
    next_obs, _ = envs.reset(seed=args.seed + 1000 * state["iteration"])
    next_done = torch.zeros(args.num_envs, device=device)
    # The training budget starts now: start-up (curriculum tasks, env workers, the first
    # reset) does not count against --time-limit.
    train_start, first_iteration = time.time(), state["iteration"]
    print(f"envs ready ({train_start - start:.0f} s); training iterations {first_iteration + 1} .. {num_iterations} "
          f"({batch_size} steps each)" + (f", for {args.time_limit:.0f} s" if args.time_limit else ""), flush=True)

    def wall() -> float:
        return wall_before + time.time() - start

    def run_eval():
        metrics = evaluate(agent, eval_envs, args.num_eval_episodes, seed=10**6 + args.seed)
        row = {"iteration": state["iteration"], "global_step": state["global_step"], "wall_s": wall(), **metrics}
        eval_log.write(row)
        if tb:
            for k, v in metrics.items():
                tb.add_scalar(f"eval/{k}", v, state["global_step"])
        print(f"eval @ {state['global_step']}: success {metrics['success_once']:.3f} return {metrics['return']:.2f}",
              flush=True)
        return metrics

    stopped_by_time = False
    while state["iteration"] < num_iterations:
        if args.time_limit and time.time() - train_start > args.time_limit and state["iteration"] > first_iteration:
            stopped_by_time = True
            break
        iteration_start = time.time()
        if args.anneal_lr:
            optimizer.param_groups[0]["lr"] = args.learning_rate * (1.0 - state["iteration"] / num_iterations)
        final_values.zero_()
        ended: dict[str, list] = {"return": [], "success_once": [], "episode_len": [], "reward": []}
        agent.eval()
        for step in range(args.num_steps):
            obs_buf[step], dones[step] = next_obs, next_done
            with torch.no_grad():
                action, logprob, _, value = agent.get_action_and_value(next_obs)
            values[step], actions[step], logprobs[step] = value.flatten(), action, logprob
            next_obs, reward, terminations, truncations, info = envs.step(torch.clamp(action, action_low, action_high))
            next_done = torch.logical_or(terminations, truncations).float()
            rewards[step] = reward.view(-1) * args.reward_scale
            if "final_info" in info:
                mask = info["_final_info"]
                for key in ended:
                    value = info["final_info"]["episode"].get(key)
                    if value is not None:
                        ended[key] += value[mask].float().cpu().tolist()
                bootstrap = mask if args.bootstrap_at_done == "always" else (mask & truncations.bool())
                if bootstrap.any():
                    with torch.no_grad():
                        idx = torch.arange(args.num_envs, device=device)[bootstrap]
                        final_values[step, idx] = agent.get_value(info["final_observation"][bootstrap]).view(-1)
        state["global_step"] += batch_size

        # Generalised advantage estimation; an ended episode's next value is its final
        # observation's (final_values), not the reset observation's.
        with torch.no_grad():
            next_value = agent.get_value(next_obs).reshape(1, -1)
            advantages = torch.zeros_like(rewards)
            lastgaelam = 0
            for t in reversed(range(args.num_steps)):
                if t == args.num_steps - 1:
                    next_not_done, nextvalues = 1.0 - next_done, next_value
                else:
                    next_not_done, nextvalues = 1.0 - dones[t + 1], values[t + 1]
                real_next_values = next_not_done * nextvalues + final_values[t]
                delta = rewards[t] + args.gamma * real_next_values - values[t]
                advantages[t] = lastgaelam = delta + args.gamma * args.gae_lambda * next_not_done * lastgaelam
            returns = advantages + values

        b_obs, b_logprobs = obs_buf.reshape(-1, obs_dim), logprobs.reshape(-1)
        b_actions, b_advantages = actions.reshape(-1, act_dim), advantages.reshape(-1)
        b_returns, b_values = returns.reshape(-1), values.reshape(-1)
        agent.train()
        b_inds = np.arange(batch_size)
        clipfracs = []
        for _ in range(args.update_epochs):
            np.random.shuffle(b_inds)
            for begin in range(0, batch_size, minibatch_size):
                mb = b_inds[begin: begin + minibatch_size]
                _, newlogprob, entropy, newvalue = agent.get_action_and_value(b_obs[mb], b_actions[mb])
                logratio = newlogprob - b_logprobs[mb]
                ratio = logratio.exp()
                with torch.no_grad():
                    approx_kl = ((ratio - 1) - logratio).mean()
                    clipfracs.append(((ratio - 1.0).abs() > args.clip_coef).float().mean().item())
                if args.target_kl is not None and approx_kl > args.target_kl:
                    break
                mb_adv = b_advantages[mb]
                if args.norm_adv:
                    mb_adv = (mb_adv - mb_adv.mean()) / (mb_adv.std() + 1e-8)
                pg_loss = torch.max(-mb_adv * ratio, -mb_adv * torch.clamp(ratio, 1 - args.clip_coef,
                                                                          1 + args.clip_coef)).mean()
                newvalue = newvalue.view(-1)
                if args.clip_vloss:
                    v_clipped = b_values[mb] + torch.clamp(newvalue - b_values[mb], -args.clip_coef, args.clip_coef)
                    v_loss = 0.5 * torch.max((newvalue - b_returns[mb]) ** 2, (v_clipped - b_returns[mb]) ** 2).mean()
                else:
                    v_loss = 0.5 * ((newvalue - b_returns[mb]) ** 2).mean()
                entropy_loss = entropy.mean()
                loss = pg_loss - args.ent_coef * entropy_loss + v_loss * args.vf_coef
                optimizer.zero_grad()
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), args.max_grad_norm)
                optimizer.step()
            if args.target_kl is not None and approx_kl > args.target_kl:
                break
        # The observation statistics move only between iterations, so the rollout and its
        # update saw the same normalisation (the ratios start at 1).
        agent.obs_rms.update(b_obs[:, : agent.state_dim])
        state["iteration"] += 1

        row = {"iteration": state["iteration"], "global_step": state["global_step"], "wall_s": wall(),
               "sps": batch_size / (time.time() - iteration_start), "episodes": len(ended["return"]),
               "return": float(np.mean(ended["return"])) if ended["return"] else "",
               "success_once": float(np.mean(ended["success_once"])) if ended["success_once"] else "",
               "episode_len": float(np.mean(ended["episode_len"])) if ended["episode_len"] else "",
               "reward_per_step": rewards.mean().item(), "value_loss": v_loss.item(), "policy_loss": pg_loss.item(),
               "entropy": entropy_loss.item(), "approx_kl": approx_kl.item(), "clipfrac": float(np.mean(clipfracs)),
               "learning_rate": optimizer.param_groups[0]["lr"]}
        train_log.write(row)
        if tb:
            for k, v in row.items():
                if v != "":
                    tb.add_scalar(f"train/{k}", v, state["global_step"])
        print(f"iter {state['iteration']} step {state['global_step']} sps {row['sps']:.0f} "
              f"return {row['return'] if row['return'] == '' else round(row['return'], 2)} "
              f"success {row['success_once']}", flush=True)
        if args.eval_freq and state["iteration"] % args.eval_freq == 0:
            run_eval()
            state["wall_s"] = wall()
            save_checkpoint(ckpt_path, agent, optimizer, state, args)

    trained = state["iteration"] - first_iteration
    final = None if stopped_by_time else run_eval()
    state["wall_s"] = wall()
    save_checkpoint(ckpt_path, agent, optimizer, state, args)
    train_log.close()
    eval_log.close()
    if tb:
        tb.close()
    envs.close()
    eval_envs.close()
    print(("stopped at the time limit" if stopped_by_time else "done")
          + f" after {trained} iterations ({trained * batch_size} steps, {time.time() - train_start:.0f} s of training)"
          + f"; now at iteration {state['iteration']} of {num_iterations}; checkpoint {ckpt_path}", flush=True)
    return {"state": state, "final_eval": final, "stopped_by_time": stopped_by_time, "trained_iterations": trained}


if __name__ == "__main__":
    result = main(ARGS)
    # A run that trained nothing did not do what it was asked: say so (above) and fail.
    sys.exit(0 if result["trained_iterations"] > 0 else 1)
