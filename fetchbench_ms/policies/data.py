"""Imitation data: what a policy sees of an observation, and the compact training format.

The Fetch dataset's demos (``fetchbench demos run``) store env states and ``pd_joint_pos``
actions; ManiSkill's replay tool renders them into ``compact_pointcloud`` observations with
``pd_joint_delta_pos`` actions (``python -m fetchbench_ms.replay_trajectory -c
pd_joint_delta_pos -o compact_pointcloud --save-traj``): 22,528 points a frame, ~139 KB.
5,000 trajectories of ~200 frames would be ~140 GB, so ``scripts/imitation/convert_demos_for_imitation.py``
keeps, at conversion time, only what the policies read (``POLICY_SIZES``: 1,024 scene + 512
target + 256 robot points, farthest-point sampled within each segment, fp16, with their
labels) plus the joint positions, the TCP pose, the arm action and the stage labels of the
source demo: about 12.6 KB a frame (docs/imitation.md), ~12.6 GB for 1M frames, which fits
in an H100's memory whole.

A training file (``*.imit.h5``) holds frames of whole trajectories back to back:

- ``points`` [F, N, 3] float16, ``point_label`` [F, N] uint8 (``envs.pointcloud.LABEL_*``):
  the segments scene, target, robot one after the other, sizes in the ``sizes`` attribute;
- ``qpos`` [F, 9] float32 (arm + fingers), ``tcp`` [F, 9] float32 (``tcp_features``);
- ``action`` [F, 7] float32: the normalised ``pd_joint_delta_pos`` arm action of the frame
  (x 0.1 rad), ``gripper`` [F] float32 (its gripper action: 1 open, -1 closed);
- ``stage`` [F] int8 (0 approach, 1 close, 2 retrieve) and ``stage_end`` [F] bool;
- ``episode_start`` [E] int64, ``episode_length`` [E] int64, and the attribute ``episodes``:
  JSON of each trajectory's source (file, episode id, task id, grasp id);
- the attribute ``frame_stride`` K when the frames are every K-th converted step of each
  stage (``select_frames``; absent: every step, K = 1, as in every file written before it);
- the attribute ``labels`` ``expert_states`` when the frames are the source demos' own
  states, their actions those that set the expert's targets there (``expert_state_episodes``,
  no replay); absent: the replay tool's converted trajectories (``convert_episodes``).

The same functions turn a live observation into the policy's input (``PolicyInput``), so
training and deployment see the same numbers.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..envs.pointcloud import (COMPACT_OBS_MODE, COMPACT_SIZES, LABEL_FURNITURE, LABEL_OBJECT, LABEL_ROBOT,
                               LABEL_TARGET, POINTS_OBS_MODES, POLICY_CLOUD_SIZES, compact_pointcloud_obs, compact_seed)
from ..geometry.pointops import farthest_point_sample

#: Points per segment the policies read (scene, target, robot), farthest-point sampled
#: from the compact cloud's blocks.
POLICY_SIZES = {"scene": 1024, "target": 512, "robot": 256}
#: Farthest-point sampling starts from at most this many candidates per point kept (every
#: k-th point of a compact block, itself a seeded random voxel draw): FPS costs
#: candidates x kept, and the full 16,384-point scene block would triple a CPU step's cost.
FPS_CANDIDATES_PER_POINT = 4
#: Per-point one-hot classes (a point labelled none, i.e. an unseen segment's filler, is all zeros).
POINT_CLASSES = (LABEL_FURNITURE, LABEL_OBJECT, LABEL_TARGET, LABEL_ROBOT)
ARM_DOF = 7
ARM_DELTA_SCALE = 0.1  # rad: ManiSkill's Panda pd_joint_delta_pos maps [-1, 1] to +-0.1 rad
#: Stages of the demos (solutions.sense_plan_act.STAGES) the policies act in; "close" is
#: scripted at deployment (the arm holds while the gripper closes), so its frames are not learned.
STAGE_APPROACH, STAGE_CLOSE, STAGE_RETRIEVE = 0, 1, 2
POLICY_STAGES = (STAGE_APPROACH, STAGE_RETRIEVE)
FORMAT_VERSION = 1
#: ManiSkill's articulation state row: root pose (7), root velocities (6), qpos, qvel.
STATE_QPOS_START = 13


def segment_slices(sizes: dict) -> dict:
    """name -> slice of that segment's points in a cloud laid out scene, target, robot."""
    out, start = {}, 0
    for name in ("scene", "target", "robot"):
        out[name] = slice(start, start + sizes[name])
        start += sizes[name]
    return out


