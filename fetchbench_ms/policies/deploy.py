"""The imitation methods of ``fetchbench eval``: end-to-end and hybrid (CGN + planner + policy).

- ``e2e-mlp`` / ``e2e-transformer`` / ``e2e-diffusion`` / ``e2e-act``: the policy drives the
  whole fetch through the re-grasp state machine (``agent.ReGraspStateMachine``), then
  FetchBench's 10 s settle-and-hold judges; ``twostage-*``: the same without re-grasping (the
  paper's TwoStageImit);
- ``cgn-imit-mlp`` / ``cgn-imit-transformer`` / ``cgn-imit-diffusion`` / ``cgn-imit-act`` (the paper's
  CGN-CuRobo-Imit): the sense-plan-act pipeline (Contact-GraspNet grasps on the observed
  target, the point-cloud world, the planner to the pre-grasp, the straight approach, the
  gripper closing) and then the policy retrieves (``SolveConfig.retrieval``).

The methods and their policy kinds are ``method_spec``'s (one row of ``POLICY_KINDS`` each);
the runners here read a resolved ``RunSpec`` and look no name up. Each loads its checkpoint from ``assets/checkpoints/imit_<kind>.pt`` (``default_checkpoint``; shipped
packed as ``imit_<kind>.pt.planes.xz``, ``utils.packed``, which is read when no plain ``.pt`` is there)
or from the one given (``fetchbench eval --policy-checkpoint PATH``); its policy observes every
control step, or every K-th with ``--policy-stride K`` (``ImitationPolicy``). Policies speak
``pd_joint_delta_pos``; the evaluation env drives ``pd_joint_pos`` (as the planners do), so a
delta is sent as the target qpos + 0.1 rad x action, which is what ManiSkill's
``pd_joint_delta_pos`` controller (targets from the current qpos) does with it.
"""
from __future__ import annotations

import functools
import os
import time
from pathlib import Path

import numpy as np

from ..envs.pointcloud import COMPACT_OBS_MODE, COMPOSED_OBS_MODE
from ..method_spec import MethodSpec, RunSpec
from ..utils.paths import assets_root
from .agent import RETRIEVE, ImitationPolicy, ReGraspConfig
from .data import ARM_DELTA_SCALE, ARM_DOF

MAX_POLICY_STEPS = 600  # 30 s at 20 Hz: a demo takes ~200, re-grasps take more
MAX_RETRIEVE_STEPS = 300


def default_checkpoint(kind: str) -> Path:
    return assets_root() / "checkpoints" / f"imit_{kind}.pt"


def policy_obs_mode(method: MethodSpec, checkpoint: str | None = None) -> str:
    """The env obs mode of a policy method: the one its checkpoint was trained on for the
    end-to-end methods (``compact_pointcloud``, ``policy_pointcloud`` or ``composed_pointcloud``); for the hybrids, the raw
    cloud CGN needs (made compact per step for a ``compact_pointcloud`` policy; a
    ``composed_pointcloud`` one reads the env's composed points, ``run_hybrid``)."""
    from .agent import checkpoint_obs_mode

    trained_on = checkpoint_obs_mode(resolve_checkpoint(method, checkpoint))
    if method.family == "hybrid":
        if trained_on not in (COMPACT_OBS_MODE, COMPOSED_OBS_MODE):
            raise ValueError(f"{method.name} reads the 320x240 point cloud CGN grasps on and makes it compact for the "
                             f"policy; its checkpoint was trained on {trained_on} observations: use an "
                             f"end-to-end method, or a {COMPACT_OBS_MODE} or {COMPOSED_OBS_MODE} checkpoint")
        return "pointcloud"
    return trained_on


def resolve_checkpoint(method: MethodSpec, checkpoint: str | None = None) -> Path:
    """The checkpoint file a policy method loads (``X.pt``, or its packed copy
    ``X.pt.planes.xz`` when only that exists); a clear error naming the trainer when absent."""
    from ..utils.packed import packed_or_plain

    kind = method.policy
    if kind is None:
        raise ValueError(f"{method.name} runs no learned policy")
    path = packed_or_plain(Path(checkpoint) if checkpoint else default_checkpoint(kind.name))
    if not path.is_file():
        raise FileNotFoundError(
            f"{method.name}: no policy checkpoint at {path}. Train one with `python {kind.trainer} --data "
            f"CONVERTED_DIR --run RUN --export` (docs/imitation.md) and pass --policy-checkpoint "
            f"RUN/export/imit_{kind.name}.pt")
    return path


def _load_model(method: MethodSpec, path: Path, device: str = "cpu"):
    """The checkpoint's network, built as the method's policy kind, and its meta (ValueError:
    a truncated copy, another file, another kind's policy)."""
    from .agent import CheckpointKindError, load_model

    try:
        return load_model(path, device, kind=method.policy)
    except CheckpointKindError as error:
        raise ValueError(f"{method.name} {error}") from None


