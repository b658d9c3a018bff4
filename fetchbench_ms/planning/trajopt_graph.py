"""The trajectory optimiser's Adam loop over fixed-shape tensors, replayable as a CUDA graph.

``trajopt_costs.TrajectoryCosts`` measures only the sphere-obstacle and sphere-sphere pairs
that can cost something: pair lists found by ``torch.nonzero``, whose lengths the host must
read every iteration (on a GPU, a sync and dozens of small launches per call; most of a
plan's time).
``FixedShapeCosts`` computes the same costs with every shape fixed by the problem sizes:

- world: per configuration and robot link (``SphereGroups``: the link's spheres around
  their mean), the exact distance from the link's centre to every obstacle less the
  link's reach, then the ``max_obstacles`` nearest obstacles of each kind (``topk``), and
  the exact distances of the link's spheres to those. An obstacle beyond the horizon of
  the link's bounding sphere costs 0 for each of its spheres (the distance is
  1-Lipschitz), so the costs are the sparse path's unless more than ``max_obstacles``
  obstacles of a kind are that near one link: those are counted (``over_cap``, per
  problem), not hidden. With ``broad_candidates`` the link's centre is measured exactly
  against only that many obstacles of a kind, those of the nearest bounding spheres (a
  bounding sphere is never farther than its obstacle: the same costs unless more bounding
  spheres than that are within the horizon, also counted in ``over_cap``);
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

In both modes the particle warm start (``trajopt._optimise``) scores its particles with
these costs too: its rounds read nothing back to the host.

With ``cuda_graph`` the captured loop outlives its plan: the world is padded to fixed
capacities (``pad_world``: ``TrajoptConfig.graph_capacity`` boxes, cylinders and convex
parts, convex parts to ``max_planes`` planes; a kind with more obstacles is padded to the
next multiple of its capacity, a shape of its own), and ``GraphCache`` keeps the loops by
the shapes of every tensor they read, at most ``graph_cache`` of them (least recently used
dropped). Their graphs take their memory from one pool per process and device
(``graph_pool="shared"``): a block's tensors are all allocated before its capture and
updated in place, so a capture leaves nothing of the pool alive and the next capture reuses
its memory; the loops of a process cost the memory of its largest one, not their sum. A
problem of a cached shape copies its world, robot and seeds into that loop's buffers and
replays its graph: no capture. On a CPU the same cache and copies run, uncaptured (the
tests' view of the bookkeeping).
"""
from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from typing import Callable

import numpy as np
import torch

from .distance import (_FAR_CENTER, FAR, SphereGroups, TorchRobot, TorchWorld, _Primitives, _smooth_norm,
                       collision_cost, distance_to_every, plane_max)
from .trajopt_costs import TrajectoryCosts

#: ``TrajoptConfig.graph_pool``'s choices (``graph_pool``).
GRAPH_POOLS = ("shared", "loop")
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