def subsample_compact(xyz, label, sizes: dict = POLICY_SIZES, compact_sizes: dict = COMPACT_SIZES,
                      device: str | torch.device = "cpu", batch: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Farthest-point sample each segment block of compact clouds (``xyz`` [F, M, 3], ``label``
    [F, M], laid out as ``compact_sizes``) down to ``sizes``; returns (points [F, N, 3]
    float16, labels [F, N] uint8). The candidates are every k-th point of the block
    (``FPS_CANDIDATES_PER_POINT``). Deterministic: the sampling starts at each block's first
    point (itself a seeded random draw of the compact cloud)."""
    for name in sizes:
        if sizes[name] > compact_sizes[name]:
            raise ValueError(f"{name}: {sizes[name]} points asked, the compact cloud has {compact_sizes[name]}")
    xyz = np.asarray(xyz)
    label = np.asarray(label)
    source, target = segment_slices(compact_sizes), segment_slices(sizes)
    n_out = sum(sizes.values())
    points = np.empty((len(xyz), n_out, 3), np.float16)
    labels = np.empty((len(xyz), n_out), np.uint8)
    for f0 in range(0, len(xyz), batch):
        block_xyz = torch.from_numpy(xyz[f0:f0 + batch].astype(np.float32)).to(device)
        block_label = torch.from_numpy(label[f0:f0 + batch].astype(np.int64)).to(device)
        for name in ("scene", "target", "robot"):
            stride = max(1, compact_sizes[name] // (FPS_CANDIDATES_PER_POINT * sizes[name]))
            seg_xyz = block_xyz[:, source[name]][:, ::stride]
            index = farthest_point_sample(seg_xyz, sizes[name])
            picked = torch.gather(seg_xyz, 1, index[..., None].expand(-1, -1, 3))
            points[f0:f0 + batch, target[name]] = picked.cpu().numpy().astype(np.float16)
            seg_label = block_label[:, source[name]][:, ::stride]
            labels[f0:f0 + batch, target[name]] = torch.gather(seg_label, 1, index).cpu().numpy()
    return points, labels


def tcp_features(qpos) -> np.ndarray:
    """[F, 9] float32: the TCP position in the base frame and the first two columns of its
    rotation (a continuous 6-D rotation code), by the package's Panda FK from the arm joints."""
    from ..planning.robot import panda

    q = torch.as_tensor(np.asarray(qpos, dtype=np.float64)[:, :ARM_DOF])
    T = panda().tcp_pose(q).numpy()
    return np.concatenate([T[:, :3, 3], T[:, :3, 0], T[:, :3, 1]], axis=1).astype(np.float32)


@dataclass
class PolicyInput:
    """What a policy reads at one step (numpy, batched [B, ...])."""

    points: np.ndarray  # [B, N, 3] float16, base frame, segments scene/target/robot
    point_label: np.ndarray  # [B, N] uint8
    qpos: np.ndarray  # [B, 9] float32
    tcp: np.ndarray  # [B, 9] float32


def observation_input(obs: dict, sizes: dict = POLICY_SIZES, episode_seed: int | None = None,
                      step: int = 0) -> PolicyInput:
    """A ManiSkill observation of a FetchBench env to the policy's input.

    ``obs_mode="compact_pointcloud"`` observations are used as they are; a raw
    ``obs_mode="pointcloud"`` one (what the sense-plan-act methods read) is made compact first,
    seeded as the env would (``compact_seed(episode_seed, step)``)."""
    pcd = obs["pointcloud"]
    if "points" in pcd:  # policy_pointcloud / composed_pointcloud: the env made the policy's points itself
        points, point_label = _numpy(pcd["points"]), _numpy(pcd["point_label"])
        if points.shape[1] != sum(sizes.values()):
            raise ValueError(f"a {' / '.join(POINTS_OBS_MODES)} observation of {points.shape[1]} points; the policy reads "
                             f"{sum(sizes.values())} ({dict(sizes)})")
        qpos = _numpy(obs["agent"]["qpos"]).astype(np.float32).reshape(len(points), -1)
        return PolicyInput(points.astype(np.float16), point_label.astype(np.uint8), qpos, tcp_features(qpos))
    if "xyz" not in pcd:
        if "xyz_base" not in pcd:
            raise ValueError("a policy reads obs_mode='compact_pointcloud' (or 'pointcloud') observations; "
                             f"this one has pointcloud keys {sorted(pcd)}")
        batch = len(pcd["xyz_base"])
        seed = 0 if episode_seed is None else episode_seed
        pcd = compact_pointcloud_obs(obs, [compact_seed(seed, step)] * batch)["pointcloud"]
    xyz = _numpy(pcd["xyz"])
    label = _numpy(pcd["seg"])
    points, point_label = subsample_compact(xyz, label, sizes)
    qpos = _numpy(obs["agent"]["qpos"]).astype(np.float32).reshape(len(points), -1)
    return PolicyInput(points, point_label, qpos, tcp_features(qpos))


def _numpy(x) -> np.ndarray:
    return x.detach().cpu().numpy() if isinstance(x, torch.Tensor) else np.asarray(x)


# ----------------------------------------------------------------------- converted demos
def _episode_key(episode: dict) -> str:
    return json.dumps(episode.get("reset_kwargs", {}), sort_keys=True)


#: rad: the ``pd_joint_delta_pos`` arm action's range (a normalised action of 1 is 0.1 rad).
DELTA_POS_LIMIT = 0.1
#: ManiSkill's ``from_pd_joint_pos`` takes a second step when a normalised delta exceeds this.
_CLIP_THRESHOLD = 1 + 1e-3


def source_steps(converted_actions: np.ndarray, source_actions: np.ndarray,
                 converted_qpos: np.ndarray | None = None) -> np.ndarray | None:
    """The source step of each converted step, or None if they do not line up.

    ManiSkill's conversion from ``pd_joint_pos`` (``from_pd_joint_pos``) takes one
    ``pd_joint_delta_pos`` step per source step, or two when the normalised delta from the
    arm's joints to the source's target exceeds 1 + 1e-3 (the PD-tracked arm lags its
    targets): it clips, steps, and steps again. With ``converted_qpos`` (the converted
    trajectory's joints, the observation before each step) that rule is applied as ManiSkill
    applies it. Without them a step whose arm action is at +-1 is taken as clipped, which
    misreads a delta in (1, 1.001]: clipped to 1 but given no second step. The gripper action
    is copied, so it must agree step for step."""
    n = len(converted_actions)
    counts = []
    if converted_qpos is not None:
        k = 0
        for target in np.asarray(source_actions, np.float32)[:, :ARM_DOF]:
            if k >= n:
                return None
            # float32 as in the controller (joint positions and targets are float32 there)
            delta = (target - np.asarray(converted_qpos[k, :ARM_DOF], np.float32)) / np.float32(DELTA_POS_LIMIT)
            counts.append(2 if np.abs(delta).max() > _CLIP_THRESHOLD else 1)
            k += counts[-1]
        if k != n:
            return None
    else:
        clipped = np.abs(converted_actions[:, :ARM_DOF]).max(axis=1) >= 1.0
        k = 0
        while k < n:
            step = 2 if clipped[k] and k + 1 < n else 1
            counts.append(step)
            k += step
        if len(counts) != len(source_actions):
            return None
    index = np.repeat(np.arange(len(counts)), counts)
    if np.abs(converted_actions[:, ARM_DOF] - source_actions[index, ARM_DOF]).max() > 1e-6:
        return None
    return index


def state_qpos(env_states) -> np.ndarray:
    """[T, 9] the Panda's joints in recorded env states (``env_states`` group of a trajectory)."""
    panda = env_states["articulations"]["panda"]
    dof = (panda.shape[1] - STATE_QPOS_START) // 2
    return panda[:, STATE_QPOS_START:STATE_QPOS_START + dof]


def converted_qpos(traj) -> np.ndarray:
    """[n + 1, 9] a converted trajectory's joints before each step (and after the last): its
    observations' ``agent/qpos``, or, for a state-only replay (``-o state``: one flat vector an
    observation), its env states' rows, which hold the same joints at the same times."""
    obs = traj.get("obs")
    if hasattr(obs, "keys") and "agent" in obs:
        return obs["agent"]["qpos"][:]
    return state_qpos(traj["env_states"])


def match_converted_episodes(source_json: dict, converted_json: dict, source_h5, converted_h5,
                             tolerance: float = 0.15) -> list[tuple[dict, dict, np.ndarray]]:
    """Triples (source episode, converted episode, source step of each converted step). The
    replay tool keeps the source order but drops episodes it could not replay and numbers its
    output anew; several trajectories of one task share their reset kwargs, so a pair also
    needs its steps to line up (``source_steps``) and about the same final arm joints (about:
    the converted arm lags while the clipped deltas catch up, e.g. 0.06 rad 12 steps into a demo)."""
    out, sources = [], list(source_json["episodes"])
    k = 0
    for converted in converted_json["episodes"]:
        c_traj = converted_h5[f"traj_{converted['episode_id']}"]
        c_actions = c_traj["actions"][:]
        c_qpos = converted_qpos(c_traj)
        c_final = c_qpos[-1, :ARM_DOF]
        for j in range(k, len(sources)):
            source = sources[j]
            if _episode_key(source) != _episode_key(converted):
                continue
            s_traj = source_h5[f"traj_{source['episode_id']}"]
            index = source_steps(c_actions, s_traj["actions"][:], c_qpos)
            if index is None:
                continue
            s_qpos = state_qpos(s_traj["env_states"])[-1, :ARM_DOF]
            if np.abs(s_qpos - c_final).max() <= tolerance:
                out.append((source, converted, index))
                k = j + 1
                break
    return out


def select_frames(stage, stage_end, actions, stride: int) -> dict:
    """Every ``stride``-th step of each stage segment (a maximal run of one ``stage``) of one
    converted demo: the steps kept (``frame``, [M]) and their labels. A kept step t stands for
    its window [t, t + stride), cut at the segment's end: its arm action (``action`` [M, 7]
    float32) is the mean of the window's arm actions, its gripper action (``gripper`` [M]),
    ``stage`` [M] are step t's, and ``stage_end`` [M] is set on a segment's last kept step
    when the segment's last step has it. ``actions`` [n, 8]: the converted actions."""
    stage, stage_end = np.asarray(stage), np.asarray(stage_end, bool)
    n = len(stage)
    starts = np.flatnonzero(np.r_[True, stage[1:] != stage[:-1]])
    ends = np.r_[starts[1:], n]
    frame = np.concatenate([np.arange(start, end, stride) for start, end in zip(starts, ends)])
    # The windows tile the demo: each ends where the next kept step begins (a segment's last
    # one at the segment's end, so it may be shorter than the stride).
    window = np.diff(np.r_[frame, n])
    # The policy acts every K steps and its arm action is repeated in between (deployment's
    # ImitationPolicy(stride=K)). A delta action moves the joints by its value at each step, so
    # the window's mean, repeated over the window, moves the arm as far as the expert's steps
    # did; the gripper is a command held from step t, not a motion, so step t's is kept.
    arm = np.add.reduceat(np.asarray(actions, np.float64)[:, :ARM_DOF], frame, axis=0) / window[:, None]
    segment = np.searchsorted(starts, frame, side="right") - 1
    last_of_segment = np.r_[segment[1:] != segment[:-1], True]
    return {"frame": frame, "action": arm.astype(np.float32),
            "gripper": np.asarray(actions, np.float32)[frame, ARM_DOF],
            "stage": stage[frame].astype(np.int8), "stage_end": last_of_segment & stage_end[ends[segment] - 1]}


@dataclass
class _KeptFrames:
    """The frames kept of one converted demo, before their points."""

    traj: object  # the demo's group in the converted file
    episode: dict  # its entry in the converted file's JSON (reset kwargs, episode seed)
    frame: np.ndarray  # [M] the converted steps kept
    labels: dict  # their action, gripper, stage, stage_end
    qpos: np.ndarray  # [M, 9] float32


def convert_episodes(converted_path: str | Path, source_path: str | Path, sizes: dict = POLICY_SIZES,
                     device: str = "cpu", log=print, frame_stride: int = 1, render_workers: int = 1,
                     render_obs_mode: str = COMPACT_OBS_MODE, render_backends: list[str] | None = None,
                     pool=None) -> dict:
    """Frames of every converted trajectory (the replay tool's ``pd_joint_delta_pos`` output)
    that matches a source demo, in the training format's arrays (see the module docstring),
    with the source's stage labels.

    The points come from the file's ``compact_pointcloud`` observations, or, for a state-only
    replay (``-o state``), are rendered from its recorded env states at the frames kept only
    (``fetchbench_ms.render_env_states``, ``render_workers`` processes). ``frame_stride`` K > 1
    keeps every K-th step of each stage (``select_frames``); 1 keeps every step.
    ``render_obs_mode="policy_pointcloud"`` or ``"composed_pointcloud"`` (``POINTS_OBS_MODES``)
    renders the states in that obs mode, whose points are the frames' as they are (``sizes``
    must be ``POLICY_CLOUD_SIZES``); the result then carries ``obs_mode``."""
    import h5py

    converted_path, source_path = Path(converted_path), Path(source_path)
    source_json = json.loads(source_path.with_suffix(".json").read_text())
    converted_json = json.loads(converted_path.with_suffix(".json").read_text())
    env_kwargs = converted_json["env_info"]["env_kwargs"]
    control, obs_mode = env_kwargs.get("control_mode"), env_kwargs.get("obs_mode")
    if control != "pd_joint_delta_pos" or obs_mode not in (COMPACT_OBS_MODE, "state"):
        raise ValueError(f"{converted_path}: converted with control_mode={control!r}, obs_mode={obs_mode!r}; the "
                         "policies need -c pd_joint_delta_pos -o compact_pointcloud (or -o state: the clouds are "
                         "then rendered from its env states)")
    policy_obs = render_obs_mode in POINTS_OBS_MODES
    if policy_obs and (obs_mode != "state" or dict(sizes) != POLICY_CLOUD_SIZES):
        raise ValueError(f"{render_obs_mode} frames are rendered from a state-only replay (-o state) at its own "
                         f"sizes {POLICY_CLOUD_SIZES}; got obs_mode={obs_mode!r}, sizes {dict(sizes)}")
    episodes, kept = [], []
    with h5py.File(source_path, "r") as source_h5, h5py.File(converted_path, "r") as converted_h5:
        pairs = match_converted_episodes(source_json, converted_json, source_h5, converted_h5)
        for source, converted, index in pairs:
            c_traj = converted_h5[f"traj_{converted['episode_id']}"]
            s_traj = source_h5[f"traj_{source['episode_id']}"]
            actions = c_traj["actions"][:]
            n = len(actions)
            # A source step converted into two steps: its stage on both, its end flag on the second.
            last_of_step = np.r_[index[1:] != index[:-1], True]
            stage = s_traj["stage"][:][index].astype(np.int8)
            stage_end = s_traj["stage_end"][:][index].astype(bool) & last_of_step
            if frame_stride == 1:
                labels = {"frame": np.arange(n), "action": actions[:, :ARM_DOF].astype(np.float32),
                          "gripper": actions[:, ARM_DOF].astype(np.float32), "stage": stage, "stage_end": stage_end}
            else:
                labels = select_frames(stage, stage_end, actions, frame_stride)
            frame = labels.pop("frame")
            kept.append(_KeptFrames(c_traj, converted, frame, labels, converted_qpos(c_traj)[frame].astype(np.float32)))
            episode = {"source": source_path.name, "episode_id": int(source["episode_id"]),
                       "task_id": source.get("task_id"), "grasp_id": source.get("grasp_id"),
                       "length": len(frame), "source_length": int(len(s_traj["actions"]))}
            if frame_stride != 1:
                episode["converted_length"] = n
            episodes.append(episode)
        if obs_mode == COMPACT_OBS_MODE:
            clouds = ((d.traj["obs"]["pointcloud"]["xyz"][:][d.frame], d.traj["obs"]["pointcloud"]["seg"][:][d.frame])
                      for d in kept)
        else:
            from ..render_env_states import render_compact_clouds

            jobs = _render_jobs(kept)  # by the pool kept over many calls, or by workers started for them
            clouds = pool.imap(jobs) if pool is not None else render_compact_clouds(
                converted_json["env_info"]["env_id"], env_kwargs, jobs, render_workers, render_obs_mode, render_backends)
        out = _training_arrays(kept, episodes, clouds, sizes, render_obs_mode, frame_stride, device, log,
                               rendered=obs_mode != COMPACT_OBS_MODE, workers=render_workers)
    dropped = len(converted_json["episodes"]) - len(pairs)
    if dropped:
        log(f"{converted_path.name}: {dropped} converted trajectories matched no source demo (left out)")
    return out


def _render_jobs(kept: list[_KeptFrames]) -> list:
    """The kept frames as ``RenderJob``s: their task's reset and their recorded env states."""
    from mani_skill.trajectory.utils import index_dict

    from ..render_env_states import RenderJob

    return [RenderJob(d.episode["reset_kwargs"], int(d.episode["episode_seed"]), d.frame,
                      index_dict(index_dict(d.traj["env_states"], slice(None)), d.frame)) for d in kept]


def _training_arrays(kept: list[_KeptFrames], episodes: list[dict], clouds, sizes: dict, render_obs_mode: str,
                     frame_stride: int, device: str, log, rendered: bool, workers: int, labels: str | None = None) -> dict:
    """The training format's arrays (``write_training_file``) of the kept frames and their clouds."""
    parts: dict[str, list] = {k: [] for k in ARRAYS}
    policy_obs = render_obs_mode in POINTS_OBS_MODES
    t = time.perf_counter()
    for demo, (xyz, label) in zip(kept, clouds):
        if policy_obs:  # the obs mode's own points, as a policy reads them at deployment
            points, point_label = xyz, label
        else:
            points, point_label = subsample_compact(xyz, label, sizes, device=device)
        parts["points"].append(points)
        parts["point_label"].append(point_label)
        parts["qpos"].append(demo.qpos)
        parts["tcp"].append(tcp_features(demo.qpos))
        for key, value in demo.labels.items():
            parts[key].append(value)
    if rendered and kept:
        frames = sum(len(d.frame) for d in kept)
        log(f"  rendered {frames} frames of {len(kept)} demos from their env states "
            f"({workers} processes) and subsampled them in {time.perf_counter() - t:.0f} s")
    extra = {"obs_mode": render_obs_mode} if policy_obs else {}
    if labels is not None:
        extra["labels"] = labels
    if not episodes:
        return {"episodes": [], "sizes": dict(sizes), "frame_stride": frame_stride, **extra}
    out = {k: np.concatenate(v) for k, v in parts.items()}
    lengths = np.array([e["length"] for e in episodes], np.int64)
    out["episode_length"] = lengths
    out["episode_start"] = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    out["episodes"] = episodes
    out["sizes"] = dict(sizes)
    out["frame_stride"] = frame_stride
    out.update(extra)
    return out


#: ``labels`` of a training file whose actions are the expert's at its own recorded states
#: (``expert_state_episodes``); absent (``REPLAY_LABELS``): at the replay tool's converted states.
EXPERT_STATE_LABELS, REPLAY_LABELS = "expert_states", "replay"


def expert_state_actions(source_actions: np.ndarray, source_qpos: np.ndarray) -> np.ndarray:
    """[n, 8] the ``pd_joint_delta_pos`` actions that give, at each recorded state, the arm
    targets the expert's ``pd_joint_pos`` actions gave: (target - joints) / 0.1 rad, as
    ManiSkill's ``qpos_to_pd_joint_delta_pos`` computes it (float32, as in the controller),
    clipped to [-1, 1]; the gripper action copied. ``source_qpos`` [n, >= 7]: the joints of
    the state before each action (``state_qpos`` of the demo's env states)."""
    actions = np.asarray(source_actions, np.float32)
    delta = (actions[:, :ARM_DOF] - np.asarray(source_qpos, np.float32)[:len(actions), :ARM_DOF]) \
        / np.float32(DELTA_POS_LIMIT)
    return np.concatenate([np.clip(delta, -1, 1), actions[:, ARM_DOF:]], axis=1).astype(np.float32)


def expert_state_episodes(source_path: str | Path, episodes: list[dict], pool, obs_mode: str,
                          frame_stride: int = 1, log=print, first_steps: int | None = None) -> dict:
    """Frames of the source demos ``episodes`` (entries of the source's JSON) at their own
    recorded states, without a replay: each kept step's env state is set and rendered in
    ``obs_mode`` (one of ``POINTS_OBS_MODES``) by ``pool`` (a ``StateRenderPool``), and its
    action is the ``pd_joint_delta_pos`` action that sets the expert's arm targets there
    (``expert_state_actions``). The replay tool's conversion instead steps the physics with
    those actions and, where a delta exceeds 0.1 rad (the PD-tracked arm lags its targets),
    takes a second clipped step: its trajectories are longer and lag the expert's; here the
    states are the expert's and such an action is clipped. The stride, stage labels and
    training format are ``convert_episodes``'; the result carries ``labels``. ``first_steps``
    N keeps each demo's first N steps (tests)."""
    import h5py

    if obs_mode not in POINTS_OBS_MODES:
        raise ValueError(f"frames at the expert's states are made in the points obs modes "
                         f"({', '.join(POINTS_OBS_MODES)}), got {obs_mode!r}")
    source_path = Path(source_path)
    kept, out_episodes = [], []
    with h5py.File(source_path, "r") as source_h5:
        for source in episodes:
            s_traj = source_h5[f"traj_{source['episode_id']}"]
            n = len(s_traj["actions"]) if first_steps is None else min(first_steps, len(s_traj["actions"]))
            qpos = state_qpos(s_traj["env_states"])[:n]
            actions = expert_state_actions(s_traj["actions"][:n], qpos)
            stage = s_traj["stage"][:n].astype(np.int8)
            stage_end = s_traj["stage_end"][:n].astype(bool)
            labels = select_frames(stage, stage_end, actions, frame_stride)
            frame = labels.pop("frame")
            kept.append(_KeptFrames(s_traj, source, frame, labels, qpos[frame].astype(np.float32)))
            out_episodes.append({"source": source_path.name, "episode_id": int(source["episode_id"]),
                                 "task_id": source.get("task_id"), "grasp_id": source.get("grasp_id"),
                                 "length": len(frame), "source_length": int(len(actions))})
        clouds = pool.imap(_render_jobs(kept))
        return _training_arrays(kept, out_episodes, clouds, POLICY_CLOUD_SIZES, obs_mode, frame_stride, "cpu", log,
                                rendered=True, workers=pool.workers, labels=EXPERT_STATE_LABELS)


def write_training_file(path: str | Path, data: dict) -> int:
    """Write ``convert_episodes``' arrays as a training file (temp name, then renamed);
    returns its size in bytes."""
    import os

    import h5py

    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with h5py.File(tmp, "w") as f:
        f.attrs["format_version"] = FORMAT_VERSION
        f.attrs["sizes"] = json.dumps(data["sizes"])
        f.attrs["episodes"] = json.dumps(data["episodes"])
        if data.get("frame_stride", 1) != 1:  # (stride-1 files stay as they were: no attribute)
            f.attrs["frame_stride"] = int(data["frame_stride"])
        if data.get("obs_mode", COMPACT_OBS_MODE) != COMPACT_OBS_MODE:  # (absent: compact_pointcloud)
            f.attrs["obs_mode"] = data["obs_mode"]
        if data.get("labels") is not None:  # (absent: the replay tool's converted trajectories)
            f.attrs["labels"] = data["labels"]
        for key in ("points", "point_label", "qpos", "tcp", "action", "gripper", "stage", "stage_end",
                    "episode_start", "episode_length"):
            if key in data:
                f.create_dataset(key, data=data[key])
    os.replace(tmp, path)
    return path.stat().st_size


ARRAYS = ("points", "point_label", "qpos", "tcp", "action", "gripper", "stage", "stage_end")


def load_training_files(paths, sizes: dict | None = None) -> dict:
    """Concatenate training files (``*.imit.h5``, or folders of them, in sorted order) into
    one dict of numpy arrays plus ``episode_start`` / ``episode_length`` / ``episodes``."""
    import h5py

    files = []
    for p in [Path(p) for p in ([paths] if isinstance(paths, (str, Path)) else paths)]:
        files += sorted(p.glob("*.imit.h5")) if p.is_dir() else [p]
    if not files:
        raise FileNotFoundError(f"no training files (*.imit.h5) in {paths}; make them with "
                                "scripts/imitation/convert_demos_for_imitation.py")
    parts = {k: [] for k in ARRAYS}
    episodes, lengths, file_sizes, file_stride, file_mode, file_labels = [], [], None, None, None, None
    for path in files:
        with h5py.File(path, "r") as f:
            if int(f.attrs.get("format_version", -1)) != FORMAT_VERSION:
                raise ValueError(f"{path}: training format {f.attrs.get('format_version')}, this code reads "
                                 f"{FORMAT_VERSION}: convert the demos again")
            these = json.loads(f.attrs["sizes"])
            if file_sizes is not None and these != file_sizes:
                raise ValueError(f"{path}: point sizes {these} differ from the other files' {file_sizes}")
            file_sizes = these
            # A frame of one stride stands for another span of control steps, with another
            # action (select_frames): frames of two strides are not one training set.
            stride = int(f.attrs.get("frame_stride", 1))
            if file_stride is not None and stride != file_stride:
                raise ValueError(f"{path}: frames every {stride} converted steps (--frame-stride {stride}), the "
                                 f"other files' every {file_stride}: train on files of one frame stride")
            file_stride = stride
            # The points of two obs modes are other draws of other cameras: not one training set.
            mode = str(f.attrs.get("obs_mode", COMPACT_OBS_MODE))
            if file_mode is not None and mode != file_mode:
                raise ValueError(f"{path}: frames of obs mode {mode}, the other files' {file_mode}: train on files "
                                 "of one obs mode")
            file_mode = mode
            labels = str(f.attrs.get("labels", REPLAY_LABELS))
            if file_labels is not None and labels != file_labels:
                raise ValueError(f"{path}: actions labelled at {labels}, the other files' at {file_labels}: train "
                                 "on files of one conversion")
            file_labels = labels
            if "points" not in f:  # a chunk none of whose trajectories replayed
                continue
            for k in ARRAYS:
                parts[k].append(f[k][:])
            episodes += json.loads(f.attrs["episodes"])
            lengths.append(f["episode_length"][:])
    if sizes is not None and file_sizes != dict(sizes):
        raise ValueError(f"the training files hold {file_sizes} points per segment, the policy wants {dict(sizes)}")
    if not episodes:
        raise ValueError(f"the training files in {paths} hold no trajectory")
    out = {k: np.concatenate(v) for k, v in parts.items()}
    lengths = np.concatenate(lengths)
    out["episode_length"] = lengths
    out["episode_start"] = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    out["episodes"] = episodes
    out["sizes"] = file_sizes
    out["frame_stride"] = file_stride
    out["obs_mode"] = file_mode
    out["labels"] = file_labels
    out["files"] = [str(p) for p in files]
    return out
