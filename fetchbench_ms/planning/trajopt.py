"""A cuRobo-style trajectory optimiser: many seeds per problem, a particle (MPPI) warm
start, then Adam on a fixed-length joint trajectory, batched over problems, in torch on
any device (CUDA when there is one).

The optimised variable is the interior of a ``n_waypoints`` joint trajectory whose ends
are the start and one goal of the problem's goal set (each seed is tied to one goal).
Costs, summed per trajectory:
- world collision of every robot sphere (and of the carried object's spheres) at every
  waypoint and ``collision_substeps - 1`` points between neighbours: CHOMP's / cuRobo's
  smooth cost of the signed distance with activation distance ``eta`` (``distance.py``);
- self-collision of the sphere pairs that can touch, and carried object vs arm; sphere
  overlap up to ``self_tolerance`` is free (the spheres are conservative: about a third of
  valid IK solutions overlap; the exact check below decides);
- joint limits (and a projection into them after every step);
- smoothness: squared finite-difference velocity, acceleration and jerk.

Seeds per problem: the straight line to each goal, then random via points around the
midpoint. The best seeds (collision-free under the spheres first, then shortest) are
checked by the exact checker (``CollisionChecker.valid`` densely along every segment, as
RRTConnect's paths are), shortcut to few waypoints, and returned as the same
``PlanResult`` RRTConnect returns; execution time-parametrises it with
``timing.time_parametrize`` like any plan. If no seed passes, an optional RRTConnect
fallback searches with the caller's collision-check budget (cuRobo falls back to a graph
planner). Starts the spheres call invalid are escaped first, as ``plan_rrtconnect`` does; a
straight segment that is free is returned at once ("direct").

Budgets are counts, so a plan does not depend on the machine's speed or load: the seeds,
particles and iterations of ``TrajoptConfig`` (the same on every device: CPU and CUDA run the
same optimisation, up to their floating-point arithmetic) and the fallback's collision
checks. The time limit is a safety net only: a plan it cuts short has status ``timeout``.

``TrajoptConfig.phase_times`` reports where a plan's wall time goes, phase by phase
(``PHASES``), in ``PlanResult.extras["phase_s"]``; ``extras`` also says how the fixed-shape
loop ran (``loop``, ``over_cap``) and which verified seed was taken (``rank``).
"""
from __future__ import annotations

import os
import time
import zlib
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import torch

from .checker import CollisionChecker
from .distance import PairCache, TorchRobot, TorchWorld
from .rrt import PlanRequest, PlanResult, escape_start, path_valid, plan_rrtconnect
from .trajopt_costs import TrajectoryCosts
from .trajopt_graph import GRAPH_POOLS, fixed_shape_costs, optimise_fixed_shape


def default_device() -> str:
    """``$FETCHBENCH_TRAJOPT_DEVICE`` if set, else CUDA when available, else CPU."""
    return os.environ.get("FETCHBENCH_TRAJOPT_DEVICE") or ("cuda" if torch.cuda.is_available() else "cpu")


#: The counts a run names with the planner option ``trajopt_counts=SEEDSxITERSxSUBSTEPS``
#: (``solutions.planner_options``): ``TrajoptConfig``'s ``seeds``, ``opt_iters`` and
#: ``collision_substeps``.
COUNT_FIELDS = ("seeds", "opt_iters", "collision_substeps")

#: Twice the defaults' seeds and iterations and 3 collision points a segment: 2-3x the work
#: for no better plans. On val 0:120 they solve 91 of 102 problems against the defaults' 92,
#: with the same median C-space length and finer-check validity
#: (results/planning/bench-trajopt-cpu1-val120-{16seeds,counts}.json); test runs that carry
#: ``trajopt_counts=16x80x3`` were made with them.
FULL_COUNTS = {"seeds": 16, "opt_iters": 80, "collision_substeps": 3}


