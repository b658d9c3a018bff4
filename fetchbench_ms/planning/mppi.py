"""MPPI in joint space with a receding horizon (the CabiNet-style planner of FetchBench's
third sense-plan-act family), batched in torch on any device.

A plan is a sequence of ``horizon`` joint steps (at most the Panda's velocity limits x
``speed_scale`` x ``dt`` each) from the current configuration. Each replan runs
``iterations`` MPPI updates: ``rollouts`` perturbations of the current mean sequence
(Gaussian, ``noise_std`` rad a step; one rollout keeps the mean, one heads straight for
the nearest goal), each rolled out and scored; the mean becomes their average weighted by
``exp(-cost / temperature)``. Then the first ``replan_seconds`` of the best free sequence
is executed (``execute``: the robot moves, and its measured configuration starts the next
replan; the rest of the sequence, shifted, warm-starts it). Up to ``max_replans`` per call
(the original's: 50 rollouts, horizon 40, noise 0.08, replan every 1 s, 30 replans).

Costs per rollout state: distance to the nearest goal of the goal set (and more at the
end), collision with the scene (CHOMP's smooth cost of the clearance below ``eta`` after
a ``safety`` margin, plus a large step cost for a predicted contact, which stays for the
rest of the rollout: a crash does not undo), sphere self-collision and carried object vs
arm (as trajopt's), joint limits (states are clipped into them), smoothness (squared step
changes). The scene clearance comes from

- ``cost="network"``: the learned scene-collision network (``collision_net``) on the
  observed cloud of the checker's point-cloud world (its groups that are not excluded);
- ``cost="distance"``: the checker's world as the torch distance fields of ``distance.py``
  (the point-cloud grid, or the oracle meshes): the ablation, no checkpoint needed.

The goals come checked free by the caller's exact checker, but a cautious cost model (the
network at its decision margin calls ~3 cm around surfaces a contact; a pre-grasp is 4 cm
from its target, often near a board) may call them in contact: its rollouts into the goal
then all "crash" and MPPI hovers outside until its replans run out. So around each goal
(``goal_region`` rad) the cost model's clearance gets a credit, fading with the distance,
of what it lacks at the goal; executed states that are free only on that credit must pass
the exact checker. Near a goal (within ``snap_distance`` rad) a straight segment to it that
the cost model calls free is taken: MPPI's noise would otherwise dither around a 0.01 rad
tolerance; within ``exact_snap_distance`` a straight segment to any goal that the exact
checker passes all along is taken (the final approach, validated as RRT's edges are).
The result is the ``PlanResult`` of the other planners with ``path`` the executed
waypoints and ``executed=True``: the robot is already there.
"""
from __future__ import annotations

import os
import time
import zlib
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from .checker import CollisionChecker
from .distance import TorchRobot, TorchWorld, collision_cost
from .rrt import PlanRequest, PlanResult, densify
from .world import PointCloudField

COSTS = ("network", "distance")
FLOOR_SLACK = 0.002  # m: how much deeper than an in-contact start a move may go (float noise, tracking)


def default_device() -> str:
    """``$FETCHBENCH_MPPI_DEVICE`` if set, else CUDA when available, else CPU."""
    return os.environ.get("FETCHBENCH_MPPI_DEVICE") or ("cuda" if torch.cuda.is_available() else "cpu")


@dataclass
class MppiConfig:
    rollouts: int = 50
    horizon: int = 40  # steps
    noise_std: float = 0.08  # rad per step
    noise_knot_steps: int = 5  # noise drawn every this many steps, interpolated between (1: white)
    dt: float = 0.1  # s per step: 40 steps look 4 s ahead
    replan_seconds: float = 1.0  # executed between replans
    max_replans: int = 30  # per call (one phase)
    iterations: int = 3  # MPPI updates per replan
    check_resolution: float = 0.02  # rad: the executed second is checked this densely first (as RRT's edges)
    fallback_rollouts: int = 8  # when the mean's first second is not free: the cheapest rollouts tried
    temperature: float = 0.02  # of the cost spread among rollouts
    speed_scale: float = 0.4  # of the velocity limits, as the executor's
    goal_tolerance: float = 0.01  # rad, max joint error
    snap_distance: float = 0.3  # rad: a free straight segment to the goal from this near is taken
    # rad (joint-space norm): around a goal the cost model's clearance is raised, fading out
    # linearly over this distance, by as much as it lacks at the goal itself (the goal comes
    # checked free by the caller's exact checker; a network that doubts it would otherwise
    # fence the goal off). States executed on that credit are checked by the exact checker.
    goal_region: float = 0.5
    exact_snap_distance: float = 0.8  # rad: a straight segment to a goal the exact checker passes is taken
    cost: str = "network"  # network | distance
    safety: float = 0.01  # m of clearance the collision cost asks for
    eta: float = 0.03  # m: activation distance of the smooth collision cost
    self_tolerance: float = 0.015  # m of sphere self overlap left free (trajopt's)
    w_goal: float = 1.0
    w_terminal: float = 10.0
    w_tcp: float = 3.0  # rad per m of TCP distance in the goal cost
    w_collision: float = 300.0
    w_contact: float = 50.0  # per state at and after a predicted contact
    w_self: float = 300.0
    w_smooth: float = 5.0
    checkpoint: str | None = None  # network cost: default collision_net.checkpoint_path()
    device: str | None = None  # None: default_device()
    seed: int = 0

    def __post_init__(self):
        if self.cost not in COSTS:
            raise ValueError(f"unknown MPPI cost {self.cost!r}; valid: {', '.join(COSTS)}")


