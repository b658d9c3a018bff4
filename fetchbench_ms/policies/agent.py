"""Trained imitation policies as ManiSkill agents, and the re-grasp state machine.

    policy = ImitationPolicy.load("assets/checkpoints/imit_mlp.pt")
    env = gym.make("FetchBench-v0", obs_mode="compact_pointcloud", control_mode="pd_joint_delta_pos")
    obs, _ = env.reset(seed=0)
    policy.reset(episode_seed=0)
    while not policy.done:
        obs, *_ = env.step(policy.get_action(obs))

``get_action`` returns a ``pd_joint_delta_pos`` action [B, 8] (7 normalised arm deltas, the
gripper: 1 open, -1 closed). The arm comes from the network; the gripper and the stage the
network is told come from ``ReGraspStateMachine`` (the paper's end-to-end deployment):

    APPROACH --termination--> CLOSE --close_steps--> RETRIEVE --termination--> DONE
        ^                                              |
        +--- reopen_steps --- REOPEN <-- fingers fully closed (grasped nothing)

``regrasp=False`` is the paper's two-stage deployment (approach, then retrieve, no way back).

``get_action`` is ``begin_step(qpos)`` (does this step read the observation?) then
``act(obs)``: rendering the cameras' cloud costs far more than the network, so a deployment
(``deploy.run_policy``) renders only when ``begin_step`` says so. ``stride`` k: the network
reads an observation every k-th acting step and its arm action is repeated in between (a
diffusion policy's chunk actions each last the control steps its training frames stood for,
the checkpoint's ``frame_stride``; its termination is checked every k-th step). An ACT
policy reads every k-th step too and ensembles its overlapping chunks (``TemporalEnsemble``),
or, with its config's ``temporal_ensemble`` off, runs each chunk open-loop as the diffusion
policy does.
"""
from __future__ import annotations

import numbers
import time
import warnings
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..envs.pointcloud import COMPACT_OBS_MODE, POINTS_OBS_MODES
from ..method_spec import PolicyKind
from .data import ARM_DOF, STAGE_APPROACH, STAGE_RETRIEVE, PolicyInput, _numpy, observation_input
from .networks import build_policy, config_from_dict, config_to_dict

APPROACH, CLOSE, RETRIEVE, REOPEN, DONE = "approach", "close", "retrieve", "reopen", "done"
PHASES = (APPROACH, CLOSE, RETRIEVE, REOPEN, DONE)
GRIPPER_OPEN, GRIPPER_CLOSED = 1.0, -1.0
#: The phase the network acts in -> the demo stage id it was trained with.
PHASE_STAGE = {APPROACH: STAGE_APPROACH, RETRIEVE: STAGE_RETRIEVE}
CHECKPOINT_VERSION = 1


@dataclass
class ReGraspConfig:
    termination_threshold: float = 0.5
    close_steps: int = 30  # 1.5 s at 20 Hz, as the demos close
    reopen_steps: int = 10
    # Fingers (sum of the two finger joints) below this in retrieval: closed on nothing.
    closed_gap: float = 0.002  # m
    settle_steps: int = 5  # retrieval steps before the gap is judged (the fingers may still move)
    min_approach_steps: int = 5  # no termination before this many approach steps
    min_retrieve_steps: int = 10  # nor before this many retrieval steps (a demo retrieves in ~100)
    regrasp: bool = True  # False: the two-stage deployment
    max_regrasps: int = 3


@dataclass
class ReGraspStateMachine:
    """The deployment's phases. Per control step: ``begin_step(finger_gap)`` moves on by time
    and by the gripper; the network then acts if ``acting`` and ``end_step(p)`` takes its
    termination probability."""

    config: ReGraspConfig = field(default_factory=ReGraspConfig)
    phase: str = APPROACH
    steps_in_phase: int = 0
    regrasps: int = 0
    log: list = field(default_factory=list)  # (step, from, to) of every transition
    step: int = 0

    def _go(self, phase: str) -> None:
        self.log.append((self.step, self.phase, phase))
        self.phase, self.steps_in_phase = phase, 0

    def begin_step(self, finger_gap: float) -> str:
        cfg = self.config
        if self.phase == CLOSE and self.steps_in_phase >= cfg.close_steps:
            self._go(RETRIEVE)
        elif self.phase == REOPEN and self.steps_in_phase >= cfg.reopen_steps:
            self.regrasps += 1
            self._go(APPROACH)
        elif (self.phase == RETRIEVE and cfg.regrasp and self.regrasps < cfg.max_regrasps
              and self.steps_in_phase >= cfg.settle_steps and finger_gap < cfg.closed_gap):
            self._go(REOPEN)
        return self.phase

    @property
    def acting(self) -> bool:
        """Whether the network commands the arm in this phase (else the arm holds)."""
        return self.phase in PHASE_STAGE

    @property
    def gripper(self) -> float:
        return GRIPPER_OPEN if self.phase in (APPROACH, REOPEN) else GRIPPER_CLOSED

    def end_step(self, termination_prob: float | None = None) -> None:
        cfg = self.config
        fired = termination_prob is not None and termination_prob > cfg.termination_threshold
        self.steps_in_phase += 1
        self.step += 1
        if self.phase == APPROACH and fired and self.steps_in_phase >= cfg.min_approach_steps:
            self._go(CLOSE)
        elif self.phase == RETRIEVE and fired and self.steps_in_phase >= cfg.min_retrieve_steps:
            self._go(DONE)