def counts_config(counts: str | None, **fields) -> "TrajoptConfig":
    """The ``TrajoptConfig`` of a ``trajopt_counts`` value (``"16x80x3"``: seeds, Adam
    iterations, collision points a segment; None: the defaults), with ``fields`` set too."""
    if counts:
        fields = {**dict(zip(COUNT_FIELDS, (int(n) for n in counts.split("x")))), **fields}
    return TrajoptConfig(**fields)


#: The Adam loops a run names with the planner option ``trajopt_loop`` (``eager`` by default):
#: ``graph`` steps it over fixed shapes, replayed as a CUDA graph on CUDA (uncaptured on a CPU,
#: where it is slower than ``eager``), with costs equal to the eager loop's up to float rounding;
#: ``grid`` reads the world in it through a distance grid of 1.5 cm (other costs: other plans);
#: ``cpu`` is the eager loop on the CPU whatever the machine has (``default_device``'s choice
#: is CUDA when there is one): a GPU node's evaluation workers each optimise on their own core,
#: leaving the GPU to the renderer (the same work: only the arithmetic differs).
#: The plans' checks stay the exact checker's in every loop (docs/trajopt-speed.md).
LOOPS = {
    "eager": {},
    "graph": {"fixed_shape": True, "cuda_graph": True},
    "grid": {"fixed_shape": True, "cuda_graph": True, "world_grid": 0.015},
    "cpu": {"device": "cpu"},
}


def counts_of(config: "TrajoptConfig") -> str:
    """``config``'s counts as ``trajopt_counts`` spells them (``"8x40x2"``)."""
    return "x".join(str(getattr(config, name)) for name in COUNT_FIELDS)