def _cloud_fields(checker: CollisionChecker) -> list[PointCloudField]:
    """The observed clouds of a point-cloud world's groups the checker does not exclude."""
    fields = [s for g, sets in checker.world.groups.items() if g not in checker.exclude for s in sets]
    if not fields or not all(isinstance(s, PointCloudField) for s in fields):
        raise ValueError("the network cost reads an observed point cloud: plan in a point-cloud world "
                         "(planning.world_models.pointcloud_world), or use cost='distance'")
    return fields


class SceneClearance:
    """World clearance (B,) of configurations (B, 7) for one checker: the network's
    prediction or the distance fields' value, arm spheres the checker checks plus its
    carried object's."""

    def __init__(self, checker: CollisionChecker, cost: str, device, checkpoint: str | None = None):
        self.cost, self.device = cost, torch.device(device)
        self.robot = TorchRobot(checker.robot, [checker], self.device, torch.float32)
        if cost == "distance":
            self.torch_world = TorchWorld([checker.world], [checker.exclude], self.device, torch.float32, max_planes=24)
            return
        from .collision_net import RobotSpheres, load_collision_net, scene_grid

        fields = _cloud_fields(checker)
        self.net = load_collision_net(checkpoint, str(self.device))
        self.spheres = RobotSpheres(self.device)
        # The encoding is made once per world and exclusion (a phase replans many times).
        cache = fields[0].__dict__.setdefault("_collision_net_scene", {})
        key = (tuple(id(f) for f in fields), str(self.device), id(self.net))
        if key not in cache:
            points = np.concatenate([f.centers for f in fields])
            with torch.no_grad():
                cache[key] = self.net.encode(torch.as_tensor(scene_grid(points)))
        self.scene = cache[key]
        world_links = [l for l in checker.robot.world_links if l in checker.robot.spheres.links]
        arm_checked = checker.world_mask.numpy()[checker.robot.sphere_mask(tuple(world_links))]
        att = checker.attachment
        self.att_c = None if att is None else torch.as_tensor(att.centers_hand, device=self.device, dtype=torch.float32)
        radii = [self.spheres.radii] + ([] if att is None else [torch.as_tensor(att.radii, device=self.device,
                                                                                  dtype=torch.float32)])
        self.radii = torch.cat(radii)
        mask = np.concatenate([arm_checked, np.ones(0 if att is None else len(att.radii), bool)])
        self.mask = torch.as_tensor(mask, device=self.device)
        self.finger = checker.finger

    @torch.no_grad()
    def clearance(self, q: torch.Tensor) -> torch.Tensor:
        if self.cost == "network":
            centers = self.spheres.centers(q, self.finger, self.att_c)
            # Relative to the network's decision margin: < 0 is what it calls a collision.
            return self.net.clearance(self.scene, centers, self.radii, self.mask) - self.net.decision_margin
        centers, att = self.robot.spheres(q[None])
        S = centers.shape[2]
        d = self.torch_world.distance(centers.reshape(1, -1, 3)).reshape(1, -1, S) - self.robot.world_radii[:, None]
        clear = d.amin(dim=2)
        if att is not None:
            M = att.shape[2]
            d_att = self.torch_world.distance(att.reshape(1, -1, 3)).reshape(1, -1, M) - self.robot.att_r[:, None]
            clear = torch.minimum(clear, d_att.amin(dim=2))
        return clear[0]

    @torch.no_grad()
    def self_cost(self, q: torch.Tensor, tolerance: float) -> torch.Tensor:
        """(B,) smooth self-collision cost (sphere pairs beyond ``tolerance``, carried object vs arm)."""
        centers, att = self.robot.spheres(q[None])
        cost = collision_cost(self.robot.self_distance(centers, 0.05)[0] + tolerance, 0.01)
        if att is not None:
            d_arm = self.robot.attachment_arm_distance(centers, att)[0].flatten(1).amin(dim=1)
            cost = cost + collision_cost(d_arm, 0.01)
        return cost


