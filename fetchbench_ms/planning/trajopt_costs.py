"""The trajectory optimiser's cost of a batch of trajectories (``TrajectoryCosts``): the world's
and the robot's own collision costs at waypoints and between them, the joint limits, and the
smoothness terms. Its world and self-collision parts use the sparse pair lists of
``distance.py`` (fast on a CPU); ``trajopt_graph.FixedShapeCosts`` overrides them with
fixed-shape tensors. Both the optimiser (``trajopt``) and its fixed-shape loop
(``trajopt_graph``) build on this module, which imports neither.
"""
from __future__ import annotations

import torch

from .distance import PairCache, TorchRobot, TorchWorld, collision_cost


class TrajectoryCosts:
    """Trajectory costs for a batch of problems (P, B trajectories each), weighted by ``cfg``
    (a ``trajopt.TrajoptConfig``)."""

    def __init__(self, robot: TorchRobot, world: TorchWorld, cfg, q_min, q_max):
        self.robot, self.world, self.cfg = robot, world, cfg
        dd = dict(device=robot.device, dtype=robot.dtype)
        self.q_min, self.q_max = torch.as_tensor(q_min, **dd), torch.as_tensor(q_max, **dd)
        self.dd = dd

    def dense(self, traj: torch.Tensor, k: int | None = None) -> torch.Tensor:
        """(P, B, (T-1)*k + 1, 7): waypoints and ``k - 1`` points between neighbours."""
        k = k or self.cfg.collision_substeps
        sub = torch.arange(k, **self.dd) / k  # fractions between neighbouring waypoints
        a, b = traj[:, :, :-1], traj[:, :, 1:]
        mid = a[:, :, :, None] + sub[:, None] * (b - a)[:, :, :, None]
        return torch.cat([mid.flatten(2, 3), traj[:, :, -1:]], dim=2)

    def __call__(self, traj: torch.Tensor, cache: PairCache | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(total cost (P, B), collision part (P, B)) of trajectories (P, B, T, 7); ``cache``
        keeps the world broad phase's pairs between calls on the same trajectories."""
        cfg, robot = self.cfg, self.robot
        P, B, T, _ = traj.shape
        q = self.dense(traj)
        n = q.shape[2]
        centers, att = robot.spheres(q.reshape(P, B * n, 7))
        S = centers.shape[2]
        radii = (robot.world_radii + robot.margin[:, None])[:, None].expand(P, B * n, S)
        coll = self.world_penalty(centers.reshape(P, -1, 3), radii, cache).reshape(P, B, -1).sum(2)
        self_cost = self.self_penalty(centers, cache).reshape(P, B, n).sum(2)
        if att is not None:
            M = att.shape[2]
            r_att = (robot.att_r + robot.margin[:, None])[:, None].expand(P, B * n, M)
            coll = coll + self.attached_penalty(att.reshape(P, -1, 3), r_att).reshape(P, B, -1).sum(2)
            d_arm = robot.attachment_arm_distance(centers, att)
            self_cost = self_cost + collision_cost(d_arm, 0.01).reshape(P, B, -1).sum(2)
        # Normalise by the samples per trajectory so weights do not depend on its length.
        coll, self_cost = coll / n, self_cost / n
        limits = ((traj - self.q_max).clamp(min=0) ** 2 + (self.q_min - traj).clamp(min=0) ** 2).sum((2, 3))
        vel = torch.diff(traj, dim=2)
        acc = torch.diff(vel, dim=2)
        jerk = torch.diff(acc, dim=2)
        # Integrals of squared derivatives over a trajectory of unit duration (dt = 1 / (T - 1)).
        h = T - 1
        smooth = (cfg.w_velocity * (vel ** 2).sum((2, 3)) * h + cfg.w_acceleration * (acc ** 2).sum((2, 3)) * h ** 3
                  + cfg.w_jerk * (jerk ** 2).sum((2, 3)) * h ** 5)
        collision = cfg.w_collision * coll + cfg.w_self * self_cost
        return collision + cfg.w_limits * limits + smooth, collision

    # The world and self-collision parts, per sphere or configuration: the sparse pair lists
    # of ``distance.py`` here (fast on a CPU); ``trajopt_graph.FixedShapeCosts`` overrides
    # them with fixed-shape tensors (no host syncs, capturable in a CUDA graph).
    def world_penalty(self, centers: torch.Tensor, radii: torch.Tensor, cache: PairCache | None) -> torch.Tensor:
        """(P, N) collision cost of the robot's spheres (P, N, 3) of radii (P, N)."""
        return self.world.penalty(centers, radii, self.cfg.eta, self.robot.groups, cache)

    def attached_penalty(self, att: torch.Tensor, radii: torch.Tensor) -> torch.Tensor:
        """(P, N) collision cost of the carried object's spheres (P, N, 3)."""
        return self.world.penalty(att, radii, self.cfg.eta)

    def self_penalty(self, centers: torch.Tensor, cache: PairCache | None) -> torch.Tensor:
        """(P * B * n,) self-collision cost per configuration of sphere centres (P, B * n, S, 3)."""
        # Only the pairs nearer than the cost's activation (the rest cost exactly 0), with a
        # 0.1 mm margin for float rounding.
        cfg, robot = self.cfg, self.robot
        horizon = 0.01 - cfg.self_tolerance
        idx, d_self = robot.self_pairs(centers, horizon, within=horizon + 1e-4, cache=cache)
        per_config = torch.zeros(centers.shape[0] * centers.shape[1], device=centers.device, dtype=centers.dtype)
        return per_config.index_add(0, idx, collision_cost(d_self + cfg.self_tolerance, 0.01))