class FixedShapeCosts(TrajectoryCosts):
    """``trajopt_costs.TrajectoryCosts`` with fixed-shape world and self-collision parts (module
    docstring): the smoothness and limit terms are its own."""

    def __init__(self, robot, world, cfg, q_min, q_max, max_obstacles: int):
        super().__init__(robot, world, cfg, q_min, q_max)
        dev = robot.device
        self.max_obstacles = max_obstacles
        self.broad_candidates = cfg.broad_candidates
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

    def dense_per_config(self) -> int:
        """Elements of ``_penalty``'s largest broad-phase tensor per configuration: each link
        group against every obstacle of a kind (``distance_to_every``; a convex part's every
        plane, 3 coordinates for the others). 0 for a world read through its grid alone."""
        G = self.link_groups.table.shape[0]
        return G * sum(kind.O * (kind.t["planes"].shape[2] if kind.kind == "convex" else 3)
                       for kind in self.world.kinds)

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
                near = bound < horizon
                if self.broad_candidates is not None and self.broad_candidates < O:
                    # The exact distance of only the nearest bounding spheres: a bounding sphere is
                    # never farther than its obstacle, so every obstacle within the horizon is among
                    # them unless more bounding spheres than that are (counted in over_cap).
                    kb = max(self.broad_candidates, k)
                    too_many = near.sum(dim=2) > kb
                    bound, candidates = bound.topk(kb, dim=2, largest=False)  # (P, C * G, kb)
                    exact = _member_distance(kind, centre.reshape(P, C * G, 1, 3), candidates)[:, :, 0]
                    exact = exact - reach.reshape(P, C * G, 1)
                    near = bound < horizon
                else:
                    too_many, candidates = None, None
                    exact = distance_to_every(kind, centre.reshape(P, C * G, 3)) - reach.reshape(P, C * G, 1)
                score = torch.where(near, exact, torch.full_like(exact, FAR)).reshape(P, C, G, -1)
                over = (score < horizon).sum(dim=3) > k
                if too_many is not None:
                    over = over | too_many.reshape(P, C, G)
                self.over_cap += over.sum(dim=(1, 2))
                score, nearest = score.topk(k, dim=3, largest=False)  # (P, C, G, k)
                if candidates is not None:  # back to the kind's obstacle indices
                    nearest = candidates.reshape(P, C, G, -1).gather(3, nearest)
            d = _member_distance(kind, member_x.reshape(P, C * G, W, 3), nearest.reshape(P, C * G, k))
            d = d.reshape(P, C, G, W, k)
            use = (score < horizon)[:, :, :, None] & groups.valid[:, :, None]
            cost = collision_cost(d - member_r[..., None], eta)
            per_member = per_member + torch.where(use, cost, torch.zeros_like(cost)).sum(dim=4)
        out = per_member.reshape(P, C, G * W).index_select(2, groups.slots).reshape(P, N)
        if world.grid is not None:
            out = out + collision_cost(world.grid_distance(points) - radii.reshape(P, N), eta)
        return out


def _member_distance(kind, x: torch.Tensor, o: torch.Tensor) -> torch.Tensor:
    """(P, A, W, k) exact distance of points ``x`` (P, A, W, 3) to obstacles ``o`` (P, A, k)
    of ``kind`` (the W points of a row share its k obstacles)."""
    P, A, W, _ = x.shape
    k = o.shape[2]
    po = (torch.arange(P, device=x.device)[:, None, None] * kind.O + o).reshape(-1)
    if kind.kind == "convex":  # the rows' planes gathered once, then a batched matrix product
        planes = kind.flat["planes"].index_select(0, po).reshape(P, A, k, -1, 4)
        if torch.compiler.is_compiling():
            d = plane_max(x[:, :, :, None, None], planes[:, :, None])
        else:
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
        # Compiled per loop, so a cached loop (the same tensors, new values) reuses its kernels.
        self.cost_fn = costs if cfg.compile_backend is None else torch.compile(
            costs.__call__, backend=cfg.compile_backend, dynamic=False)
        self.start, self.goal = start.clone(), goal.clone()
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

    def load(self, interior: torch.Tensor, start: torch.Tensor, goal: torch.Tensor) -> None:
        """Another problem's start into the same buffers (a captured graph's inputs): the
        state as ``__init__`` leaves it."""
        with torch.no_grad():
            self.interior.copy_(interior)
            self.start.copy_(start)
            self.goal.copy_(goal)
            self.m.zero_()
            self.v.zero_()
            self.previous.fill_(float("inf"))
            self.stop.zero_()
            self.costs.over_cap.zero_()

    def block(self, n: int, check: bool) -> None:
        """``n`` iterations from the state; with ``check``, the last one tests convergence and,
        converged, leaves the state as it was before its step (the sparse loop's ``break``)."""
        cfg, q_lo, q_hi = self.cfg, self.costs.q_min, self.costs.q_max
        interior = self.interior
        for j in range(n):
            x = interior.detach().requires_grad_(True)
            total, _ = self.cost_fn(torch.cat([self.start, x, self.goal], dim=2))
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
        side = warmup_stream(self.interior.device)
        side.wait_stream(torch.cuda.current_stream())
        # Warm-up (autograd's and the libraries' lazy set-up must not happen during capture):
        # one iteration with the test is every kernel the block launches; ten would cost as
        # much as the eager block, once per problem batch.
        with torch.cuda.stream(side):
            self.block(1, check=True)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, pool=graph_pool(self.cfg.graph_pool, self.interior.device)):
            self.block(CHECK_EVERY, check=True)
        for t, s in zip(self._state(), saved):
            t.copy_(s)
        return graph

    def run(self, capture: bool, check_time: Callable[[], None], graph=None) -> torch.Tensor:
        """All ``opt_iters`` iterations (fewer when converged); the final interior. ``graph``:
        one this loop captured before (its buffers now hold another problem)."""
        full, tail = divmod(self.cfg.opt_iters, CHECK_EVERY)
        if graph is None and capture and full:
            graph = self.capture()
        self.graph = graph
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


