"""Does the dense reward rank behaviour? Returns of expert demos, perturbed demos, a
random and an idle policy on the same tasks, and a figure of the reward per stage
along one demonstration (docs/rl.md).

- expert: the recorded trajectories' pd_joint_pos actions replayed from their reset
  kwargs (``fetchbench_ms.demos.returns.demo_rollout``), then the last action held to
  ``--horizon`` steps;
- noised: the same with the arm's joint targets perturbed (per-episode offset N(0, s)
  plus per-step N(0, s/2), rad) for each s of ``--noise``: worse demonstrators, some of
  which fail;
- random: uniform pd_joint_delta_pos actions; idle: zero pd_joint_delta_pos actions
  (the arm holds its start), both for ``--horizon`` steps on the demos' tasks.

Prints and writes (``--out``, JSON) the mean return of each, the success rates, the
correlation of return with success at the end across expert and noised rollouts
(point-biserial, i.e. Pearson with success as 0/1) and the fraction of tasks where the
expert's return beats the random and the idle policy's.

    PYTHONPATH=. python scripts/bench/bench_reward.py --count 10 --noise 0.005 0.01 0.02 \\
        --out build/bench-reward.json --png docs/img/rl_reward_stages.png
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from fetchbench_ms.demos.returns import TERM_NAMES, demo_rollout, load_demos, make_env, policy_rollout
from fetchbench_ms.envs.fetchbench import CONTACT_PENALTY, DENSE_REWARD_MAX, DISTURB_PENALTY, REWARD_WEIGHTS
from fetchbench_ms.utils.io import atomic_write_text

SAMPLE = Path(__file__).resolve().parents[2] / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"


def _summary(rollouts) -> dict:
    returns = np.array([r.ret for r in rollouts])
    return {"n": len(rollouts), "mean_return": round(float(returns.mean()), 2),
            "std_return": round(float(returns.std()), 2),
            "success_at_end": round(float(np.mean([r.success_at_end for r in rollouts])), 3)}


def plot_stages(rollout, title: str, png: Path) -> None:
    """Stacked weighted stages along one demo, the reward on top, penalties and success below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(len(rollout.rewards))
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8, 5.2), sharex=True, height_ratios=(3, 1))
    stacked = [REWARD_WEIGHTS[n] * rollout.terms[n] for n in REWARD_WEIGHTS]
    ax.stackplot(t, stacked, labels=[f"{n} (x{REWARD_WEIGHTS[n]:g})" for n in REWARD_WEIGHTS], alpha=0.75)
    ax.plot(t, rollout.rewards, color="k", lw=1.5, label="dense reward")
    ax.axvline(rollout.recorded_steps - 0.5, color="grey", ls="--", lw=1)
    ax.text(rollout.recorded_steps + 2, 0.3, "demo ends; last action held", color="grey", fontsize=8)
    ax.set_ylim(0, DENSE_REWARD_MAX * 1.05)
    ax.set_ylabel("reward")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", fontsize=7, ncol=2)
    ax2.plot(t, rollout.terms["disturb"], label=f"disturb (x{DISTURB_PENALTY:g} off)")
    ax2.plot(t, rollout.terms["contact"], label=f"robot-furniture contact (x{CONTACT_PENALTY:g} off)")
    ax2.fill_between(t, 0, rollout.success.astype(float), color="g", alpha=0.15, step="mid", label="success")
    ax2.set_ylim(-0.05, 1.05)
    ax2.set_xlabel("control step (20 Hz)")
    ax2.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    png.parent.mkdir(parents=True, exist_ok=True)
    tmp = png.with_name(png.stem + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    tmp.replace(png)
    plt.close(fig)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--demos", type=Path, default=SAMPLE, help="a trajectory .h5 with its .json")
    p.add_argument("--count", type=int, default=10, help="first N trajectories")
    p.add_argument("--noise", type=float, nargs="*", default=[0.005, 0.01, 0.02], help="perturbation scales, rad")
    p.add_argument("--horizon", type=int, default=300, help="steps per rollout (demos then hold their last action)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--figure-traj", type=int, default=0, help="which trajectory the figure shows")
    p.add_argument("--png", type=Path, default=None)
    p.add_argument("--out", type=Path, default=None, help="JSON of the figures")
    args = p.parse_args(argv)
    if args.count < 2:
        p.error("--count must be >= 2 (a correlation needs several rollouts)")

    start = time.time()
    env_info, episodes = load_demos(args.demos)
    episodes = episodes[: args.count]
    rng = np.random.default_rng(args.seed)
    env = make_env(env_info)
    expert = [demo_rollout(env, args.demos, e, args.horizon) for e in episodes]
    noised = {s: [demo_rollout(env, args.demos, e, args.horizon, action_noise=s, rng=rng) for e in episodes]
              for s in args.noise}
    env.close()
    env = make_env(env_info, control_mode="pd_joint_delta_pos")
    dim = env.action_space.shape[-1]
    random_runs = [policy_rollout(env, e["reset_kwargs"], lambda t: rng.uniform(-1, 1, dim), args.horizon)
                   for e in episodes]
    idle = [policy_rollout(env, e["reset_kwargs"], lambda t: np.zeros(dim), args.horizon) for e in episodes]
    env.close()

    pooled = expert + [r for runs in noised.values() for r in runs]
    returns = np.array([r.ret for r in pooled])
    success = np.array([r.success_at_end for r in pooled], dtype=float)
    corr = float(np.corrcoef(returns, success)[0, 1]) if 0 < success.mean() < 1 else None
    result = {
        "demos": str(args.demos), "count": len(episodes), "horizon": args.horizon, "seed": args.seed,
        "expert": _summary(expert),
        "noised": {str(s): _summary(runs) for s, runs in noised.items()},
        "random": _summary(random_runs),
        "idle": _summary(idle),
        "expert_beats_random": round(float(np.mean([e.ret > r.ret for e, r in zip(expert, random_runs)])), 3),
        "expert_beats_idle": round(float(np.mean([e.ret > r.ret for e, r in zip(expert, idle)])), 3),
        "return_success_correlation": None if corr is None else round(corr, 3),
        "pooled_rollouts": len(pooled), "pooled_success": round(float(success.mean()), 3),
        "mean_return_success": round(float(returns[success == 1].mean()), 2) if success.any() else None,
        "mean_return_failure": round(float(returns[success == 0].mean()), 2) if (success == 0).any() else None,
        "expert_end_reward": [round(float(r.rewards[r.recorded_steps - 1]), 3) for r in expert],
        "expert_end_success": [bool(r.success[r.recorded_steps - 1]) for r in expert],
        "wall_s": round(time.time() - start, 1),
    }
    print(json.dumps(result, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.out, json.dumps(result, indent=1) + "\n")
    if args.png:
        k = args.figure_traj if args.figure_traj < len(expert) else 0
        e = episodes[k]
        plot_stages(expert[k], f"dense reward per stage: demo traj_{e['episode_id']} ({e['task_id']}, "
                    f"{e['scene_type']}, {e['category']}); return {expert[k].ret:.0f} over {args.horizon} steps",
                    args.png)
    return result


if __name__ == "__main__":
    main()
