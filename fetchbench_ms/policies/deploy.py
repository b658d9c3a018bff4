"""The imitation methods of ``fetchbench eval``: end-to-end and hybrid (CGN + planner + policy).

- ``e2e-mlp`` / ``e2e-transformer`` / ``e2e-diffusion`` / ``e2e-act``: the policy drives the
  whole fetch through the re-grasp state machine (``agent.ReGraspStateMachine``), then
  FetchBench's 10 s settle-and-hold judges; ``twostage-*``: the same without re-grasping (the
  paper's TwoStageImit);
- ``cgn-imit-mlp`` / ``cgn-imit-transformer`` / ``cgn-imit-diffusion`` / ``cgn-imit-act`` (the paper's
  CGN-CuRobo-Imit): the sense-plan-act pipeline (Contact-GraspNet grasps on the observed
  target, the point-cloud world, the planner to the pre-grasp, the straight approach, the
  gripper closing) and then the policy retrieves (``SolveConfig.retrieval``).

Each loads its checkpoint from ``assets/checkpoints/imit_<kind>.pt`` (``default_checkpoint``; shipped
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
from ..utils.paths import assets_root
from .agent import RETRIEVE, ImitationPolicy, ReGraspConfig
from .data import ARM_DELTA_SCALE, ARM_DOF
from .networks import POLICIES

POLICY_KINDS = tuple(POLICIES)  # mlp, transformer, diffusion, act: the networks the package has
E2E_METHODS = {f"e2e-{kind}": kind for kind in POLICY_KINDS}
#: The paper's TwoStageImit: the same policies without re-grasping (approach, then retrieve).
TWO_STAGE_METHODS = {f"twostage-{kind}": kind for kind in POLICY_KINDS}
HYBRID_METHODS = {f"cgn-imit-{kind}": kind for kind in POLICY_KINDS}
POLICY_METHODS = {**E2E_METHODS, **TWO_STAGE_METHODS, **HYBRID_METHODS}
#: Trainers per policy kind (named in the error when a checkpoint is missing).
TRAINERS = {kind: f"baselines/imitation/train_{kind}.py" for kind in POLICY_KINDS}
MAX_POLICY_STEPS = 600  # 30 s at 20 Hz: a demo takes ~200, re-grasps take more
MAX_RETRIEVE_STEPS = 300


def default_checkpoint(kind: str) -> Path:
    return assets_root() / "checkpoints" / f"imit_{kind}.pt"


def hybrid_approach_method() -> str:
    """The sense-plan-act method the hybrids approach with: CGN grasps in the point-cloud world
    with the trajectory optimiser where that method exists (the paper's CuRobo), else RRTConnect."""
    from ..solutions.sense_plan_act import METHODS

    return "cgn-ptd-trajopt" if "cgn-ptd-trajopt" in METHODS else "cgn-ptd-rrt"


def policy_obs_mode(method: str, checkpoint: str | None = None) -> str:
    """The env obs mode of a policy method: the one its checkpoint was trained on for the
    end-to-end methods (``compact_pointcloud``, ``policy_pointcloud`` or ``composed_pointcloud``); for the hybrids, the raw
    cloud CGN needs (made compact per step for a ``compact_pointcloud`` policy; a
    ``composed_pointcloud`` one reads the env's composed points, ``run_hybrid``)."""
    from .agent import checkpoint_obs_mode

    trained_on = checkpoint_obs_mode(resolve_checkpoint(method, checkpoint))
    if method in HYBRID_METHODS:
        if trained_on not in (COMPACT_OBS_MODE, COMPOSED_OBS_MODE):
            raise ValueError(f"{method} reads the 320x240 point cloud CGN grasps on and makes it compact for the "
                             f"policy; its checkpoint was trained on {trained_on} observations: use an "
                             f"end-to-end method, or a {COMPACT_OBS_MODE} or {COMPOSED_OBS_MODE} checkpoint")
        return "pointcloud"
    return trained_on


def resolve_checkpoint(method: str, checkpoint: str | None = None) -> Path:
    """The checkpoint file a policy method loads (``X.pt``, or its packed copy
    ``X.pt.planes.xz`` when only that exists); a clear error naming the trainer when absent."""
    from ..utils.packed import packed_or_plain

    if method not in POLICY_METHODS:
        raise ValueError(f"unknown imitation method {method!r}; valid: {', '.join(POLICY_METHODS)}")
    kind = POLICY_METHODS[method]
    path = packed_or_plain(Path(checkpoint) if checkpoint else default_checkpoint(kind))
    if not path.is_file():
        raise FileNotFoundError(
            f"{method}: no policy checkpoint at {path}. Train one with `python {TRAINERS[kind]} --data CONVERTED_DIR "
            f"--run RUN --export` (docs/imitation.md) and pass --policy-checkpoint RUN/export/imit_{kind}.pt")
    return path


def check_checkpoint(method: str, checkpoint: str | None = None) -> Path:
    """``resolve_checkpoint``, and the file loads as a policy of the method's kind (ValueError
    otherwise: a truncated copy, another file, another kind's policy)."""
    from .agent import load_model

    path = resolve_checkpoint(method, checkpoint)
    model, _ = load_model(path)
    expected = POLICY_METHODS[method]
    if model.kind != expected:
        raise ValueError(f"{method} needs a {expected} checkpoint; {path} holds a {model.kind} policy")
    return path


@functools.lru_cache(maxsize=None)
def _sha256(path: str) -> str:
    from ..utils.packed import content_sha256

    return content_sha256(path)


@functools.lru_cache(maxsize=None)
def _obs_mode(path: str) -> str:
    from .agent import checkpoint_obs_mode

    return checkpoint_obs_mode(path)


def checkpoint_fields(method: str, checkpoint: str | None = None) -> dict:
    """What a record says of the policy it ran: the checkpoint's path, the sha256 of its
    ``.pt`` bytes (unpacked: the shipped checkpoint's JSON names the val runs made with
    exactly these bytes) and the obs mode it reads."""
    path = resolve_checkpoint(method, checkpoint)
    return {"checkpoint": str(path), "checkpoint_sha256": _sha256(str(path.resolve())),
            "policy_obs_mode": _obs_mode(str(path.resolve()))}


def load_policy(method: str, checkpoint: str | None = None, device: str | None = None, stride: int = 1,
                **kwargs) -> ImitationPolicy:
    """``stride``: control steps per observation (``ImitationPolicy``); ``kwargs``: its other options."""
    import torch

    path = resolve_checkpoint(method, checkpoint)
    device = device or os.environ.get("FETCHBENCH_POLICY_DEVICE") or ("cuda" if torch.cuda.is_available() else "cpu")
    policy = ImitationPolicy.load(path, device, stride=stride, **kwargs)
    expected = POLICY_METHODS[method]
    if policy.model.kind != expected:
        raise ValueError(f"{method} needs a {expected} checkpoint; {path} holds a {policy.model.kind} policy")
    return policy


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


def run_e2e(env, seed: int, method: str, checkpoint: str | None = None, max_steps: int = MAX_POLICY_STEPS,
            regrasp: bool = True, stride: int = 1) -> dict:
    """One end-to-end episode on an env already reset to its task; FetchBench's judge after."""
    from ..envs import settle_and_hold
    from ..solutions.sense_plan_act import final_failure

    policy = load_policy(method, checkpoint, stride=stride, regrasp=ReGraspConfig(regrasp=regrasp))
    policy.reset(episode_seed=seed)
    t = time.perf_counter()
    did = run_policy(env, policy, max_steps)
    info = settle_and_hold(env)
    u = env.unwrapped
    success = bool(info["success"][0])
    held = bool(u.agent.is_grasping(u.target)[0])
    failure = None
    if not success:
        failure = final_failure(None, held_at_end=held, others_undisturbed=bool(info["others_undisturbed"][0]))
    return {
        "method": method,
        "success": success,
        "failure": failure,
        "computation_time": round(did["inference_time"], 4),
        "cspace_length": round(did["cspace_length"], 4),
        # The funnel's stages (evaluation.metrics.FUNNEL) an end-to-end policy has: it plans
        # nothing, so no plan stage; "retrieved": its retrieval ran to its end (termination).
        "phases": {"approach_reached": any(to == "close" for _, _, to in did["phase_log"]),
                   "grasped": did["grasped"], "retrieved": did["final_phase"] == "done", "held_at_end": held},
        "regrasps": did["regrasps"],
        "policy_steps": did["steps"],
        "policy_stride": policy.stride,
        "observations": did["observations"],
        "phase_log": did["phase_log"],
        **checkpoint_fields(method, checkpoint),
        "target_moved": round(float(info["target_moved"][0]), 4),
        "max_others_moved": round(float(info["max_others_moved"][0]), 4),
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


def run_hybrid(env, seed: int, method: str, checkpoint: str | None = None, retries: int = 1,
               grasp_model: str = "pretrained", stride: int = 1, improvements=()) -> dict:
    """CGN + planner approach (``hybrid_approach_method()``, with the pipeline's
    ``improvements``), then the policy's retrieval."""
    from ..solutions.sense_plan_act import SolveConfig, solve

    policy = load_policy(method, checkpoint, stride=stride, regrasp=ReGraspConfig(regrasp=False))
    approach = hybrid_approach_method()
    tally = {"steps": 0, "observations": 0}
    observe = None
    if policy.model.cfg.encoder.obs_mode == COMPOSED_OBS_MODE:
        # The composed points' start is the episode's start, as in training: taken now, before
        # the approach moves anything; the retrieval then composes without rendering.
        env.unwrapped.composed_pointcloud_obs()
        observe = composed_observation
    record = solve(env, seed=seed, method=approach, retries=retries, reset=False, grasp_model=grasp_model,
                   config=SolveConfig(improvements=tuple(improvements),
                                      retrieval=retrieval_by_policy(policy, seed, tally=tally, observe=observe)))
    record.update(method=method, approach_method=approach, **checkpoint_fields(method, checkpoint),
                  policy_stride=policy.stride, policy_steps=tally["steps"], observations=tally["observations"])
    return record