_POOLS: dict = {}
_WARMUP_STREAMS: dict = {}


def warmup_stream(device: torch.device):
    """The process's one side stream on ``device`` for the warm-up before a capture. One, not
    a new stream per capture: torch keeps a cuBLAS and a cuBLASLt workspace (32 MiB each on
    an H200) for every stream that ever ran a matrix product and never frees them: a stream
    per capture would keep 64 MB more after each one, up to torch's pool of 32 streams."""
    if device not in _WARMUP_STREAMS:
        _WARMUP_STREAMS[device] = torch.cuda.Stream(device=device)
    return _WARMUP_STREAMS[device]


def graph_pool(kind: str, device: torch.device):
    """The memory pool a loop's capture takes (``torch.cuda.graph``'s ``pool``): for "shared",
    the process's one pool on ``device`` (kept for the process, so its memory is reused by
    the next capture after a loop is dropped); for "loop", None (a pool of its own)."""
    if kind not in GRAPH_POOLS:
        raise ValueError(f"unknown graph_pool {kind!r}; valid: {', '.join(GRAPH_POOLS)}")
    if kind == "loop":
        return None
    if device not in _POOLS:
        _POOLS[device] = torch.cuda.graph_pool_handle()
    return _POOLS[device]


# -- one captured loop reused across problems --------------------------------------------------
#: The obstacle kinds of ``TorchWorld`` in its order, with each one's per-obstacle tensors' tails.
KIND_TAILS = {"box": {"R": (3, 3), "t": (3,), "half": (3,)},
              "cylinder": {"R": (3, 3), "t": (3,), "radius": (), "half_length": (), "capsule": ()},
              "convex": {"planes": None}}
PLANES_BUCKET = 8  # convex parts' plane counts are padded to a multiple of this when max_planes is None


def _bucket(n: int, cap: int) -> int:
    """``cap`` when ``n`` fits, else the next multiple of ``cap`` (a larger shape: its own graph)."""
    return cap * max(1, math.ceil(n / cap))


def pad_world(world: TorchWorld, capacity, max_planes: int | None) -> tuple[TorchWorld, bool]:
    """A copy of ``world`` whose obstacle kinds all exist (kinds of capacity 0 only where the
    world has some) and are padded to ``capacity`` (boxes, cylinders, convex parts; a kind
    with more obstacles than its capacity to the next multiple of it) and convex parts to
    ``max_planes`` planes: problems of different scenes then share tensor shapes (one CUDA
    graph). Padding obstacles are those of ``TorchWorld``'s own padding (far away, zero
    bounding radius: the fixed-shape costs never use them), so the costs are the same up to
    float rounding. Returns the world and whether a kind exceeded its capacity."""
    have = {k.kind: k for k in world.kinds}
    dd = dict(device=world.device, dtype=world.dtype)
    P, kinds, over = world.P, [], False
    for name, cap in zip(KIND_TAILS, capacity):
        kind = have.get(name)
        O = kind.O if kind is not None else 0
        if cap <= 0 and kind is None:
            continue
        over |= O > cap
        n = _bucket(O, cap) if cap > 0 else O
        tensors = {}
        for key, tail in KIND_TAILS[name].items():
            if name == "convex":
                K = kind.t["planes"].shape[2] if kind is not None else 1
                K = max_planes if max_planes is not None and K <= max_planes else _bucket(K, PLANES_BUCKET)
                planes = torch.zeros((P, n, K, 4), **dd)
                planes[:, :O, :, 3] = 1e9  # padding planes of a real part never bind
                if kind is not None:
                    planes[:, :O, : kind.t["planes"].shape[2]] = kind.t["planes"]
                tensors[key] = planes
                continue
            value = torch.zeros((P, n) + tail, **dd)
            if kind is not None:
                value[:, :O] = kind.t[key]
            tensors[key] = value
        bound_c = torch.full((P, n, 3), _FAR_CENTER, **dd)
        bound_r = torch.zeros((P, n), **dd)
        if kind is not None:
            bound_c[:, :O], bound_r[:, :O] = kind.bound_c, kind.bound_r
        padded = _Primitives(name, tensors, bound_c, bound_r, world.device, world.dtype)
        padded.reduced = kind.reduced if kind is not None else (name == "convex" and max_planes is not None)
        kinds.append(padded)
    out = TorchWorld.__new__(TorchWorld)
    out.__dict__.update(world.__dict__)
    out.kinds = kinds
    return out, over