@dataclass
class TrajoptConfig:
    """The optimiser's work, in counts: the same on every device (the benchmark's rows must
    not depend on whether a GPU was there). About 1 s a searched problem on one CPU core
    (``FULL_COUNTS``: 1-3 s)."""

    n_waypoints: int = 24  # including start and goal
    seeds: int = 8  # per problem: the straight line to each goal, then random via points
    via_noise: float = 0.8  # rad: spread of the random seeds' via point around the midpoint
    collision_substeps: int = 2  # collision cost at waypoints and between them
    check_substeps: int = 8  # the spheres' verdict on the result, before the exact check
    mppi_iters: int = 3
    mppi_particles: int = 8  # per seed
    mppi_noise: float = 0.2  # rad: spread of the particles' smooth perturbations
    mppi_temperature: float = 0.1
    opt_iters: int = 40
    converged: float = 0.005  # stop early when 10 iterations improve the summed cost less than this
    lr: float = 0.04
    eta: float = 0.03  # m: activation distance of the collision cost
    self_tolerance: float = 0.015  # m of sphere overlap left to the exact self check
    w_collision: float = 3000.0
    w_self: float = 3000.0
    w_limits: float = 300.0
    w_velocity: float = 1.0
    w_acceleration: float = 0.01
    w_jerk: float = 0.0001
    max_configs: int = 50_000  # configurations per cost evaluation of the particles, at most
    # fixed_shape: elements of the broad phase's dense tensor (configurations x link groups x
    # obstacles x planes, every padded part) per cost evaluation of the particles, at most: a
    # piece's transient memory (2^25: 128 MB in float32; the padded world's particle round
    # would take ~0.6 GB at once). Each trajectory's costs are its own, whatever the pieces.
    max_dense: int = 1 << 25
    max_planes: int | None = 24  # per convex part (more are thinned: a larger, conservative polytope)
    max_verify: int = 4  # seeds checked by the exact checker per problem, best first
    # m: the Adam steps reuse the broad phase's sphere-obstacle pairs of a configuration until
    # one of its spheres moved this far (distance.PairCache): speed only, the costs are the same
    broad_phase_slack: float = 0.03
    resolution: float = 0.02  # rad: dense check step, as RRTConnect's
    # rad: the optimiser's checks (the direct segments, the chosen path, its shortcuts) also
    # certify the moves between their configurations free (``CollisionChecker.certified``:
    # sphere clearances against how far a move can carry a sphere), halving those they cannot
    # down to steps of this; None: the configurations only. Not the RRT fallback's checks.
    certify: float | None = None
    # The exact checks of a segment or path (the direct segments, the seeds' paths, the
    # shortcuts) compute this many of its configurations before the rest, spread over a
    # segment (``CollisionChecker.all_valid``), and stop there when one collides. Speed only:
    # the same answers and check counts.
    motion_check_first: int = 16
    rrt_fallback: bool = True
    # The Adam loop over fixed-shape tensors (``trajopt_graph``): no pair lists, one host read
    # per convergence test; costs equal to the default's up to float rounding, not bitwise.
    fixed_shape: bool = False
    cuda_graph: bool = False  # fixed_shape, with its blocks replayed as a CUDA graph (on CUDA only)
    max_obstacles: int = 16  # fixed_shape: nearest obstacles of each kind per robot link
    # fixed_shape: the broad phase measures the exact distance of only this many obstacles of a
    # kind per link, those of the nearest bounding spheres (None: of all); the costs are the same
    # unless more bounding spheres than this are within the horizon (counted in over_cap)
    broad_candidates: int | None = None
    # cuda_graph: worlds padded to these many boxes, cylinders, convex parts (a kind with more:
    # to the next multiple, its own graph), so that problems share one captured loop; val 0:20's
    # pre-grasp worlds have up to 46 boxes, 28 cylinders, 161 convex parts
    graph_capacity: tuple[int, int, int] = (48, 32, 192)
    graph_cache: int = 4  # cuda_graph: captured loops kept (by shape), least recently used dropped
    # cuda_graph: where a captured loop's memory comes from: "shared", one pool per process and
    # device for all its loops (a block leaves no tensor of the pool alive, and one loop replays
    # at a time), so the cached loops cost one loop's memory; "loop", a pool each (CUDA graphs'
    # default: the cache costs its loops' sum). The plans are the same either way.
    graph_pool: str = "shared"
    # fixed_shape: the Adam loop's cost function (forward and backward) through torch.compile with
    # this backend, e.g. "inductor" (fused kernels: Triton on CUDA, a C++ compiler on a CPU;
    # compiled once per loop shape); None: eager. The costs are the same up to float rounding.
    compile_backend: str | None = None
    # m: the costs read the whole world through one distance grid of this resolution, measured
    # once per world (``distance.baked_grid_values``; within half a cell diagonal of the exact
    # distance): one interpolation per sphere instead of its obstacles' formulas. None: exact.
    # The plan's checks stay exact (the checker's).
    world_grid: float | None = None
    device: str | None = None  # None: default_device()
    dtype: torch.dtype = torch.float32
    seed: int = 0
    # Wall seconds per phase into each result's ``extras["phase_s"]`` (``PHASES``): a report, the
    # plans are the same; on CUDA it waits for the device at every phase boundary
    phase_times: bool = False

    def __post_init__(self):
        if self.graph_pool not in GRAPH_POOLS:
            raise ValueError(f"unknown graph_pool {self.graph_pool!r}; valid: {', '.join(GRAPH_POOLS)}")
        if self.certify is not None and not self.certify > 0:
            raise ValueError(f"certify needs a step floor > 0 rad (or None), not {self.certify!r}")

    @classmethod
    def for_device(cls, device: str | None = None, **overrides) -> "TrajoptConfig":
        """The same counts on ``device`` (default ``default_device()``)."""
        return cls(device=device or default_device(), **overrides)


#: The phases ``TrajoptConfig.phase_times`` times, in a plan's order. ``BATCH_PHASES`` run once
#: for all the optimised problems of a batch (``batch_size`` in ``extras["phase_s"]``): each of
#: them reports the batch's seconds. The others are the problem's own.
PHASES = ("prepare", "world", "seeds", "particles", "adam", "final_costs", "to_host", "select", "fallback")
BATCH_PHASES = ("world", "seeds", "particles", "adam", "final_costs", "to_host")