def check_stride(stride) -> int:
    """A policy stride (control steps per observation): an integer >= 1."""
    if isinstance(stride, bool) or not isinstance(stride, numbers.Integral) or stride < 1:
        raise ValueError(f"the policy stride takes an integer >= 1 (control steps per observation), got {stride!r}")
    return int(stride)


class TemporalEnsemble:
    """ACT's temporal ensembling: every predicted chunk is kept with the frame it started at;
    a frame's action is the mean of every kept prediction for it, weighted exp(-m i) with i = 0
    for the oldest (the earliest predictions count most: the action changes smoothly).

    ``push(chunk)`` adds the chunk [T, A] predicted at the current frame and returns that
    frame's action [A]; the next push is the next frame. ``clear()``: a new phase, frame 0."""

    def __init__(self, m: float = 0.01):
        self.m = float(m)
        self.clear()

    def clear(self) -> None:
        self.frame = 0
        self.chunks: deque = deque()  # (start frame, chunk [T, A]), oldest first

    def weights(self, n: int) -> np.ndarray:
        """The normalised weights of ``n`` predictions, oldest first."""
        w = np.exp(-self.m * np.arange(n))
        return w / w.sum()

    def push(self, chunk) -> np.ndarray:
        chunk = np.asarray(chunk, np.float32)
        self.chunks.append((self.frame, chunk))
        while self.chunks[0][0] + len(self.chunks[0][1]) <= self.frame:  # chunks ended before this frame
            self.chunks.popleft()
        predictions = np.stack([c[self.frame - start] for start, c in self.chunks])
        self.frame += 1
        return (self.weights(len(predictions))[:, None] * predictions).sum(0).astype(np.float32)


def check_obs_mode(obs: dict, trained_on: str) -> None:
    """ValueError unless ``obs`` is of the kind the policy was trained on: the points of
    ``policy_pointcloud`` or ``composed_pointcloud`` (``pointcloud/points``), or a compact / raw
    cloud for the ``compact_pointcloud`` policies (the raw one is made compact as the env would).
    (The two points modes have the same keys: the env of a method is made in its checkpoint's
    mode, ``deploy.policy_obs_mode``.)"""
    policy_obs = "points" in obs.get("pointcloud", {})
    if policy_obs != (trained_on in POINTS_OBS_MODES):
        have = " or ".join(POINTS_OBS_MODES) if policy_obs else "a compact or raw point cloud"
        raise ValueError(f"the policy was trained on {trained_on} observations, the env gives {have}: make the env "
                         f"with obs_mode={trained_on!r}")


def checkpoint_obs_mode(path: str | Path) -> str:
    """The env obs mode a checkpoint's policy reads (its encoder config; before the field: compact)."""
    from ..utils.packed import packed_or_plain, torch_load

    payload = torch_load(packed_or_plain(path), map_location="cpu", weights_only=False)
    return payload["config"]["encoder"].get("obs_mode", COMPACT_OBS_MODE)


def save_checkpoint(path: str | Path, model: torch.nn.Module, meta: dict, fp16: bool = True) -> int:
    """The model's weights (fp16 by default) and config, plus ``meta`` (training command,
    data hash, ...), written atomically; returns the file size."""
    import io

    from ..utils.io import atomic_write_bytes

    state = {k: (v.half() if fp16 and v.is_floating_point() else v).cpu() for k, v in model.state_dict().items()}
    payload = {"version": CHECKPOINT_VERSION, "kind": model.kind, "config": config_to_dict(model.cfg),
               "state_dict": state, "meta": meta}
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    atomic_write_bytes(path, buffer.getvalue())
    return len(buffer.getvalue())


class CheckpointKindError(ValueError):
    """The checkpoint holds another kind's policy than the one asked for."""


