"""ManiSkill's example baselines (``examples/baselines/{bc,diffusion_policy,act}`` of the
ManiSkill repository) on FetchBench demos, run as a ManiSkill user runs them:

    python -m fetchbench_ms.maniskill_baselines PATH/TO/ManiSkill/examples/baselines/bc/bc.py \\
        --env-id FetchBench-v0 --demo-path demos/...state.pd_joint_delta_pos.physx_cpu.h5 \\
        --control-mode pd_joint_delta_pos --sim-backend cpu --num-eval-envs 1 ...

The script runs unchanged, as ``python SCRIPT ARGS`` would run it (its folder first on
``sys.path``, ``__main__``), after two things that ManiSkill's own entry point cannot do:

- ``import fetchbench_ms``, so ``gym.make("FetchBench-v0")`` knows the ids (ManiSkill 3.0.1
  has no plugin entry point, gymnasium 1.x none either); this module is what the
  evaluation's worker processes import first too;
- gymnasium >= 1.0's CPU vector envs no longer put ``final_info`` in ``info`` (their default
  autoreset is NEXT_STEP), and ManiSkill's ``evaluate()`` of those baselines reads
  ``info["final_info"]`` at every episode end (``KeyError: 'final_info'``, on ManiSkill's own
  PickCube-v1 too). Within this launcher ``gymnasium.vector.SyncVectorEnv`` and
  ``AsyncVectorEnv`` reset a finished env in the same step (``AutoresetMode.SAME_STEP``) and
  give ``final_info`` as gymnasium 0.29 did, a list with one dict per env (``None`` for an
  env that did not end), which both the ManiSkill 3.0.1 and the later ``evaluate()`` read.

The demos: ``python -m fetchbench_ms.replay_trajectory --traj-path DEMO.h5 -o state -c
pd_joint_delta_pos --save-traj`` (docs/imitation.md). What the scripts import beyond this
package (tensorboard, diffusers, torchvision, wandb) is the ``[baselines]`` extra.
"""
from __future__ import annotations

import os
import runpy
import sys

import numpy as np

import fetchbench_ms  # noqa: F401  (registers FetchBench-*-v0, here and in spawned workers)


def _env_entry(tree, i: int):
    """Env ``i``'s part of a vectorised info tree (masks, the ``_``-keys, left out)."""
    if isinstance(tree, dict):
        return {k: _env_entry(v, i) for k, v in tree.items() if not k.startswith("_")}
    try:
        return tree[i]
    except (TypeError, IndexError, KeyError):
        return tree


def final_info_per_env(info: dict, num_envs: int) -> dict:
    """``info`` with a SAME_STEP vector env's ``final_info`` (a vectorised dict with the
    ``_final_info`` mask) as a list of per-env dicts (``None`` where no episode ended)."""
    final = info.get("final_info")
    if not isinstance(final, dict):
        return info
    ended = np.asarray(info.get("_final_info", np.ones(num_envs, dtype=bool)), dtype=bool)
    return {**info, "final_info": [_env_entry(final, i) if ended[i] else None for i in range(num_envs)]}


class ImportPluginFirst:
    """An env factory that imports this package before it makes the env: a vector env's
    worker processes (forkserver / spawn) import the script, not this launcher, and would not
    know the FetchBench ids otherwise. Pickled by reference, so unpickling imports it."""

    def __init__(self, env_fn):
        self.env_fn = env_fn

    def __call__(self):
        import fetchbench_ms  # noqa: F401

        return self.env_fn()


def _final_info_vector_env(base):
    """A subclass of gymnasium vector env ``base`` with SAME_STEP autoreset and ``final_info``
    per env (``final_info_per_env``)."""
    import gymnasium as gym

    class FinalInfoVectorEnv(base):
        def __init__(self, env_fns, *args, **kwargs):
            kwargs.setdefault("autoreset_mode", gym.vector.AutoresetMode.SAME_STEP)
            super().__init__([ImportPluginFirst(fn) for fn in env_fns], *args, **kwargs)

        def step(self, actions):
            obs, reward, terminated, truncated, info = super().step(actions)
            return obs, reward, terminated, truncated, final_info_per_env(info, self.num_envs)

    FinalInfoVectorEnv.__name__ = FinalInfoVectorEnv.__qualname__ = base.__name__
    return FinalInfoVectorEnv


def install_final_info_compat() -> None:
    """Replace ``gymnasium.vector.SyncVectorEnv`` / ``AsyncVectorEnv`` in this process (gymnasium
    >= 1.0 only; 0.29 gives ``final_info`` itself). Idempotent."""
    import gymnasium as gym

    if not hasattr(gym.vector, "AutoresetMode"):
        return
    for name in ("SyncVectorEnv", "AsyncVectorEnv"):
        cls = getattr(gym.vector, name)
        if not getattr(cls, "_fetchbench_final_info", False):
            compat = _final_info_vector_env(cls)
            compat._fetchbench_final_info = True
            setattr(gym.vector, name, compat)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0 if argv else 2
    script = os.path.abspath(argv[0])
    if not os.path.isfile(script) or not script.endswith(".py"):
        print(f"maniskill_baselines: error: {argv[0]} is not a Python file; valid: a training script of ManiSkill's "
              "examples/baselines (bc/bc.py, diffusion_policy/train.py, act/train.py)", file=sys.stderr)
        return 2
    install_final_info_compat()
    sys.argv = [script, *argv[1:]]
    sys.path.insert(0, os.path.dirname(script))  # as `python SCRIPT` puts its folder first
    runpy.run_path(script, run_name="__main__")
    return 0


if __name__ == "__main__":
    sys.exit(main())
