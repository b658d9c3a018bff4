"""The trajectory optimiser's Adam loop over fixed-shape tensors, replayable as a CUDA graph.

``trajopt._Costs`` measures only the sphere-obstacle and sphere-sphere pairs that can cost
something: pair lists found by ``torch.nonzero``, whose lengths the host must read every
iteration (on a GPU, a sync and dozens of small launches per call; most of a plan's time).
``FixedShapeCosts`` computes the same costs with every shape fixed by the problem sizes:

- world: per configuration and robot link (``SphereGroups``: the link's spheres around
  their mean), the exact distance from the link's centre to every obstacle less the
  link's reach, then the ``max_obstacles`` nearest obstacles of each kind (``topk``), and
  the exact distances of the link's spheres to those. An obstacle beyond the horizon of
  the link's bounding sphere costs 0 for each of its spheres (the distance is
  1-Lipschitz), so the costs are the sparse path's unless more than ``max_obstacles``
  obstacles of a kind are that near one link: those are counted (``over_cap``, per
  problem), not hidden;
- self-collision: every sphere pair the robot model checks, masked by the cost itself;
- the carried object's spheres: one group, as a link.

Sums run in another order than the sparse path's, so the two agree to float rounding,
not bitwise: the default configuration keeps the sparse path (its shipped records).

``optimise_fixed_shape`` runs Adam in blocks of ``CHECK_EVERY`` iterations, the
convergence test (the sparse loop's: the summed cost under ``1 - converged`` of the
previous test's) at each block's last iteration, decided on the device: one host read per
block. On CUDA with ``cuda_graph`` the block is captured once per problem batch and
replayed (the world's tensors, the trajectories and Adam's moments are the graph's
static inputs); elsewhere the same block runs eagerly, so the CPU runs and tests the code
the graph replays.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from .distance import FAR, SphereGroups, _smooth_norm, collision_cost
from .trajopt import _Costs

CHECK_EVERY = 10  # iterations between convergence tests (the sparse loop's ``it % 10 == 9``)
BETA1, BETA2 = 0.9, 0.999


class _Groups:
    """Spheres in fixed groups: ``table`` (G, W) sphere indices (padded, ``valid``),
    ``mean`` (G, S) the group centre's weights, ``slots`` the valid (G * W) entries in
    sphere order."""

    def __init__(self, table: torch.Tensor, valid: torch.Tensor, mean: torch.Tensor):
        self.table, self.valid, self.mean = table, valid, mean
        self.flat_table = table.reshape(-1)
        self.slots = torch.nonzero(valid.reshape(-1), as_tuple=True)[0]  # once, at construction


class FixedShapeCosts(_Costs):
    """``trajopt._Costs`` with fixed-shape world and self-collision parts (module docstring):
    the smoothness and limit terms are its own."""

    def __init__(self, robot, world, cfg, q_min, q_max, max_obstacles: int):
        super().__init__(robot, world, cfg, q_min, q_max)
        dev = robot.device
        self.max_obstacles = max_obstacles
        g = robot.groups
        self.link_groups = _Groups(g.table, g.valid, g.mean)
        M = robot.att_c.shape[1]
        self.att_groups = _Groups(torch.arange(M, device=dev)[None], torch.ones((1, M), dtype=torch.bool, device=dev),
                                  torch.full((1, M), 1.0 / max(M, 1), **self.dd))
        self.self_a = robot.pair_table[..., 0][robot.pair_valid]
        self.self_b = robot.pair_table[..., 1][robot.pair_valid]
        self.self_r = robot.radii.index_select(0, self.self_a) + robot.radii.index_select(0, self.self_b)
        # Per problem: (configuration, link, kind) triples with more near obstacles than the cap.
        self.over_cap = torch.zeros(robot.P, dtype=torch.long, device=dev)

    def world_penalty(self, centers, radii, cache=None):
        return self._penalty(centers, radii, self.link_groups)

    def attached_penalty(self, att, radii):
        return self._penalty(att, radii, self.att_groups)

    def self_penalty(self, centers, cache=None):
        S = centers.shape[-2]
        c = centers.reshape(-1, S, 3)
        d = _smooth_norm(c.index_select(1, self.self_a) - c.index_select(1, self.self_b)) - self.self_r
        return collision_cost(d + self.cfg.self_tolerance, 0.01).sum(1)

    def _penalty(self, points: torch.Tensor, radii: torch.Tensor, groups: _Groups) -> torch.Tensor:
        """(P, N) summed collision cost of spheres (P, N, 3) of radii (P, N), N = C * S."""
        eta, world = self.cfg.eta, self.world
        P, N, _ = points.shape
        G, W = groups.table.shape
        S = groups.mean.shape[1]
        C = N // S
        x = points.reshape(P, C, S, 3)
        r = radii.reshape(P, C, S)
        member_x = x.index_select(2, groups.flat_table).reshape(P, C, G, W, 3)
        member_r = r.index_select(2, groups.flat_table).reshape(P, C, G, W)
        with torch.no_grad():
            centre = torch.einsum("gs,pcsi->pcgi", groups.mean, x.detach())
            reach = ((member_x.detach() - centre[:, :, :, None]).norm(dim=-1) + member_r)
            reach = reach.masked_fill(~groups.valid, -FAR).amax(dim=3)  # (P, C, G)
        per_member = torch.zeros((P, C, G, W), device=points.device, dtype=points.dtype)
        horizon = eta + SphereGroups.SLACK
        for kind in world.kinds:
            O, k = kind.O, min(self.max_obstacles, kind.O)
            with torch.no_grad():
                # Bounding spheres first (padding obstacles sit far away), then the exact distance.
                bound = (torch.cdist(centre.reshape(P, C * G, 3), kind.bound_c) - kind.bound_r[:, None]
                         - reach.reshape(P, C * G, 1))
                exact = _group_distance(kind, centre.reshape(P, C * G, 3)) - reach.reshape(P, C * G, 1)
                score = torch.where(bound < horizon, exact, torch.full_like(exact, FAR)).reshape(P, C, G, O)
                self.over_cap += ((score < horizon).sum(dim=3) > k).sum(dim=(1, 2))
                score, nearest = score.topk(k, dim=3, largest=False)  # (P, C, G, k)
            d = _member_distance(kind, member_x.reshape(P, C * G, W, 3), nearest.reshape(P, C * G, k))
            d = d.reshape(P, C, G, W, k)
            use = (score < horizon)[:, :, :, None] & groups.valid[:, :, None]
            cost = collision_cost(d - member_r[..., None], eta)
            per_member = per_member + torch.where(use, cost, torch.zeros_like(cost)).sum(dim=4)
        out = per_member.reshape(P, C, G * W).index_select(2, groups.slots).reshape(P, N)
        if world.grid is not None:
            out = out + collision_cost(world.grid_distance(points) - radii.reshape(P, N), eta)
        return out


def _group_distance(kind, x: torch.Tensor) -> torch.Tensor:
    """(P, A, O) exact distance of points ``x`` (P, A, 3) to every obstacle of ``kind``."""
    P, A, _ = x.shape
    O = kind.O
    if kind.kind == "convex":  # one batched matrix product per problem: every point, every plane
        planes = kind.t["planes"]  # (P, O, K, 4)
        d = torch.einsum("pai,poki->paok", x, planes[..., :3]) - planes[:, None, :, :, 3]
        d = d.amax(dim=3)
        if kind.reduced:
            d = torch.maximum(d, torch.cdist(x, kind.bound_c) - kind.bound_r[:, None])
        return d
    p = torch.arange(P, device=x.device)[:, None, None].expand(P, A, O).reshape(-1)
    o = torch.arange(O, device=x.device).expand(P, A, O).reshape(-1)
    return kind.exact(x[:, :, None].expand(P, A, O, 3).reshape(-1, 3), p, o).reshape(P, A, O)


def _member_distance(kind, x: torch.Tensor, o: torch.Tensor) -> torch.Tensor:
    """(P, A, W, k) exact distance of points ``x`` (P, A, W, 3) to obstacles ``o`` (P, A, k)
    of ``kind`` (the W points of a row share its k obstacles)."""
    P, A, W, _ = x.shape
    k = o.shape[2]
    po = (torch.arange(P, device=x.device)[:, None, None] * kind.O + o).reshape(-1)
    if kind.kind == "convex":  # the rows' planes gathered once, then a batched matrix product
        planes = kind.flat["planes"].index_select(0, po).reshape(P, A, k, -1, 4)
        d = torch.einsum("pawi,pamji->pawmj", x, planes[..., :3]) - planes[:, :, None, :, :, 3]
        d = d.amax(dim=4)
        if kind.reduced:
            centre = kind.flat_bound_c.index_select(0, po).reshape(P, A, 1, k, 3)
            bound_r = kind.flat_bound_r.index_select(0, po).reshape(P, A, 1, k)
            d = torch.maximum(d, _smooth_norm(x[:, :, :, None] - centre) - bound_r)
        return d
    p = torch.arange(P, device=x.device)[:, None, None, None].expand(P, A, W, k).reshape(-1)
    xm = x[:, :, :, None].expand(P, A, W, k, 3).reshape(-1, 3)
    return kind.exact(xm, p, o[:, :, None].expand(P, A, W, k).reshape(-1)).reshape(P, A, W, k)


class _AdamLoop:
    """Adam on the interior waypoints in blocks of ``CHECK_EVERY`` iterations; every tensor
    a block reads or writes is allocated here once (a CUDA graph's static inputs)."""

    def __init__(self, costs, interior: torch.Tensor, start: torch.Tensor, goal: torch.Tensor, cfg):
        self.costs, self.cfg = costs, cfg
        self.start, self.goal = start, goal
        self.interior = interior.clone()
        self.m, self.v = torch.zeros_like(interior), torch.zeros_like(interior)
        dev = interior.device
        self.previous = torch.full((), float("inf"), dtype=torch.float64, device=dev)
        self.stop = torch.zeros((), dtype=torch.bool, device=dev)
        # Adam's bias corrections of every iteration, and the current block's (a static input).
        it = np.arange(cfg.opt_iters + CHECK_EVERY) + 1
        table = np.stack([1 - BETA1 ** it, 1 - BETA2 ** it], axis=1)
        self.corrections = torch.as_tensor(table, device=dev, dtype=interior.dtype)
        self.block_corrections = self.corrections[:CHECK_EVERY].clone()

    def block(self, n: int, check: bool) -> None:
        """``n`` iterations from the state; with ``check``, the last one tests convergence and,
        converged, leaves the state as it was before its step (the sparse loop's ``break``)."""
        cfg, q_lo, q_hi = self.cfg, self.costs.q_min, self.costs.q_max
        interior = self.interior
        for j in range(n):
            x = interior.detach().requires_grad_(True)
            total, _ = self.costs(torch.cat([self.start, x, self.goal], dim=2))
            loss = total.sum()
            (grad,) = torch.autograd.grad(loss, x)
            with torch.no_grad():
                self.m.mul_(BETA1).add_(grad, alpha=1 - BETA1)
                self.v.mul_(BETA2).addcmul_(grad, grad, value=1 - BETA2)
                bc = self.block_corrections[j]
                step = cfg.lr * (self.m / bc[0]) / ((self.v / bc[1]).sqrt() + 1e-8)
                stepped = torch.minimum(torch.maximum(interior - step, q_lo), q_hi)
                if check and j == n - 1:  # in float64, as the sparse loop's Python floats
                    value = loss.detach().double()
                    stop = value > (1 - cfg.converged) * self.previous
                    self.stop.copy_(stop)
                    self.previous.copy_(torch.where(stop, self.previous, value))
                    stepped = torch.where(stop, interior, stepped)
                interior = stepped
        with torch.no_grad():
            self.interior.copy_(interior)

    def _state(self) -> list[torch.Tensor]:
        return [self.interior, self.m, self.v, self.previous, self.stop, self.costs.over_cap]

    def capture(self) -> "torch.cuda.CUDAGraph":
        """One full block as a CUDA graph; the state is as before (warm-up runs on copies)."""
        saved = [t.clone() for t in self._state()]
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        # Warm-up (autograd's and the libraries' lazy set-up must not happen during capture):
        # one iteration with the test is every kernel the block launches; ten would cost as
        # much as the eager block, once per problem batch.
        with torch.cuda.stream(side):
            self.block(1, check=True)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self.block(CHECK_EVERY, check=True)
        for t, s in zip(self._state(), saved):
            t.copy_(s)
        return graph

    def run(self, capture: bool, check_time: Callable[[], None]) -> torch.Tensor:
        """All ``opt_iters`` iterations (fewer when converged); the final interior."""
        full, tail = divmod(self.cfg.opt_iters, CHECK_EVERY)
        graph = self.capture() if capture and full else None
        for b in range(full):
            check_time()
            self.block_corrections.copy_(self.corrections[b * CHECK_EVERY: (b + 1) * CHECK_EVERY])
            if graph is not None:
                graph.replay()
            else:
                self.block(CHECK_EVERY, check=True)
            if bool(self.stop):  # the one host read of a block
                return self.interior
        if tail:
            check_time()
            self.block_corrections.copy_(self.corrections[full * CHECK_EVERY: (full + 1) * CHECK_EVERY])
            self.block(tail, check=False)
        return self.interior


def optimise_fixed_shape(costs, interior: torch.Tensor, start: torch.Tensor, goal: torch.Tensor, cfg,
                         check_time: Callable[[], None]) -> tuple[torch.Tensor, torch.Tensor]:
    """Adam on ``interior`` (P, S, T - 2, 7) between ``start`` and ``goal`` (P, S, 1, 7) with
    the fixed-shape costs of ``costs`` (a ``trajopt._Costs``); a CUDA graph when ``cfg.cuda_graph``
    and the tensors are on CUDA. ``check_time`` raises past the deadline (between blocks).
    Returns the final interior and, per problem, the (configuration, link, kind) triples that
    had more near obstacles than ``cfg.max_obstacles`` (summed over iterations)."""
    fixed = FixedShapeCosts(costs.robot, costs.world, cfg, costs.q_min, costs.q_max, cfg.max_obstacles)
    loop = _AdamLoop(fixed, interior, start, goal, cfg)
    capture = bool(cfg.cuda_graph) and interior.is_cuda
    return loop.run(capture, check_time), fixed.over_cap
