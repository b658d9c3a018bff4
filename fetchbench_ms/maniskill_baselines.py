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
  env that did not end), which is what those ``evaluate()`` read on the CPU.

The demos: ``python -m fetchbench_ms.replay_trajectory --traj-path DEMO.h5 -o state -c
pd_joint_delta_pos --save-traj``. What the scripts import beyond this package (tensorboard,
diffusers; wandb with ``--track``) is the ``[baselines]`` extra. ACT imports torchvision too,
which must be the build made for the installed torch (a torchvision from the package index
is built against CUDA torch and does not load beside torch's CPU build); a missing package or
a torchvision of another build ends in one line that gives the pip command. docs/maniskill-baselines.md
has the commands and their times.
"""
from __future__ import annotations

import importlib.metadata
import os
import re
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


# What the scripts import beyond this package that the [baselines] extra installs.
EXTRA_MODULES = ("tensorboard", "diffusers", "wandb")


def _installed(name: str) -> str:
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return "(not installed)"


def torchvision_install_command(replace: bool = False) -> str:
    """The pip command for the torchvision build made for the installed torch: torchvision
    0.(m+15).p pairs with torch 2.m.p, and torch's local tag (``+cpu``, ``+cu130``) names the
    PyTorch index of its build; without one (the package index's torch) the package index.
    ``replace``: over a torchvision of another build (its dependencies left as they are)."""
    torch_version = _installed("torch")
    base, _, local = torch_version.partition("+")
    m = re.match(r"2\.(\d+)\.(\d+)", base)
    if not m:
        return f"pip install the torchvision release made for torch {torch_version}"
    pip = "pip install --force-reinstall --no-deps" if replace else "pip install"
    pin = f"torchvision==0.{int(m.group(1)) + 15}.{m.group(2)}"
    if local:
        return f'{pip} "{pin}+{local}" --index-url https://download.pytorch.org/whl/{local}'
    return f'{pip} "{pin}"'


def missing_dependency_message(exc: BaseException, script: str) -> str | None:
    """One line naming the package a script could not import and the pip command that
    installs it, or None when ``exc`` is not such a failure."""
    if isinstance(exc, ModuleNotFoundError) and exc.name:
        top = exc.name.split(".")[0]
        if top in EXTRA_MODULES:
            return (f'{script} imports {top}, which is not installed: pip install "fetchbench_ms[baselines]" '
                    f'(in a checkout: pip install -e ".[baselines]")')
        if top == "torchvision":
            return (f"{script} imports torchvision, which is not installed; the build made for torch "
                    f"{_installed('torch')}: {torchvision_install_command()}")
    if isinstance(exc, RuntimeError) and "torchvision::" in str(exc):
        return (f"torchvision {_installed('torchvision')} is not built for the installed torch "
                f"{_installed('torch')} (its operators do not load: {exc}); the build made for it: "
                f"{torchvision_install_command(replace=True)}")
    return None


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
    try:
        runpy.run_path(script, run_name="__main__")
    except (ImportError, RuntimeError) as exc:
        message = missing_dependency_message(exc, os.path.join(*script.split(os.sep)[-2:]))
        if message is None:
            raise
        print(f"maniskill_baselines: error: {message}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