_WALKED = (FixedShapeCosts, _Groups, TorchWorld, TorchRobot, _Primitives, SphereGroups)
_SCALARS = (int, float, bool, str, type(None), torch.dtype, torch.device)


def _walk(obj, path: tuple, tensors: dict, signature: list, keep: list) -> None:
    """Every tensor reachable from ``obj`` through the classes of ``_WALKED`` (by attribute
    path), and a signature of everything a captured graph depends on: tensor shapes, scalar
    values, the identity of other objects (the robot model, its kinematics; kept alive)."""
    if isinstance(obj, torch.Tensor):
        tensors[path] = obj
        signature.append((path, tuple(obj.shape), obj.dtype, obj.device))
    elif isinstance(obj, _SCALARS):
        signature.append((path, obj))
    elif isinstance(obj, (list, tuple)):
        signature.append((path, type(obj), len(obj)))
        for i, v in enumerate(obj):
            _walk(v, path + (i,), tensors, signature, keep)
    elif isinstance(obj, dict):
        signature.append((path, dict, tuple(sorted(obj, key=str))))
        for k in sorted(obj, key=str):
            _walk(obj[k], path + (k,), tensors, signature, keep)
    elif isinstance(obj, _WALKED):
        signature.append((path, type(obj)))
        for k in sorted(vars(obj)):
            # The configuration is in the key whole; the kinematics (``TorchRobot.fk``, a copy
            # per plan) are the robot model's, whose identity is in the signature.
            if k not in ("cfg", "fk"):
                _walk(vars(obj)[k], path + (k,), tensors, signature, keep)
    else:  # the robot model, its kinematics module: the same objects, not copies
        signature.append((path, "id", id(obj)))
        keep.append(obj)


def _replace(obj, path: tuple, value):
    """Set the tensor at ``path`` (``_walk``'s) below ``obj`` to ``value``, or, ``None``, read it."""
    for step in path[:-1]:
        obj = obj[step] if isinstance(obj, (list, tuple, dict)) else getattr(obj, step)
    last = path[-1]
    if value is None:
        return obj[last] if isinstance(obj, (list, tuple, dict)) else getattr(obj, last)
    if isinstance(obj, (list, dict)):
        obj[last] = value
    else:
        setattr(obj, last, value)
    return value