class _PhaseTimer:
    """Wall seconds between phase boundaries (``TrajoptConfig.phase_times``); off, it does
    nothing (no sync). On CUDA each boundary waits for the device: a phase's kernels count
    to it, not to the next phase that reads a result back."""

    def __init__(self, on: bool, device: str | torch.device):
        self.on = on
        self.device = torch.device(device)
        self.batch: dict[str, float] = {}
        self.restart()

    def _now(self) -> float:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        return time.perf_counter()

    def restart(self) -> None:
        """A boundary whose seconds before it count to no phase."""
        if self.on:
            self._last = self._now()

    def lap(self, phase: str, pr: "_Problem | None" = None) -> None:
        """The seconds since the last boundary to ``phase``: of problem ``pr``, or of the batch."""
        if not self.on:
            return
        now = self._now()
        into = self.batch if pr is None else pr.extras.setdefault("phase_s", {})
        into[phase] = into.get(phase, 0.0) + now - self._last
        self._last = now

    def share(self, problems: list["_Problem"]) -> None:
        """The batch's phases into each of its optimised ``problems``' report."""
        if self.on:
            for pr in problems:
                pr.extras.setdefault("phase_s", {}).update(self.batch, batch_size=len(problems))


@dataclass
class _Problem:
    checker: CollisionChecker
    q_start: np.ndarray  # where the optimised part begins (after any escape)
    goals: np.ndarray  # valid goals (K, 7)
    goal_ids: np.ndarray  # their indices among the asked goals
    prefix: np.ndarray  # (0 or 1, 7): the original start when it was escaped
    t0: float
    n0: int
    result: PlanResult | None = None
    extras: dict = field(default_factory=dict)


def _smooth_basis(n_interior: int, n_knots: int) -> torch.Tensor:
    """(n_interior, n_knots) hat-function interpolation from knots to the interior
    waypoints, zero at both ends: smooth perturbations that keep start and goal."""
    s = np.linspace(0, 1, n_interior + 2)[1:-1]
    knots = np.linspace(0, 1, n_knots + 2)
    width = knots[1] - knots[0]
    return torch.as_tensor(np.clip(1 - np.abs(s[:, None] - knots[None, 1:-1]) / width, 0, None))


def _problem_seed(pr: _Problem, seed: int) -> int:
    """A seed from the problem's own numbers: its plan does not depend on its batch."""
    return zlib.crc32(np.ascontiguousarray(np.concatenate([pr.q_start, pr.goals.ravel()])).tobytes()) ^ seed


def _seeds(problems: list[_Problem], cfg: TrajoptConfig, q_min, q_max) -> tuple[np.ndarray, np.ndarray]:
    """(P, S, T, 7) seed trajectories and (P, S) goal index (into each problem's valid goals)."""
    T, S = cfg.n_waypoints, cfg.seeds
    s = np.linspace(0, 1, T)[:, None]
    out = np.empty((len(problems), S, T, 7))
    goal_of = np.empty((len(problems), S), dtype=int)
    for p, pr in enumerate(problems):
        rng = np.random.default_rng(_problem_seed(pr, cfg.seed))
        K = len(pr.goals)
        for i in range(S):
            g = i % K
            goal_of[p, i] = g
            a, b = pr.q_start, pr.goals[g]
            line = a + s * (b - a)
            if i >= K:  # a via point: the straight line bent through it (a parabola in s)
                via = np.clip(0.5 * (a + b) + rng.normal(0, cfg.via_noise, 7), q_min, q_max)
                line = line + 4 * s * (1 - s) * (via - 0.5 * (a + b))
            out[p, i] = line
            out[p, i, 0], out[p, i, -1] = a, b  # exactly (a + 1 * (b - a) need not be b)
    return out, goal_of


class _OutOfTime(Exception):
    """The wall-clock safety net stopped the optimisation (its result would depend on the machine)."""