def load_model(path: str | Path, device: str | torch.device = "cpu",
               kind: PolicyKind | None = None) -> tuple[torch.nn.Module, dict]:
    """A policy checkpoint's network (eval mode) and meta; ``path`` is a ``.pt`` file or its
    packed copy (``utils.packed``: ``X.pt`` reads ``X.pt.planes.xz`` when only that exists).
    ``kind``: the policy kind it must hold (its row: its network needs no look-up); None:
    the registered kind the checkpoint names."""
    from ..utils.packed import packed_or_plain, torch_load

    path = packed_or_plain(path)
    if not path.is_file():
        raise FileNotFoundError(f"no policy checkpoint at {path}")
    try:
        payload = torch_load(path, map_location="cpu", weights_only=False)
    except Exception as error:  # truncated or not a torch file: zip, pickle and EOF errors alike
        raise ValueError(f"{path} is not a readable policy checkpoint ({type(error).__name__}: "
                         f"{str(error).splitlines()[0] if str(error) else 'no detail'}); copy it again or "
                         "re-export it (docs/imitation.md)") from None
    if not isinstance(payload, dict) or not {"kind", "config", "state_dict"} <= set(payload):
        raise ValueError(f"{path} is not a FetchBench policy checkpoint (no kind/config/state_dict)")
    if payload.get("version") != CHECKPOINT_VERSION:
        raise ValueError(f"{path}: checkpoint version {payload.get('version')}, this code reads {CHECKPOINT_VERSION}")
    if kind is not None and payload["kind"] != kind.name:
        raise CheckpointKindError(f"needs a {kind.name} checkpoint; {path} holds a {payload['kind']} policy")
    kind = kind or payload["kind"]
    model = build_policy(kind, config_from_dict(kind, payload["config"]))
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in payload["state_dict"].items()})
    return model.to(device).eval(), payload.get("meta", {})