def _rollout(q0: torch.Tensor, steps: torch.Tensor, lo, hi) -> torch.Tensor:
    """(R, H, 7) states reached by steps (R, H, 7) from q0 (7,), clipped into the limits."""
    return torch.minimum(torch.maximum(q0 + torch.cumsum(steps, dim=1), lo), hi)


def plan_mppi(checker: CollisionChecker, q_start, q_goals, execute: Callable[[np.ndarray], np.ndarray] | None = None,
              config: MppiConfig | None = None) -> PlanResult:
    """Move from ``q_start`` to any of ``q_goals`` ((7,) or (K, 7)) by receding-horizon MPPI.

    ``execute(path (N, 7))`` moves the robot along joint waypoints and returns the measured
    configuration (the sense-plan-act executor); None: ideal tracking (the path's end).
    ``planning_time`` counts the planner's computation only.
    """
    cfg = config or MppiConfig()
    device = torch.device(cfg.device or default_device())
    dd = dict(device=device, dtype=torch.float32)
    robot = checker.robot
    q = np.asarray(q_start, float).reshape(7)
    goals_np = np.asarray(q_goals, float).reshape(-1, 7)
    t_compute = 0.0
    tc = time.perf_counter()
    scene = SceneClearance(checker, cfg.cost, device, cfg.checkpoint)
    goals = torch.as_tensor(goals_np, **dd)
    gripper = checker.robot.gripper_q(float(checker.finger)).to(**dd)  # (1, G)
    tcp_link = checker.robot.tcp_link

    def tcp(x: torch.Tensor) -> torch.Tensor:
        return scene.robot.fk.forward(torch.cat([x, gripper.expand(len(x), -1)], 1))[tcp_link][:, :3, 3]

    goal_tcp = tcp(goals)
    # What each goal's clearance lacks of the collision cost's activation distance: the
    # credit given around it (``goal_region``; 0 for a goal the cost model calls roomy).
    goal_deficit = (cfg.safety + cfg.eta - scene.clearance(goals)).clamp(min=0)

    def credit(x: torch.Tensor) -> torch.Tensor:
        """(N,) clearance credit of configurations (N, 7) near a goal the cost model doubts."""
        if cfg.goal_region <= 0:
            return torch.zeros(len(x), **dd)
        fade = (1 - torch.cdist(x, goals) / cfg.goal_region).clamp(min=0)
        return (goal_deficit[None] * fade).amax(dim=1)

    def executable(dense: np.ndarray, floor: float, self_limit: float) -> bool:
        """Whether the robot may move through configurations ``dense`` (N, 7): clearance (with
        the goal credit) above ``floor`` and self cost no higher than ``self_limit`` everywhere, and
        the states that are above ``floor`` only on the credit valid for the exact checker."""
        nonlocal n_checked
        x = torch.as_tensor(dense, **dd)
        n_checked += len(x)
        raw, extra = scene.clearance(x), credit(x)
        if not bool((raw + extra > floor).all()):
            return False
        if not bool((scene.self_cost(x, cfg.self_tolerance) <= self_limit + 1e-6).all()):
            return False
        lean = ((extra > 0) & (raw <= floor)).cpu().numpy()
        return not lean.any() or bool(checker.valid(dense[lean]).all())

    def goal_distance(x: torch.Tensor) -> torch.Tensor:
        """(N,) distance of configurations (N, 7) to the nearest goal: joint space (rad) plus
        ``w_tcp`` x the TCP's distance (m) to that goal's (the hand has to come in through
        the shelf's opening, which joint distance alone does not see)."""
        d = torch.cdist(x, goals) + cfg.w_tcp * torch.cdist(tcp(x), goal_tcp)
        return d.amin(dim=1)
    lo, hi = torch.as_tensor(robot.q_min, **dd), torch.as_tensor(robot.q_max, **dd)
    max_step = torch.as_tensor(robot.velocity_limits * cfg.speed_scale * cfg.dt, **dd)
    H, R = cfg.horizon, cfg.rollouts
    seed = zlib.crc32(np.ascontiguousarray(np.concatenate([q, goals_np.ravel()])).tobytes()) ^ cfg.seed
    gen = torch.Generator(device=device).manual_seed(seed)
    executed = [q.copy()]
    n_checked = 0
    replan_steps = max(1, int(round(cfg.replan_seconds / cfg.dt)))
    t_compute += time.perf_counter() - tc  # building or encoding the scene counts as planning

    # Noise drawn at knots every ``noise_knot_steps`` and interpolated between them: a
    # perturbation that lasts changes where a rollout goes (white noise per step averages out).
    n_knots = max(2, int(np.ceil(H / max(1, cfg.noise_knot_steps))) + 1)
    knot_t = torch.linspace(0, n_knots - 1, H, **dd)
    k0 = knot_t.floor().long().clamp(max=n_knots - 2)
    frac = (knot_t - k0)[None, :, None]

    def smooth_noise(knots: torch.Tensor) -> torch.Tensor:
        if cfg.noise_knot_steps <= 1:
            return knots[:, :H] if knots.shape[1] >= H else torch.randn((R, H, 7), generator=gen, **dd)
        return knots[:, k0] * (1 - frac) + knots[:, k0 + 1] * frac

    def nearest_goal(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        d = torch.cdist(x.reshape(-1, 7), goals)  # (N, K)
        v, i = d.min(dim=1)
        return v.reshape(x.shape[:-1]), i.reshape(x.shape[:-1])

    def straight(q_now: torch.Tensor) -> torch.Tensor:
        """(H, 7) steps heading for the nearest goal at the step limit, stopping there."""
        _, g = nearest_goal(q_now[None])
        delta = goals[g[0]] - q_now
        n = torch.clamp((delta.abs() / max_step).max().ceil(), min=1)
        step = delta / n
        k = torch.arange(H, device=device)[:, None]
        return torch.where(k < n, step, torch.zeros_like(step))

    def costs(q_now: torch.Tensor, steps: torch.Tensor, floor: float) -> tuple[torch.Tensor, torch.Tensor]:
        """(R,) rollout costs and (R, H) clearances; ``floor``: the clearance below which a
        state is a contact (0, or a little below a start that is already in contact)."""
        states = _rollout(q_now, steps, lo, hi)  # (R, H, 7)
        R_ = len(steps)
        flat = states.reshape(-1, 7)
        clear = (scene.clearance(flat) + credit(flat)).reshape(R_, H)
        hit = (clear < floor).float()
        crashed = torch.cummax(hit, dim=1).values  # a contact stays for the rest of the rollout
        coll = cfg.w_collision * collision_cost(clear - cfg.safety, cfg.eta) + cfg.w_contact * crashed
        self_c = cfg.w_self * scene.self_cost(flat, cfg.self_tolerance).reshape(R_, H)
        dist = goal_distance(flat).reshape(R_, H)
        goal = cfg.w_goal * dist.mean(dim=1) + cfg.w_terminal * dist[:, -1]
        smooth = cfg.w_smooth * (torch.diff(steps, dim=1) ** 2).sum(dim=(1, 2))
        return goal + (coll + self_c).mean(dim=1) + smooth, clear

    mean = None
    # Running out of replans is the count budget's end ("budget", a planning failure), as
    # for the other planners; MPPI has no wall-clock limit of its own.
    status, goal_index = "budget", -1
    for replan in range(cfg.max_replans + 1):
        tc = time.perf_counter()
        q_now = torch.as_tensor(q, **dd)
        dist, g = nearest_goal(q_now[None])
        g = int(g[0])
        if float(np.abs(q - goals_np[g]).max()) <= cfg.goal_tolerance:
            status, goal_index = "solved", g
            t_compute += time.perf_counter() - tc
            break
        if replan == cfg.max_replans:
            t_compute += time.perf_counter() - tc
            break
        # A start the cost model calls in contact (the robot at rest on a support, a goal
        # that the planner's checker accepted but the network doubts) may be left, never
        # entered deeper: moves are allowed down to a little below the start's clearance.
        c_start = float((scene.clearance(q_now[None]) + credit(q_now[None]))[0])
        self_start = float(scene.self_cost(q_now[None], cfg.self_tolerance)[0])
        floor = 0.0 if c_start >= 0 else c_start - FLOOR_SLACK
        # Near the goal: the straight segment, if the cost model calls all of it free (or no
        # deeper than its ends: the goal comes checked by the caller's checker). Farther
        # (``exact_snap_distance``): a segment to any goal that the caller's exact checker
        # passes all along (the final approach, validated as the other planners' edges are).
        path = None
        if float(np.abs(q - goals_np[g]).max()) <= cfg.snap_distance:
            segment = densify(np.stack([q, goals_np[g]]), cfg.check_resolution)
            end = torch.as_tensor(goals_np[g:g + 1], **dd)
            c_goal = float((scene.clearance(end) + credit(end))[0])
            seg_floor = floor if c_goal >= 0 else min(floor, c_goal - FLOOR_SLACK)
            self_goal = float(scene.self_cost(end, cfg.self_tolerance)[0])
            if executable(segment, seg_floor, max(self_start, self_goal)):
                path = segment[[0, -1]]
        reach = np.abs(goals_np - q).max(axis=1)
        for k in np.argsort(reach, kind="stable") if path is None else ():
            if reach[k] > cfg.exact_snap_distance:
                break
            segment = densify(np.stack([q, goals_np[k]]), cfg.check_resolution)
            n_checked += len(segment)
            if bool(checker.valid(segment).all()):
                path = segment[[0, -1]]
                break
        if path is None:
            mean = straight(q_now) if mean is None else mean
            for _ in range(cfg.iterations):
                noise = smooth_noise(torch.randn((R, n_knots, 7), generator=gen, **dd)) * cfg.noise_std
                noise[0] = 0  # the mean itself
                cand = mean + noise
                cand[1] = straight(q_now)  # heading straight for the goal
                cand = torch.maximum(torch.minimum(cand, max_step), -max_step)
                c, clear = costs(q_now, cand, floor)
                n_checked += R * H
                spread = (c.mean() - c.min()).clamp(min=1e-9)
                w = torch.softmax(-(c - c.min()) / (cfg.temperature * spread), dim=0)
                mean = (w[:, None, None] * cand).sum(dim=0)
            # Execute the mean if its first second is free, else the best free rollout.
            def free_first(steps: torch.Tensor) -> bool:
                """The first second of a sequence, checked densely (``check_resolution``)."""
                states = _rollout(q_now, steps[None, :replan_steps], lo, hi)[0]
                dense = densify(np.concatenate([q[None], states.double().cpu().numpy()]), cfg.check_resolution)
                return executable(dense, floor, self_start)

            # Execute the mean's first second if it is free, else that of the best free
            # rollout (the cheapest few are tried).
            chosen = mean if free_first(mean) else None
            if chosen is None:
                for i in torch.argsort(c)[: cfg.fallback_rollouts].tolist():
                    if free_first(cand[i]):
                        chosen = cand[i]
                        break
            if chosen is not None:
                states = _rollout(q_now, chosen[None], lo, hi)[0, :replan_steps]
                # Exactly within the limits in float64 (float32 clipping can overshoot by 1e-7).
                path = np.concatenate([q[None], np.clip(states.double().cpu().numpy(), robot.q_min, robot.q_max)])
            # Warm start: the rest of the sequence, shifted; zeros after it.
            mean = torch.cat([mean[replan_steps:], torch.zeros((replan_steps, 7), **dd)])
        t_compute += time.perf_counter() - tc
        if path is None:
            continue  # nothing free to do this round: think again
        q_new = path[-1] if execute is None else np.asarray(execute(path), float).reshape(7)
        executed.extend(path[1:])
        if execute is not None and not np.allclose(q_new, path[-1]):
            executed.append(q_new)  # where the robot really got to
        q = q_new
    return PlanResult(status, np.stack(executed), t_compute, n_checked, goal_index, planner="mppi", executed=True)


__all__ = ["COSTS", "MppiConfig", "SceneClearance", "default_device", "plan_mppi"]


def plan(request: PlanRequest) -> PlanResult:
    """MPPI for the pipeline: moves the robot while it plans (``request.execute``); its
    collision cost is the method's (``request.collision``) unless the run's ``mppi_cost``
    says otherwise, its goal region ``mppi_goal_region`` (None: ``MppiConfig``'s)."""
    region = request.options.get("mppi_goal_region")
    config = MppiConfig(cost=request.options.get("mppi_cost") or request.collision,
                        goal_region=MppiConfig.goal_region if region is None else region,
                        speed_scale=request.speed_scale, seed=request.seed)
    return plan_mppi(request.checker, request.q_start, request.q_goals, request.execute, config)