def check_checkpoint(method: MethodSpec, checkpoint: str | None = None) -> Path:
    """``resolve_checkpoint``, and the file loads as a policy of the method's kind."""
    path = resolve_checkpoint(method, checkpoint)
    _load_model(method, path)
    return path


@functools.lru_cache(maxsize=None)
def _sha256(path: str) -> str:
    from ..utils.packed import content_sha256

    return content_sha256(path)


@functools.lru_cache(maxsize=None)
def _obs_mode(path: str) -> str:
    from .agent import checkpoint_obs_mode

    return checkpoint_obs_mode(path)


def checkpoint_fields(method: MethodSpec, checkpoint: str | None = None) -> dict:
    """What a record says of the policy it ran: the checkpoint's path, the sha256 of its
    ``.pt`` bytes (unpacked: the shipped checkpoint's JSON names the val runs made with
    exactly these bytes) and the obs mode it reads."""
    path = resolve_checkpoint(method, checkpoint)
    return {"checkpoint": str(path), "checkpoint_sha256": _sha256(str(path.resolve())),
            "policy_obs_mode": _obs_mode(str(path.resolve()))}


def load_policy(method: MethodSpec, checkpoint: str | None = None, device: str | None = None, stride: int = 1,
                **kwargs) -> ImitationPolicy:
    """``stride``: control steps per observation (``ImitationPolicy``); ``kwargs``: its other options."""
    import torch

    path = resolve_checkpoint(method, checkpoint)
    device = device or os.environ.get("FETCHBENCH_POLICY_DEVICE") or ("cuda" if torch.cuda.is_available() else "cpu")
    model, meta = _load_model(method, path, device)
    return ImitationPolicy(model, meta, device, stride=stride, **kwargs)


def env_action(env, action: np.ndarray) -> np.ndarray:
    """A policy's ``pd_joint_delta_pos`` action for the env's controller (that mode, or
    ``pd_joint_pos``: target = current arm qpos + 0.1 rad x the clipped delta)."""
    mode = env.unwrapped.agent.control_mode
    if mode == "pd_joint_delta_pos":
        return action
    if mode != "pd_joint_pos":
        raise ValueError(f"imitation policies drive pd_joint_delta_pos or pd_joint_pos; the env uses {mode!r}")
    qpos = env.unwrapped.agent.robot.get_qpos()[0].cpu().numpy()
    out = action.copy()
    out[:, :ARM_DOF] = qpos[:ARM_DOF] + ARM_DELTA_SCALE * np.clip(action[:, :ARM_DOF], -1, 1)
    return out


def step_unobserved(env, action: np.ndarray) -> None:
    """One control step without the observation ``env.step`` would render (the cameras' cloud
    costs far more than the simulation): its simulation part, as the sense-plan-act executor
    steps."""
    u = env.unwrapped
    u._step_action(action)
    u._elapsed_steps += 1


def composed_observation(env) -> dict:
    """What a ``composed_pointcloud`` policy reads, from an env of another camera mode (a
    hybrid's): the joints and ``env.composed_pointcloud_obs()`` (no render; the episode's
    start was taken by its first call)."""
    u = env.unwrapped
    return {"agent": {"qpos": u.agent.robot.get_qpos()}, "pointcloud": u.composed_pointcloud_obs()}


def run_policy(env, policy: ImitationPolicy, max_steps: int, on_step=None, observe=None) -> dict:
    """Step ``env`` with ``policy`` until it is done or ``max_steps``; returns what it did.
    The observation is rendered only at the steps the policy reads it (``begin_step``);
    ``on_step(action [8])`` steps the env instead of ``step_unobserved`` (the hybrids' executor);
    ``observe(env)`` gives the observation instead of the env's ``get_obs``."""
    u = env.unwrapped
    observe = observe or (lambda env: env.unwrapped.get_obs(unflattened=True))
    qpos_last = u.agent.robot.get_qpos()[0].cpu().numpy().astype(float)
    cspace, steps, grasped, observations = 0.0, 0, False, 0
    for steps in range(1, max_steps + 1):
        obs = None
        if policy.begin_step(qpos_last):
            obs = observe(env)
            observations += 1
        action = env_action(env, policy.act(obs))
        if on_step is not None:
            on_step(action[0])
        else:
            step_unobserved(env, action)
        qpos = u.agent.robot.get_qpos()[0].cpu().numpy().astype(float)
        cspace += float(np.abs(qpos - qpos_last).sum())
        qpos_last = qpos
        if policy.machine.phase == RETRIEVE and not grasped:  # held the target after some closing
            grasped = bool(u.agent.is_grasping(u.target)[0])
        if policy.done:
            break
    return {"steps": steps, "cspace_length": cspace, "inference_time": policy.inference_time, "grasped": grasped,
            "regrasps": policy.machine.regrasps, "phase_log": [list(t) for t in policy.machine.log],
            "final_phase": policy.machine.phase, "observations": observations}