def _optimise(problems: list[_Problem], robot_model, cfg: TrajoptConfig, deadline: float,
              timer: _PhaseTimer | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Seeds -> MPPI -> Adam for all problems at once. Returns trajectories (P, S, T, 7),
    their goal indices (P, S), total costs and smallest sphere clearance (P, S): self-
    collision spheres count only beyond ``self_tolerance``. Raises ``_OutOfTime`` past
    ``deadline`` (the safety net: a cut-short optimisation is not returned). ``timer``
    times the batch's phases."""
    device = torch.device(cfg.device or default_device())
    timer = timer or _PhaseTimer(False, device)
    dd = dict(device=device, dtype=cfg.dtype)
    checkers = [pr.checker for pr in problems]
    world = TorchWorld([c.world for c in checkers], [c.exclude for c in checkers], device, cfg.dtype,
                       max_planes=cfg.max_planes, baked_grid=cfg.world_grid)
    robot = TorchRobot(robot_model, checkers, device, cfg.dtype)
    costs = TrajectoryCosts(robot, world, cfg, robot_model.q_min, robot_model.q_max)
    fixed = None
    if cfg.fixed_shape or cfg.cuda_graph:  # the warm start and Adam over fixed shapes: no host syncs
        fixed, over_capacity = fixed_shape_costs(costs, cfg)
        for pr in problems:
            pr.extras["over_capacity"] = over_capacity
    timer.lap("world")
    warm_costs = fixed if fixed is not None else costs
    seeds, goal_of = _seeds(problems, cfg, robot_model.q_min, robot_model.q_max)
    P, S, T, _ = seeds.shape
    traj = torch.as_tensor(seeds, **dd)
    start, goal = traj[:, :, :1], traj[:, :, -1:]
    interior = traj[:, :, 1:-1].clone()
    q_lo, q_hi = costs.q_min, costs.q_max
    gens = [torch.Generator(device=device).manual_seed(_problem_seed(pr, cfg.seed)) for pr in problems]
    timer.lap("seeds")

    def full(x):
        return torch.cat([start, x, goal], dim=2)

    def particle_piece(per_traj: int) -> int:
        """Trajectories (of each problem) per cost evaluation of the particles."""
        piece = cfg.max_configs // per_traj
        dense = fixed.dense_per_config() if fixed is not None else 0
        if dense:
            piece = min(piece, cfg.max_dense // (per_traj * dense))
        return max(1, piece)

    # Particle warm start: smooth perturbations of each seed, exponentially weighted.
    basis = _smooth_basis(T - 2, 4).to(**dd)
    N = cfg.mppi_particles
    with torch.no_grad():
        for _ in range(cfg.mppi_iters):
            if time.perf_counter() > deadline:
                raise _OutOfTime
            knots = torch.stack([torch.randn((S, N, 4, 7), generator=g, **dd) for g in gens]) * cfg.mppi_noise
            knots[:, :, 0] = 0  # the current mean is a particle
            noise = torch.einsum("tk,psnkj->psntj", basis, knots)
            particles = torch.minimum(torch.maximum(interior[:, :, None] + noise, q_lo), q_hi)
            x = particles.reshape(P, S * N, T - 2, 7)
            x = torch.cat([start.repeat_interleave(N, 1), x, goal.repeat_interleave(N, 1)], dim=2)
            # In pieces of at most ``max_configs`` configurations (and ``max_dense`` broad-phase
            # elements): the pair tensors of a large batch would not fit a GPU at once.
            per_traj = P * ((T - 1) * cfg.collision_substeps + 1)
            c = torch.cat([warm_costs(part)[0] for part in x.split(particle_piece(per_traj), dim=1)], dim=1)
            c = c.reshape(P, S, N)
            spread = (c.mean(dim=2, keepdim=True) - c.amin(dim=2, keepdim=True)).clamp(min=1e-9)
            w = torch.softmax(-(c - c.amin(dim=2, keepdim=True)) / (cfg.mppi_temperature * spread), dim=2)
            interior = (w[..., None, None] * particles).sum(dim=2)
    timer.lap("particles")
    sparse_iters = cfg.opt_iters
    if fixed is not None:
        def check_time():
            if time.perf_counter() > deadline:
                raise _OutOfTime

        warm_over_cap = fixed.over_cap.clone()
        interior, over_cap, how = optimise_fixed_shape(fixed, interior, start, goal, cfg, check_time)
        for pr, n, w in zip(problems, over_cap.tolist(), warm_over_cap.tolist()):
            pr.extras.update(over_cap=n, over_cap_warm=w, loop=how)
        sparse_iters = 0  # done: the sparse loop below is the default's
    # Adam, written out: torch.optim's first use in a process imports torch._dynamo (~2 s).
    m, v = torch.zeros_like(interior), torch.zeros_like(interior)
    cache = PairCache(cfg.broad_phase_slack) if cfg.broad_phase_slack > 0 else None
    beta1, beta2, previous = 0.9, 0.999, float("inf")
    for it in range(sparse_iters):
        if time.perf_counter() > deadline:
            raise _OutOfTime
        x = interior.detach().requires_grad_(True)
        total, _ = costs(full(x), cache)
        loss = total.sum()
        (grad,) = torch.autograd.grad(loss, x)
        if it % 10 == 9:  # converged: under 0.5% better than 10 iterations ago
            if float(loss.detach()) > (1 - cfg.converged) * previous:
                break
            previous = float(loss.detach())
        with torch.no_grad():
            m.mul_(beta1).add_(grad, alpha=1 - beta1)
            v.mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            step = cfg.lr * (m / (1 - beta1 ** (it + 1))) / ((v / (1 - beta2 ** (it + 1))).sqrt() + 1e-8)
            interior = torch.minimum(torch.maximum(interior - step, q_lo), q_hi)
    timer.lap("adam")
    with torch.no_grad():
        traj = full(interior)
        total, _ = costs(traj)
        dense = costs.dense(traj, cfg.check_substeps)
        clearance = robot.clearance(dense.reshape(P, -1, 7), world, cfg.eta, cfg.self_tolerance)
        clearance = clearance.reshape(P, S, -1).amin(dim=2)
    clearance = clearance - robot.margin[:, None]
    timer.lap("final_costs")
    # Back to float64: the ends exactly as asked, the interior exactly within the limits.
    traj = np.clip(traj.double().cpu().numpy(), robot_model.q_min, robot_model.q_max)
    traj[:, :, 0], traj[:, :, -1] = seeds[:, :, 0], seeds[:, :, -1]
    total, clearance = total.double().cpu().numpy(), clearance.double().cpu().numpy()
    timer.lap("to_host")
    return traj, goal_of, total, clearance


def shortcut(checker: CollisionChecker, path: np.ndarray, resolution: float, first: int | None = None,
             certify: float | None = None) -> np.ndarray:
    """Fewer waypoints: from each kept waypoint, jump to the farthest of a few later ones
    whose straight segment is valid (the next one always is: the path was checked);
    ``first``, ``certify``: as ``CollisionChecker.all_valid``'s, spread over each segment. The candidate
    segments from a waypoint share one first batch (``first_valid_motion``: the answers and
    counts of checking them farthest first, in turn)."""
    keep, i, last = [0], 0, len(path) - 1
    while i < last:
        span = last - i
        far = [j for j in sorted({last, i + 3 * span // 4, i + span // 2, i + span // 4}, reverse=True) if j > i + 1]
        k = (checker.first_valid_motion(path[i], path[far], resolution, first, spread=True, certify=certify)
             if far else -1)
        i = far[k] if k >= 0 else i + 1
        keep.append(i)
    return path[keep]


def _prepare(checker, q_start, q_goals, start_tolerance, resolution, first: int,
             certify: float | None = None) -> _Problem:
    """Start escape, valid goals and the direct segment, as plan_rrtconnect does them."""
    t0, n0 = time.perf_counter(), checker.n_checked
    q_start = np.asarray(q_start, float).reshape(7)
    q_goals = np.asarray(q_goals, float).reshape(-1, 7)
    pr = _Problem(checker, q_start, q_goals[:0], np.zeros(0, int), np.zeros((0, 7)), t0, n0)

    def done(status, path=None, goal_index=-1):
        pr.result = PlanResult(status, path, time.perf_counter() - t0, checker.n_checked - n0, goal_index,
                               start_escaped=len(pr.prefix) > 0, planner="trajopt")
        return pr

    if not checker.valid(q_start)[0]:
        q_free = escape_start(checker, q_start, start_tolerance, resolution) if start_tolerance > 0 else None
        if q_free is None:
            return done("start_invalid")
        pr.prefix, pr.q_start = q_start[None], q_free
    ok = checker.valid(q_goals) if len(q_goals) else np.zeros(0, bool)
    pr.goal_ids = np.flatnonzero(ok)
    pr.goals = q_goals[pr.goal_ids]
    if len(pr.goal_ids) == 0:
        return done("no_valid_goal")
    k = checker.first_valid_motion(pr.q_start, pr.goals, resolution, first, spread=True, certify=certify)
    if k >= 0:
        return done("direct", np.concatenate([pr.prefix, [pr.q_start, pr.goals[k]]]), int(pr.goal_ids[k]))
    return pr


def _select(pr: _Problem, traj, goal_of, total, clearance, cfg: TrajoptConfig) -> None:
    """Exact-check the best seeds of one problem (free under the spheres first, shortest
    first); the first valid one, shortcut, is the plan."""
    length = np.abs(np.diff(traj, axis=1)).sum(axis=(1, 2))
    free = clearance > 0
    order = np.lexsort((np.where(free, length, total), ~free))
    checker = pr.checker
    for i in order[: cfg.max_verify]:
        if path_valid(checker, traj[i], cfg.resolution, cfg.motion_check_first, cfg.certify):
            path = shortcut(checker, traj[i], cfg.resolution, cfg.motion_check_first, cfg.certify)
            pr.result = PlanResult("solved", np.concatenate([pr.prefix, path]), time.perf_counter() - pr.t0,
                                   checker.n_checked - pr.n0, int(pr.goal_ids[goal_of[i]]),
                                   start_escaped=len(pr.prefix) > 0, planner="trajopt")
            pr.extras["rank"] = int(np.flatnonzero(order == i)[0])
            return


def plan_trajopt_batch(problems: Sequence[tuple], time_limit: float = 300.0, config: TrajoptConfig | None = None,
                       start_tolerance: float = 0.0, seed: int = 0, max_checks: int = 30000) -> list[PlanResult]:
    """Plan every problem ``(checker, q_start, q_goals)`` (goals (K, 7) or (7,), best first)
    with one batched optimisation; a ``PlanResult`` each, in order. A problem no seed solves
    goes to the RRTConnect fallback (``seed``, at most ``max_checks`` collision checks).
    ``time_limit`` (s, per batch) is the safety net: past it, the unsolved problems end
    ``timeout``."""
    cfg = config or TrajoptConfig.for_device()
    deadline = time.perf_counter() + time_limit
    timer = _PhaseTimer(cfg.phase_times, cfg.device or default_device())
    prepared = []
    for c, q, g in problems:
        prepared.append(_prepare(c, q, g, start_tolerance, cfg.resolution, cfg.motion_check_first, cfg.certify))
        timer.lap("prepare", prepared[-1])
    todo = [pr for pr in prepared if pr.result is None]
    out_of_time = False
    if todo:
        try:
            out = _optimise(todo, todo[0].checker.robot, cfg, deadline, timer)
        except _OutOfTime:
            out_of_time = True
        else:
            for p, pr in enumerate(todo):
                _select(pr, *(a[p] for a in out), cfg)
                timer.lap("select", pr)
    for pr in todo:
        if pr.result is None:
            _fallback(pr, cfg, deadline, out_of_time, seed, max_checks, timer)
    timer.share(todo)
    for pr in prepared:
        pr.result.extras = pr.extras
    return [pr.result for pr in prepared]


def _fallback(pr: _Problem, cfg: TrajoptConfig, deadline: float, out_of_time: bool, seed: int, max_checks: int,
              timer: _PhaseTimer) -> None:
    """The result of a problem no seed solved: RRTConnect's (``rrt_fallback``, time left),
    else ``timeout`` or ``budget``."""
    left = deadline - time.perf_counter()
    if cfg.rrt_fallback and not out_of_time and left > 0:
        timer.restart()
        rest = plan_rrtconnect(pr.checker, pr.q_start, pr.goals, left, cfg.resolution, seed=seed,
                               max_checks=max_checks)
        path = None if rest.path is None else np.concatenate([pr.prefix, rest.path])
        goal_index = int(pr.goal_ids[rest.goal_index]) if rest.path is not None else -1
        pr.result = PlanResult(rest.status, path, time.perf_counter() - pr.t0, pr.checker.n_checked - pr.n0,
                               goal_index, start_escaped=len(pr.prefix) > 0, planner="trajopt+rrtconnect")
        timer.lap("fallback", pr)
    else:
        status = "timeout" if out_of_time or left <= 0 else "budget"
        pr.result = PlanResult(status, None, time.perf_counter() - pr.t0, pr.checker.n_checked - pr.n0,
                               start_escaped=len(pr.prefix) > 0, planner="trajopt")


def plan_trajopt(checker: CollisionChecker, q_start, q_goals, time_limit: float = 300.0,
                 start_tolerance: float = 0.0, config: TrajoptConfig | None = None, seed: int = 0,
                 max_checks: int = 30000) -> PlanResult:
    """One problem; the signature of ``plan_rrtconnect``'s first arguments."""
    return plan_trajopt_batch([(checker, q_start, q_goals)], time_limit, config, start_tolerance, seed,
                              max_checks)[0]


def plan(request: PlanRequest) -> PlanResult:
    """The trajectory optimiser for the pipeline (``planning.rrt.PlanRequest``), with the
    run's ``trajopt_counts``, ``trajopt_loop`` and ``trajopt_certify`` (None: the defaults)."""
    fields = dict(LOOPS[request.options.get("trajopt_loop") or "eager"])
    certify = request.options.get("trajopt_certify")
    if certify is not None:
        fields["certify"] = None if certify == "off" else float(certify)
    config = counts_config(request.options.get("trajopt_counts"), **fields)
    return plan_trajopt(request.checker, request.q_start, request.q_goals, request.time_limit,
                        start_tolerance=request.start_tolerance, config=config, seed=request.seed,
                        max_checks=request.max_checks)


def plan_trajopt_to_pose(checker: CollisionChecker, q_start, T_base_tcp, time_limit: float = 300.0,
                         start_tolerance: float = 0.0, config: TrajoptConfig | None = None, n_ik_seeds: int = 32,
                         goal_set_size: int = 8) -> PlanResult:
    """A pose goal (the TCP at ``T_base_tcp`` (4, 4), or any of (G, 4, 4), best first): its
    collision-free IK solutions (``ik.solve_ik``, seeded from the start) become the goal
    set, nearest the start first; ``goal_index`` then indexes the target poses."""
    from .ik import solve_ik

    t0 = time.perf_counter()
    ik = solve_ik(checker.robot, T_base_tcp, checker=checker, q_seed=np.asarray(q_start, float), n_seeds=n_ik_seeds,
                  rng=np.random.default_rng((config or TrajoptConfig()).seed))
    if not ik.found:
        return PlanResult("no_valid_goal", None, time.perf_counter() - t0, 0, planner="trajopt")
    result = plan_trajopt(checker, q_start, ik.q[:goal_set_size], max(0.0, time_limit - (time.perf_counter() - t0)),
                          start_tolerance, config)
    result.planning_time = time.perf_counter() - t0
    if result.goal_index >= 0:
        result.goal_index = int(ik.target_index[result.goal_index])
    return result


__all__ = ["BATCH_PHASES", "COUNT_FIELDS", "FULL_COUNTS", "LOOPS", "PHASES", "TrajoptConfig", "counts_config", "counts_of",
           "default_device", "plan_trajopt", "plan_trajopt_batch", "plan_trajopt_to_pose", "shortcut"]