class ImitationPolicy:
    """A trained policy with its observation history, action queue and state machine.

    ``stride``: control steps per observation of an MLP / Transformer / ensembled ACT policy
    (its arm action is repeated meanwhile), and per termination check of an open-loop chunk
    (diffusion, ACT without the ensemble); the checkpoint's ``frame_stride`` (its data's, 1:
    every step observed) is how it was trained, and another stride is warned of."""

    def __init__(self, model: torch.nn.Module, meta: dict | None = None, device: str | torch.device = "cpu",
                 regrasp: ReGraspConfig | None = None, seed: int = 0, stride: int = 1):
        self.stride = check_stride(stride)
        self.model, self.meta, self.device = model.to(device).eval(), meta or {}, torch.device(device)
        trained = int(self.meta.get("frame_stride", 1))
        ensemble = model.kind == "act" and model.cfg.temporal_ensemble
        # A diffusion policy's chunk (an ACT one's without the ensemble) runs open-loop.
        self.open_loop = model.kind == "diffusion" or (model.kind == "act" and not ensemble)
        # ACT with the ensemble: a chunk at every observation, each frame's action averaged
        # over the chunks that predicted it (cleared with the history at a phase change).
        self.ensemble = TemporalEnsemble(model.cfg.ensemble_m) if ensemble else None
        # An open-loop chunk is a sequence of training frames, each standing for `trained`
        # control steps (--frame-stride): each chunk action is repeated that often, at any
        # policy stride (which only sets how often its termination is checked).
        self.chunk_repeat = trained if self.open_loop else 1
        # Any other arm action (an ensembled one is a frame's too) lasts the policy stride,
        # against the `trained` steps a frame's action stood for.
        if not self.open_loop and self.stride != trained:
            warnings.warn(f"this {model.kind} policy was trained on data of --frame-stride {trained} and its arm "
                          f"actions last {self.stride} control step(s) here (policy stride {self.stride}), against "
                          f"{trained} in training: it acts at another time scale than it learned", stacklevel=2)
        self.regrasp_config = regrasp or ReGraspConfig()
        self.seed = seed
        self.reset()

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu", **kwargs) -> "ImitationPolicy":
        """``kwargs``: ``regrasp``, ``seed``, ``stride`` (see the class)."""
        model, meta = load_model(path, device)
        return cls(model, meta, device, **kwargs)

    def reset(self, episode_seed: int | None = None, phase: str = APPROACH) -> None:
        """A new episode (``phase``: where it starts; the hybrid methods start in retrieval)."""
        if phase not in PHASES:
            raise ValueError(f"unknown phase {phase!r}; valid: {', '.join(PHASES)}")
        self.machine = ReGraspStateMachine(self.regrasp_config, phase=phase)
        self.episode_seed = episode_seed
        self.history: deque = deque(maxlen=self.model.history)
        self.queue: deque = deque()
        self.last_phase = phase
        self.generator = torch.Generator(device=self.device).manual_seed(
            int(self.seed if episode_seed is None else episode_seed) % 2**63)
        self.inference_time = 0.0
        self.steps = 0
        self.since_observed = 0  # acting steps since the network last read an observation
        self.needs_obs: bool | None = None  # this step's begin_step answer; None between steps

    @property
    def done(self) -> bool:
        return self.machine.phase == DONE

    def _batch(self, step_input: PolicyInput, stage: int) -> dict:
        """The model's input from the history (oldest first; at a phase's start the first
        step is repeated, as training windows are padded)."""
        frames = list(self.history)
        frames = [frames[0]] * (self.model.history - len(frames)) + frames
        obs = {k: torch.from_numpy(np.stack([getattr(f, k) for f in frames], axis=1)).to(self.device)
               for k in ("points", "point_label", "qpos", "tcp")}
        obs["stage"] = torch.full(obs["qpos"].shape[:2], stage, dtype=torch.long, device=self.device)
        if self.model.history == 1:
            obs = {k: v[:, 0] for k, v in obs.items()}
        return obs

    def get_action(self, obs: dict) -> np.ndarray:
        """The ``pd_joint_delta_pos`` action [1, 8] for a FetchBench observation (compact or raw
        point cloud, one sub-scene)."""
        self.begin_step(obs["agent"]["qpos"])
        return self.act(obs)

    def begin_step(self, qpos) -> bool:
        """Start a control step from the robot's joints ([9], or [1, 9]): the finger gap moves
        the state machine on. Returns whether ``act`` needs this step's observation (the
        network runs: the arm is the network's and no action of it is queued, or a diffusion
        policy's termination check is due); a caller renders the cameras only then."""
        if self.needs_obs is not None:
            raise RuntimeError("begin_step called twice: act() ends the control step begin_step began")
        q = _numpy(qpos).astype(np.float32).reshape(-1)
        phase = self.machine.begin_step(float(q[7] + q[8]))
        if phase != self.last_phase:  # a new phase: its own history and action chunk(s)
            self.history.clear()
            self.queue.clear()
            if self.ensemble is not None:
                self.ensemble.clear()
            self.last_phase = phase
        self.needs_obs = self.machine.acting and (
            not self.queue or (self.open_loop and self.since_observed >= self.stride))
        return self.needs_obs

    def act(self, obs: dict | None = None) -> np.ndarray:
        """The action [1, 8] of the step ``begin_step`` began; ``obs`` (compact or raw point
        cloud, one sub-scene) is read only when ``begin_step`` returned True, and needed then."""
        if self.needs_obs is None:
            raise RuntimeError("act() ends a control step: call begin_step(qpos) first")
        if self.needs_obs and obs is None:
            raise ValueError("the policy's network runs at this step (begin_step returned True): act(obs) needs "
                             "the observation")
        observe, self.needs_obs = self.needs_obs, None
        arm = np.zeros(ARM_DOF, np.float32)
        termination = None
        if observe:
            check_obs_mode(obs, self.model.cfg.encoder.obs_mode)
            step_input = observation_input(obs, self.model.cfg.encoder.sizes, self.episode_seed, self.steps)
            self.history.append(step_input)
            stage = PHASE_STAGE[self.machine.phase]
            t = time.perf_counter()
            if not self.queue:
                actions, term = self._act(self._batch(step_input, stage))
                if self.ensemble is not None:  # this frame's ensembled action, repeated over the stride
                    chunk = [self.ensemble.push(actions[0])] * self.stride
                elif not self.open_loop:  # one action, repeated over the stride (action repeat)
                    chunk = [actions[0][0]] * self.stride
                else:  # each chunk action for the steps its training frame stood for
                    chunk = [a for a in actions[0] for _ in range(self.chunk_repeat)]
                self.queue = deque(chunk)
            else:  # an action chunk in progress: only the termination output is fresh
                _, term = self._act(self._batch(step_input, stage), termination_only=True)
            termination = float(term[0])
            self.since_observed = 0
            self.inference_time += time.perf_counter() - t
        if self.machine.acting:
            arm = np.asarray(self.queue.popleft(), np.float32)
            self.since_observed += 1
        action = np.concatenate([np.clip(arm, -1, 1), [self.machine.gripper]]).astype(np.float32)
        self.machine.end_step(termination)
        self.steps += 1
        return action[None]

    def _act(self, batch: dict, termination_only: bool = False):
        with torch.no_grad():
            if termination_only:  # an open-loop chunk in progress
                return None, self.model.termination_prob(batch).cpu().numpy()
            if self.model.kind == "diffusion":
                actions, term = self.model.act(batch, generator=self.generator)
            else:
                actions, term = self.model.act(batch)
        return actions.cpu().numpy(), term.cpu().numpy()

