"""Batched, multi-seed, collision-aware inverse kinematics for the robot's TCP.

Damped least squares on pytorch_kinematics' geometric Jacobian, run for every
(target, seed) pair at once. A solution counts only when it reaches the target within
the position and rotation tolerances, lies inside the joint limits (steps are clipped
to them) and, when a checker is given, is collision-free. Otherwise: no solution.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from .robot import PandaModel

POS_TOL = 0.002  # m
ROT_TOL = 0.02  # rad
STALL_WINDOW = 15  # iterations
STALL_RATIO = 0.7


@dataclass(frozen=True)
class IKResult:
    """Solutions sorted best first (closest to the seed configuration)."""

    q: np.ndarray  # (K, 7)
    target_index: np.ndarray  # (K,) which asked pose each solution reaches

    @property
    def found(self) -> bool:
        return len(self.q) > 0

    def best_per_target(self) -> dict[int, np.ndarray]:
        out: dict[int, np.ndarray] = {}
        for q, i in zip(self.q, self.target_index):
            out.setdefault(int(i), q)
        return out


def rotation_error(R_target: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """Axis-angle vector (B, 3) of R_target R^T, in the base frame (robust up to pi)."""
    from pytorch_kinematics.transforms.rotation_conversions import matrix_to_quaternion, quaternion_to_axis_angle

    quat = matrix_to_quaternion(R_target @ R.transpose(1, 2))
    quat = torch.where(quat[:, :1] < 0, -quat, quat)  # the short way round
    return quaternion_to_axis_angle(quat)


def pose_errors(robot: PandaModel, q: torch.Tensor, T_target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Position error (m) and rotation error (rad) of the TCP, each (B,)."""
    T = robot.link_poses(q)[robot.tcp_link]
    return (T_target[:, :3, 3] - T[:, :3, 3]).norm(dim=1), rotation_error(T_target[:, :3, :3], T[:, :3, :3]).norm(dim=1)


def solve_ik(robot: PandaModel, T_base_tcp, checker=None, q_seed=None, n_seeds: int = 32,
             rng: np.random.Generator | None = None, max_iters: int = 150, damping: float = 0.02,
             pos_tol: float = POS_TOL, rot_tol: float = ROT_TOL) -> IKResult:
    """Solve for every target pose in ``T_base_tcp`` ((4, 4) or (G, 4, 4)) from ``n_seeds`` starts.

    Seeds: ``q_seed`` (if given: (7,) for every target or (G, 7), one per target) plus
    uniform samples inside the joint limits from ``rng``. Solutions are ranked by their
    distance to the target's own seed.
    """
    if rng is None:
        rng = np.random.default_rng(0)
    targets = np.asarray(T_base_tcp, dtype=float).reshape(-1, 4, 4)
    G = len(targets)
    q_min, q_max = robot.q_min, robot.q_max
    seeds = np.tile(rng.uniform(q_min, q_max, size=(n_seeds, 7)), (G, 1, 1))  # (G, S, 7)
    ref = np.broadcast_to((q_min + q_max) / 2, (G, 7))
    if q_seed is not None:
        ref = np.clip(np.broadcast_to(np.asarray(q_seed, float), (G, 7)), q_min, q_max)
        seeds[:, 0] = ref
    q = torch.as_tensor(seeds.reshape(-1, 7).copy())  # target-major: row = g * n_seeds + s
    target_index = np.repeat(np.arange(G), n_seeds)
    T_t = torch.as_tensor(targets[target_index])
    lo, hi = torch.as_tensor(q_min), torch.as_tensor(q_max)
    eye = torch.eye(6, dtype=torch.float64)
    active = torch.ones(len(q), dtype=torch.bool)
    # Seeds stuck at a joint limit or in a local minimum stop early: every STALL_WINDOW
    # iterations a seed must have cut its error by STALL_RATIO or it is dropped.
    err_then = torch.full((len(q),), float("inf"), dtype=torch.float64)
    for iteration in range(max_iters):
        idx = torch.nonzero(active, as_tuple=True)[0]
        if len(idx) == 0:
            break
        qa = q[idx]
        poses = robot.link_poses(qa)
        T = poses[robot.tcp_link]
        e_pos = T_t[idx, :3, 3] - T[:, :3, 3]
        e_rot = rotation_error(T_t[idx, :3, :3], T[:, :3, :3])
        done = (e_pos.norm(dim=1) < pos_tol * 0.5) & (e_rot.norm(dim=1) < rot_tol * 0.5)
        err = torch.cat([e_pos, e_rot], 1)
        if iteration % STALL_WINDOW == 0:
            err_now = e_pos.norm(dim=1) + 0.1 * e_rot.norm(dim=1)
            stalled = (err_now > STALL_RATIO * err_then[idx]) & ~done
            err_then[idx] = err_now
            active[idx[stalled]] = False
        J = robot.tcp_jacobian(qa, poses)
        JJt = J @ J.transpose(1, 2) + (damping ** 2) * eye
        dq = (J.transpose(1, 2) @ torch.linalg.solve(JJt, err[..., None]))[..., 0]
        # Limit the step so the linearisation holds.
        dq = dq * (0.4 / dq.abs().amax(dim=1, keepdim=True).clamp(min=0.4))
        q[idx] = torch.where(done[:, None], qa, torch.minimum(torch.maximum(qa + dq, lo), hi))
        active[idx[done]] = False
    e_pos, e_rot = pose_errors(robot, q, T_t)
    ok = ((e_pos <= pos_tol) & (e_rot <= rot_tol)).numpy() & robot.within_limits(q.numpy())
    q_np = q.numpy()
    if checker is not None and ok.any():
        ok[ok] = checker.valid(q_np[ok])
    q_np, target_index = q_np[ok], target_index[ok]
    ref = ref[target_index]
    # Best first: by target order (callers sort targets by preference), then distance to the seed.
    order = np.lexsort((np.abs(q_np - ref).sum(axis=1), target_index))
    q_np, target_index = q_np[order], target_index[order]
    # Drop duplicates (seeds that converged to the same solution).
    keep = []
    for i in range(len(q_np)):
        if not any(target_index[j] == target_index[i] and np.abs(q_np[j] - q_np[i]).max() < 1e-3 for j in keep):
            keep.append(i)
    return IKResult(q_np[keep], target_index[keep])