class GraphCache:
    """Captured Adam loops by shape, least recently used first out, at most ``size``: a long
    run's GPU memory stays bounded (a dropped graph frees its memory pool). A plan whose
    world, robot and configuration have the shapes of a cached loop copies its tensors into
    that loop's buffers and replays its graph; the counts say how often each happened."""

    def __init__(self, size: int):
        self.size = size
        self.entries: OrderedDict = OrderedDict()
        self.counts = {"new": 0, "reused": 0, "evicted": 0}

    def loop(self, fixed: FixedShapeCosts, interior, start, goal, cfg) -> tuple["_AdamLoop", bool]:
        """The cached loop for ``fixed``'s shapes, loaded with this problem (True), or a new
        one, cached (False)."""
        tensors, signature, keep = {}, [], []
        _walk(fixed, (), tensors, signature, keep)
        # The phase timer is outside the captured block: timed and untimed plans share a loop.
        key = (repr(dataclasses.replace(cfg, phase_times=False)), tuple(interior.shape), interior.dtype,
               interior.device, tuple(signature))
        entry = self.entries.get(key)
        if entry is not None:
            self.entries.move_to_end(key)
            loop, cached = entry[0], entry[1]
            with torch.no_grad():
                for path, t in tensors.items():
                    cached[path].copy_(t)
            loop.load(interior, start, goal)
            return loop, True
        # Broadcast views (the gripper's joints, expanded from the finger openings) become
        # tensors of their own: the next problem's values are copied into them.
        for path, t in tensors.items():
            if t.numel() > 1 and 0 in t.stride():
                _replace(fixed, path, t.contiguous())
                tensors[path] = _replace(fixed, path, None)
        loop = _AdamLoop(fixed, interior, start, goal, cfg)
        loop.graph = None
        self.entries[key] = (loop, tensors, keep)
        while len(self.entries) > self.size:
            self.entries.popitem(last=False)
            self.counts["evicted"] += 1
        return loop, False

    def clear(self) -> None:
        self.entries.clear()


_CACHE: GraphCache | None = None


def graph_cache(size: int) -> GraphCache:
    """The process's cache of captured loops (resized to ``size``)."""
    global _CACHE
    if _CACHE is None:
        _CACHE = GraphCache(size)
    _CACHE.size = size
    while len(_CACHE.entries) > size:
        _CACHE.entries.popitem(last=False)
        _CACHE.counts["evicted"] += 1
    return _CACHE


def fixed_shape_costs(costs, cfg) -> tuple[FixedShapeCosts, bool]:
    """The fixed-shape costs of ``costs``'s problems; with ``cfg.cuda_graph`` over the world
    padded to ``cfg.graph_capacity`` (``pad_world``: shapes shared across problems, so a
    captured loop is reused). Returns them and whether a kind exceeded its capacity."""
    world, over = costs.world, False
    if cfg.cuda_graph:  # (a baked world has no obstacle kinds to pad: its grid's shape is fixed)
        capacity = (0, 0, 0) if cfg.world_grid is not None else cfg.graph_capacity
        world, over = pad_world(world, capacity, cfg.max_planes)
    return FixedShapeCosts(costs.robot, world, cfg, costs.q_min, costs.q_max, cfg.max_obstacles), over


def optimise_fixed_shape(fixed: FixedShapeCosts, interior: torch.Tensor, start: torch.Tensor, goal: torch.Tensor,
                         cfg, check_time: Callable[[], None]) -> tuple[torch.Tensor, torch.Tensor, str]:
    """Adam on ``interior`` (P, S, T - 2, 7) between ``start`` and ``goal`` (P, S, 1, 7) with
    the fixed-shape costs ``fixed``; a CUDA graph when ``cfg.cuda_graph`` and the tensors are
    on CUDA. With ``cuda_graph`` (on any device) the loop comes from the process's
    ``GraphCache``: a problem of a cached shape reuses its buffers (and, on CUDA, its graph).
    ``check_time`` raises past the deadline (between blocks). Returns the final interior and,
    per problem, the (configuration, link, kind) triples that had more near obstacles than
    ``cfg.max_obstacles`` (summed over iterations), and how the loop ran: ``eager``,
    ``captured`` or ``replayed`` (a graph captured for an earlier problem; on a CPU, its
    buffers reused)."""
    capture = bool(cfg.cuda_graph) and interior.is_cuda
    fixed.over_cap.zero_()  # the Adam iterations' count (a cached loop's is reset by its load)
    if not cfg.cuda_graph:
        loop = _AdamLoop(fixed, interior, start, goal, cfg)
        return loop.run(False, check_time), fixed.over_cap, "eager"
    cache = graph_cache(cfg.graph_cache)
    loop, reused = cache.loop(fixed, interior, start, goal, cfg)
    how = "replayed" if reused else ("captured" if capture else "eager")
    cache.counts["reused" if reused else "new"] += 1
    out = loop.run(capture, check_time, loop.graph)
    return out.clone(), loop.costs.over_cap.clone(), how