def run_e2e(env, seed: int, run: RunSpec, max_steps: int = MAX_POLICY_STEPS) -> dict:
    """One end-to-end episode on an env already reset to its task (the policy re-grasps if
    its method does: ``e2e-*``, not ``twostage-*``); FetchBench's judge after."""
    from ..envs.judging import judge

    method, checkpoint = run.method, run.policy_checkpoint
    policy = load_policy(method, checkpoint, stride=run.policy_stride,
                         regrasp=ReGraspConfig(regrasp=method.regrasp))
    policy.reset(episode_seed=seed)
    t = time.perf_counter()
    did = run_policy(env, policy, max_steps)
    verdict = judge(env)
    return {
        "method": method.name,
        "success": verdict.success,
        "failure": verdict.failure,
        "computation_time": round(did["inference_time"], 4),
        "cspace_length": round(did["cspace_length"], 4),
        # The funnel's stages (evaluation.metrics.FUNNEL) an end-to-end policy has: it plans
        # nothing, so no plan stage; "retrieved": its retrieval ran to its end (termination).
        "phases": {"approach_reached": any(to == "close" for _, _, to in did["phase_log"]),
                   "grasped": did["grasped"], "retrieved": did["final_phase"] == "done",
                   "held_at_end": verdict.held_at_end},
        "regrasps": did["regrasps"],
        "policy_steps": did["steps"],
        "policy_stride": policy.stride,
        "observations": did["observations"],
        "phase_log": did["phase_log"],
        **checkpoint_fields(method, checkpoint),
        "target_moved": verdict.target_moved,
        "max_others_moved": verdict.max_others_moved,
        "wall_time": round(time.perf_counter() - t, 2),
    }


def retrieval_by_policy(policy: ImitationPolicy, seed: int, max_steps: int = MAX_RETRIEVE_STEPS,
                        tally: dict | None = None, observe=None):
    """A ``SolveConfig.retrieval`` callback: after the gripper closed, the policy retrieves
    (steps through the solver's executor, so C-space length and step counts stay its;
    ``run_policy`` renders the observations the policy reads, or calls ``observe``). ``tally``:
    the policy's ``steps`` and ``observations`` are added to it, over every try."""

    def retrieve(env, state, executor) -> str | None:
        u = env.unwrapped
        policy.reset(episode_seed=seed, phase=RETRIEVE)

        def step(action):
            executor.step(action[:ARM_DOF], float(action[ARM_DOF]))

        t = time.perf_counter()
        did = run_policy(env, policy, max_steps, on_step=step, observe=observe)
        if tally is not None:
            for key in ("steps", "observations"):
                tally[key] = tally.get(key, 0) + did[key]
        state.computation_time += did["inference_time"]
        state.notes.append(f"policy retrieval: {did['steps']} steps ({did['observations']} observed), ended "
                           f"{did['final_phase']} ({time.perf_counter() - t:.1f} s)")
        # The policy plans nothing: its stage is "retrieved" (ran to its termination), and the
        # planner's "retrieval_plan" is not a phase of this method.
        state.phases.pop("retrieval_plan", None)
        state.phases["grasped"] = bool(u.agent.is_grasping(u.target)[0])
        state.phases["retrieved"] = did["final_phase"] == "done"
        return None if state.phases["grasped"] else "grasp_failure"

    return retrieve


def run_hybrid(env, seed: int, run: RunSpec) -> dict:
    """The method's planned approach (its grasp source, world and planner, with the run's
    pipeline), then the policy's retrieval."""
    from ..solutions.sense_plan_act import SolveConfig, solve

    method, checkpoint = run.method, run.policy_checkpoint
    policy = load_policy(method, checkpoint, stride=run.policy_stride, regrasp=ReGraspConfig(regrasp=False))
    tally = {"steps": 0, "observations": 0}
    observe = None
    if policy.model.cfg.encoder.obs_mode == COMPOSED_OBS_MODE:
        # The composed points' start is the episode's start, as in training: taken now, before
        # the approach moves anything; the retrieval then composes without rendering.
        env.unwrapped.composed_pointcloud_obs()
        observe = composed_observation
    config = SolveConfig.for_run(run, retrieval=retrieval_by_policy(policy, seed, tally=tally, observe=observe))
    record = solve(env, seed=seed, method=method, retries=run.retries, reset=False, config=config)
    record.update(approach_method=method.approach_method, **checkpoint_fields(method, checkpoint),
                  policy_stride=policy.stride, policy_steps=tally["steps"], observations=tally["observations"])
    return record
