"""Collision checking of arm configurations against a world, with an optional carried object."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import torch
import trimesh

from .spheres import fit_balls, volume_samples
from .robot import PandaModel
from .world import CollisionWorld


@dataclass(frozen=True)
class Attachment:
    """A grasped object as spheres in the hand frame (``panda_hand``)."""

    centers_hand: np.ndarray  # (M, 3)
    radii: np.ndarray  # (M,)

    @classmethod
    def from_points(cls, points_hand: np.ndarray, n_spheres: int = 64, seed: int = 0,
                    margin: float = 0.003) -> "Attachment":
        """Balls covering object points (the observed cloud, or samples of the solid), hand
        frame: k-means clusters with their enclosing balls grown by ``margin`` (for the
        surface between samples), so every point is covered and, given interior samples,
        balls sit inside the object rather than on its skin."""
        points = np.asarray(points_hand, dtype=float).reshape(-1, 3)
        if len(points) == 0:
            raise ValueError("cannot attach an object with no points")
        centers, radii = fit_balls(points, n_spheres, margin, np.random.default_rng(seed))
        return cls(centers, radii)

    @classmethod
    def from_convex_parts(cls, parts_hand, n_samples: int = 3000, n_spheres: int = 64,
                          seed: int = 0) -> "Attachment":
        """Balls covering an object's convex parts (hand frame): surface and interior samples."""
        rng = np.random.default_rng(seed)
        area = np.array([p.area for p in parts_hand])
        points = []
        for part, share in zip(parts_hand, area / area.sum()):
            n = max(50, int(n_samples * share))
            surface, _ = trimesh.sample.sample_surface(part, n, seed=rng)
            points += [part.vertices, surface, volume_samples(part, n // 2, rng)]
        return cls.from_points(np.concatenate(points), n_spheres, seed)

    def moved(self, T_new_old: np.ndarray) -> "Attachment":
        """The same balls in another frame: e.g. balls fitted once in the object's frame, put
        in the hand frame of a grasp with ``T_hand_object``."""
        T = np.asarray(T_new_old, dtype=float)
        return Attachment(np.asarray(self.centers_hand) @ T[:3, :3].T + T[:3, 3], np.asarray(self.radii))


class CollisionChecker:
    """``valid(q)``: joint limits, self-collision and world clearance for a batch of configs.

    ``exclude`` names world groups that are ignored (e.g. the target while approaching
    it). ``margin`` is extra clearance on top of the spheres' own fitting margin.
    """

    def __init__(self, robot: PandaModel, world: CollisionWorld, finger: float | None = None,
                 exclude: tuple[str, ...] = (), attachment: Attachment | None = None, margin: float = 0.0,
                 ignore_links: tuple[str, ...] = (), exact_self_collision: bool = True):
        # None: the open hand (0.04 m per finger on the Franka hand).
        self.robot, self.world = robot, world
        self.finger = robot.finger_open if finger is None else finger
        self.exclude, self.attachment, self.margin = tuple(exclude), attachment, margin
        world_links = tuple(l for l in robot.world_links if l not in ignore_links)
        self.world_mask = torch.as_tensor(robot.sphere_mask(world_links))
        self.radii = torch.as_tensor(robot.spheres.radii)
        self._init_self_pairs(robot)
        self.n_checked = 0
        # Sphere self-collision is a broad phase: the inflated spheres of the wrist and
        # fingers overlap the forearm's in many valid poses (about a third of IK
        # solutions in a test scene, 1 in 10 of them real), so flagged link pairs are
        # decided on the exact meshes (python-fcl).
        self.exact_self = exact_self_collision
        self._exact = None
        if attachment is not None:
            self.att_c = torch.as_tensor(attachment.centers_hand, dtype=torch.float64)
            self.att_r = torch.as_tensor(attachment.radii, dtype=torch.float64)
            # The carried object may touch the hand and fingers, not the rest of the arm.
            self.att_arm_mask = torch.as_tensor(robot.sphere_mask(robot.proximal_links))

    def _init_self_pairs(self, robot: PandaModel) -> None:
        """Self-collision pairs grouped by link pair, with a bounding sphere per link so
        that far-apart link pairs (most of them, in most configurations) cost one distance."""
        sp = robot.spheres
        n_links = len(sp.links)
        centers = torch.as_tensor(sp.centers_link)
        self.link_bound_c = torch.zeros(n_links, 3, dtype=torch.float64)
        self.link_bound_r = torch.zeros(n_links, dtype=torch.float64)
        for l in range(n_links):
            m = torch.as_tensor(sp.link_index == l)
            c = centers[m].mean(dim=0)
            self.link_bound_c[l] = c
            self.link_bound_r[l] = ((centers[m] - c).norm(dim=1) + self.radii[m]).max()
        la = sp.link_index[robot.self_collision_pairs[:, 0]]
        lb = sp.link_index[robot.self_collision_pairs[:, 1]]
        link_pairs = sorted(set(zip(la.tolist(), lb.tolist())))
        self.link_pairs = torch.as_tensor(link_pairs, dtype=torch.long).reshape(-1, 2)
        blocks = [robot.self_collision_pairs[(la == p) & (lb == q)] for p, q in link_pairs]
        width = max((len(b) for b in blocks), default=1)
        table = np.zeros((len(blocks), width, 2), dtype=np.int64)
        valid = np.zeros((len(blocks), width), dtype=bool)
        for i, b in enumerate(blocks):
            table[i, : len(b)] = b
            valid[i, : len(b)] = True
        self.pair_table, self.pair_valid = torch.as_tensor(table), torch.as_tensor(valid)

    #: m past the margin (and the largest sphere) to which the world's distances are measured
    #: (the broad phase's horizon; ``CERTIFY_BOUND`` in a certified check).
    WORLD_BOUND = 0.02

    def joint_reach(self) -> np.ndarray:
        """(7,) for each arm joint, a bound on the distance of every sphere centre it moves (the
        robot's and the carried object's) from its axis, in any configuration: the distance
        from the joint's origin along the kinematic tree (each later joint's offset, a
        prismatic finger's opening) plus the centre's offset in its link. A straight move by
        ``dq`` in joint space moves no sphere centre farther than ``abs(dq) @ joint_reach()``
        (a turn by ``a`` about an axis moves a point at distance ``r`` from it by at most
        ``r * a``)."""
        return self._kinematic_reach[0]

    @cached_property
    def _kinematic_reach(self) -> tuple[np.ndarray, torch.Tensor]:
        """``joint_reach()``, and (S, 7) whether each robot sphere moves with each arm joint."""
        robot, fk = self.robot, self.robot.fk
        gripper = dict(zip(robot.gripper_joints, robot.gripper_q(self.finger)[0].abs().tolist()))
        unmoved = np.full(robot.n_arm, -np.inf)  # -inf: the link is not moved by that joint
        reach = {fk.root_link: unmoved}
        for joint in fk.joints:  # parents first
            d = reach[joint.parent] + np.linalg.norm(joint.T_parent_joint[:3, 3])
            if joint.kind == "prismatic":
                d = d + gripper.get(joint.name, 0.0)
            if joint.name in robot.arm_joints:
                d = d.copy()
                d[robot.arm_joints.index(joint.name)] = 0.0
            reach[joint.child] = d
        # ``move_bound`` takes the arm joints as one chain, each moving all later ones.
        children = [np.isfinite(reach[fk.joint_child[name]]) for name in robot.arm_joints]
        if not all(children[k][:k + 1].all() for k in range(robot.n_arm)):
            raise ValueError(f"{robot.uid}: the arm joints are not one chain in order")
        sp = robot.spheres
        offset = np.linalg.norm(sp.centers_link, axis=1)
        per_sphere = np.stack([reach[sp.links[l]] for l in sp.link_index]) + offset[:, None]  # (S, 7)
        bound = per_sphere.max(axis=0)
        if self.attachment is not None:
            att = reach[robot.hand_link] + np.linalg.norm(self.attachment.centers_hand, axis=1).max()
            bound = np.maximum(bound, att)
        return np.where(np.isfinite(bound), bound, 0.0), torch.as_tensor(np.isfinite(per_sphere))

    def _self_clearance(self, poses, centers) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, P) clearance per link pair: the bounding-sphere distance where that is
        positive, else the smallest sphere-pair distance of the pair."""
        links = self.robot.spheres.links
        T = torch.stack([poses[l] for l in links], dim=1)  # (B, L, 4, 4)
        bound = torch.einsum("blij,lj->bli", T[..., :3, :3], self.link_bound_c) + T[..., :3, 3]
        a, b = self.link_pairs[:, 0], self.link_pairs[:, 1]
        pair_clear = (bound[:, a] - bound[:, b]).norm(dim=2) - self.link_bound_r[a] - self.link_bound_r[b]
        ib, ip = torch.nonzero(pair_clear < self.margin, as_tuple=True)
        if len(ib):
            sa, sb = self.pair_table[ip, :, 0], self.pair_table[ip, :, 1]  # (N, W)
            d = (centers[ib[:, None], sa] - centers[ib[:, None], sb]).norm(dim=2) - self.radii[sa] - self.radii[sb]
            d = torch.where(self.pair_valid[ip], d, torch.full_like(d, float("inf")))
            pair_clear[ib, ip] = d.amin(dim=1)
        return pair_clear

    def clearance(self, q) -> torch.Tensor:
        """Smallest signed clearance per config (B,): < 0 means collision (ignoring limits)."""
        return self._clearance_parts(q)[0]

    def _clearance_parts(self, q, bound: float | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``clearance`` (B,), and with ``bound`` (a certified check) what ``certified`` reads
        of each configuration, (B, 9): the world clearance of the robot's and the carried
        object's spheres, at most ``bound`` beyond the margin (farther obstacles are not
        measured; the world is measured to ``bound`` instead of ``WORLD_BOUND``, with the same
        ``clearance > margin`` answers); the self clearance of the spheres (the robot's pairs,
        the object against the arm) before the exact meshes decide; and per arm joint the
        largest distance from its axis of a sphere centre it moves."""
        facts, bound = bound is not None, self.WORLD_BOUND if bound is None else bound
        q = torch.as_tensor(np.asarray(q), dtype=torch.float64).reshape(-1, 7)
        B = len(q)
        self.n_checked += B
        poses = self.robot.link_poses(q, self.finger)
        centers = self.robot.sphere_centers(q, poses=poses)  # (B, S, 3)
        horizon = float(self.radii.max()) + self.margin + bound
        c_world = centers[:, self.world_mask].reshape(-1, 3)
        r_world = self.radii[self.world_mask].repeat(B)
        d = self.world.distance(c_world, horizon, self.exclude) - r_world
        clear = d.reshape(B, -1).amin(dim=1)
        # A sphere whose centre is beyond the horizon reads some value past it: its clearance is
        # only known to be at least the horizon less its radius.
        world = clear.clamp(max=self.margin + bound)
        pair_clear = self._self_clearance(poses, centers)
        self_clear = spheres = pair_clear.amin(dim=1)
        att = None
        if self.exact_self:
            self_clear = self._exact_self_clearance(poses, pair_clear, self_clear)
        clear = torch.minimum(clear, self_clear)
        if self.attachment is not None:
            T = poses[self.robot.hand_link]
            att = torch.einsum("bij,mj->bmi", T[:, :3, :3], self.att_c) + T[:, None, :3, 3]  # (B, M, 3)
            d_att = self.world.distance(att.reshape(-1, 3), float(self.att_r.max()) + bound, self.exclude)
            d_att = (d_att.reshape(B, -1) - self.att_r).amin(dim=1)
            arm = centers[:, self.att_arm_mask]
            d_arm = (torch.cdist(att, arm) - self.att_r[:, None] - self.radii[self.att_arm_mask][None]).amin(dim=(1, 2))
            clear = torch.minimum(clear, torch.minimum(d_att, d_arm))
            world, spheres = torch.minimum(world, d_att.clamp(max=bound)), torch.minimum(spheres, d_arm)
        if not facts:
            return clear, None
        return clear, torch.cat([world[:, None], spheres[:, None], self._axis_distances(poses, centers, att)], dim=1)

    def _axis_distances(self, poses, centers, att) -> torch.Tensor:
        """(B, 7) per arm joint, the largest distance from its axis of a sphere centre it moves
        (the robot's ``centers`` (B, S, 3), the carried object's ``att`` (B, M, 3) or None)."""
        moved_by, fk, out = self._kinematic_reach[1], self.robot.fk, []
        for j, name in enumerate(self.robot.arm_joints):
            T = poses[fk.joint_child[name]]  # the axis passes through the child frame's origin
            u = T[:, :3, :3] @ fk.joint_axis((name,))[0]  # (B, 3)
            points = centers[:, moved_by[:, j]]
            if att is not None:
                points = torch.cat([points, att], dim=1)
            v = points - T[:, None, :3, 3]
            out.append((v - (v * u[:, None]).sum(dim=2, keepdim=True) * u[:, None]).norm(dim=2).amax(dim=1))
        return torch.stack(out, dim=1)

    def hand_clearance(self, T_base_hand) -> np.ndarray:
        """World clearance (N,) of the hand alone (hand, fingers and the rigidly attached
        link7) placed at each ``T_base_hand`` (N, 4, 4), without IK: a cheap filter for grasp
        candidates before the arm is solved for."""
        T_base_hand = torch.as_tensor(np.asarray(T_base_hand, float)).reshape(-1, 4, 4)
        if len(T_base_hand) == 0:
            return np.zeros(0)
        links = (self.robot.wrist_link,) + self.robot.hand_links
        poses = self.robot.link_poses(torch.zeros(1, 7, dtype=torch.float64), self.finger)
        T_hand_base = torch.linalg.inv(poses[self.robot.hand_link][0])
        mask = torch.as_tensor(self.robot.sphere_mask(links)) & self.world_mask
        idx = torch.nonzero(mask, as_tuple=True)[0]
        link_of = self.robot.spheres.link_index[idx.numpy()]
        T_hand_link = torch.stack([T_hand_base @ poses[self.robot.spheres.links[l]][0] for l in link_of])  # (M,4,4)
        c_link = torch.as_tensor(self.robot.spheres.centers_link[idx.numpy()])
        c_hand = torch.einsum("mij,mj->mi", T_hand_link[:, :3, :3], c_link) + T_hand_link[:, :3, 3]
        c_base = torch.einsum("nij,mj->nmi", T_base_hand[:, :3, :3], c_hand) + T_base_hand[:, None, :3, 3]
        horizon = float(self.radii.max()) + self.margin + 0.02
        d = self.world.distance(c_base.reshape(-1, 3), horizon, self.exclude).reshape(len(T_base_hand), -1)
        return (d - self.radii[idx][None]).amin(dim=1).numpy()

    def _exact_self_clearance(self, poses, pair_clear, self_clear) -> torch.Tensor:
        """For configs whose spheres touch: -1 if a flagged link pair's meshes collide, else +inf."""
        flagged = torch.nonzero(self_clear < self.margin, as_tuple=True)[0]
        if len(flagged) == 0:
            return self_clear
        if self._exact is None:
            from .exact import ExactRobot

            self._exact = ExactRobot(self.robot, links=self.robot.spheres.links)
        links = self.robot.spheres.links
        T_np = torch.stack([poses[l][flagged] for l in links], dim=1).numpy()  # (F, L, 4, 4)
        close = (pair_clear[flagged] < self.margin).numpy()
        link_pairs = self.link_pairs.numpy()
        out = self_clear.clone()
        for k, i in enumerate(flagged.tolist()):
            pairs = link_pairs[close[k]]
            for l in np.unique(pairs):
                self._exact.set_link_pose(links[l], T_np[k, l])
            collides = any(self._exact.link_pair_collides(links[p], links[q]) for p, q in pairs)
            out[i] = -1.0 if collides else float("inf")
        return out

    def valid(self, q) -> np.ndarray:
        return self._valid_parts(q)[0]

    def _valid_parts(self, q, bound: float | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """``valid`` (N,), and with ``bound`` the facts of ``_clearance_parts`` (N, 9) (-inf
        clearances for a configuration outside the joint limits: not measured)."""
        q = np.asarray(q, dtype=float).reshape(-1, 7)
        ok = self.robot.within_limits(q)
        facts = None if bound is None else np.full((len(q), 9), -np.inf)
        if ok.any():
            clear, measured = self._clearance_parts(q[ok], bound)
            if facts is not None:
                facts[ok] = measured.numpy()
            ok[ok] = (clear > self.margin).numpy()
        return ok, facts

    #: ``motion_valid`` checks a segment's first this many configurations as one batch and the
    #: rest only when they are all free (0: the whole segment as one batch). Most segments a
    #: planner rejects collide within a few steps of their start, so the rest is never
    #: computed; ``n_checked`` still counts the whole segment, so a budget of checks buys the
    #: same search (the same answers: each configuration's clearance does not depend on its batch).
    motion_check_first: int = 0

    @staticmethod
    def _head(n: int, first: int, spread: bool) -> np.ndarray | None:
        """The mask of the configurations of an (n, 7) batch that ``all_valid`` computes first,
        None when it computes the whole batch at once."""
        if not 0 < first < n:
            return None
        head = np.zeros(n, bool)
        if spread:
            head[:: -(-n // first)] = True
        else:
            head[:first] = True
        return head

    def all_valid(self, q, first: int | None = None, spread: bool = False, certify: float | None = None) -> bool:
        """Whether every configuration of ``q`` (N, 7) is valid: the first ``first`` (default
        ``motion_check_first``) as one batch, the rest only when those are all free; counted
        in ``n_checked`` as one batch either way. ``spread``: that first batch is ``first``
        configurations spread evenly over ``q`` (a segment to a goal deep in the scene
        collides anywhere along it, not mostly near its start). ``certify`` (rad): ``q`` is a
        path's consecutive configurations, and the straight moves between them must be free
        too (``certified``, down to steps of ``certify``)."""
        first = self.motion_check_first if first is None else first
        bound = None if certify is None else self.CERTIFY_BOUND
        head = self._head(len(q), first, spread)
        if head is None:
            ok, facts = self._valid_parts(q, bound)
            return bool(ok.all()) and (certify is None or self.certified(q, facts, certify))
        ok, at_head = self._valid_parts(q[head], bound)
        if not ok.all():
            self.n_checked += int(self.robot.within_limits(q[~head]).sum())  # as if checked at once
            return False
        return self._rest_valid(q, head, at_head, certify)

    def _rest_valid(self, q, head: np.ndarray, at_head: np.ndarray | None, certify: float | None) -> bool:
        """``all_valid``'s answer for ``q`` whose configurations ``head`` were all valid (their
        facts ``at_head`` when certifying): the rest checked, then the moves certified."""
        ok, at_tail = self._valid_parts(q[~head], None if certify is None else self.CERTIFY_BOUND)
        if not ok.all():
            return False
        if certify is None:
            return True
        facts = np.empty((len(head), at_head.shape[1]))
        facts[head], facts[~head] = at_head, at_tail
        return self.certified(q, facts, certify)

    #: m past the margin to which a certified check measures world distances (``WORLD_BOUND``
    #: otherwise): a straight move of 0.02 rad on every joint can carry a sphere several cm, and
    #: a clearance known only up to 2 cm certifies little of it.
    CERTIFY_BOUND = 0.06

    def move_bound(self, step: np.ndarray, axis_a: np.ndarray, axis_b: np.ndarray) -> np.ndarray:
        """(P,) how far the straight moves by ``step`` (P, 7) (absolute joint steps) can carry a
        sphere centre, from the axis distances at their two ends (``_axis_distances``, (P, 7)).
        Joint j turns a point at speed |dq_j| times its distance to j's axis; along the move
        that distance grows only through the later joints (the earlier ones carry the axis
        with the point): by at most ``sum_{k>j} |dq_k| joint_reach()[k]`` from either end's,
        and it never exceeds ``joint_reach()[j]``."""
        reach = self.joint_reach()
        carried = step * reach
        later = np.cumsum(carried[:, ::-1], axis=1)[:, ::-1] - carried  # sum over k > j
        radius = np.minimum(np.minimum(axis_a, axis_b) + later, reach)
        return (step * radius).sum(axis=1)

    def certified(self, q, facts, floor: float) -> bool:
        """Whether the straight joint-space moves between consecutive valid configurations
        ``q`` (N, 7), with their facts (``_valid_parts``: clearances and axis distances), are
        free. A move is certified when no sphere can reach an obstacle (or another sphere) on
        it: no sphere centre moves farther than ``move_bound`` and distances are 1-Lipschitz,
        so the world is clear when the two ends' world clearances beyond the margin sum to
        more than that, the self pairs when theirs sum to more than twice it (both spheres
        move). A move not certified is halved at its midpoint, checked (False when it
        collides), until its largest joint step is at most ``floor`` rad, where a move between
        valid ends is accepted. The midpoints count in ``n_checked``."""
        if not floor > 0:  # a floor of 0 would halve a move that grazes forever
            raise ValueError(f"certify needs a step floor > 0 rad, not {floor!r}")
        margin = self.margin
        a, b = np.asarray(q[:-1], float), np.asarray(q[1:], float)
        fa, fb = facts[:-1], facts[1:]
        while len(a):
            step = np.abs(b - a)
            move = self.move_bound(step, fa[:, 2:], fb[:, 2:])
            clear = (fa[:, 0] + fb[:, 0] - 2 * margin > move) & (fa[:, 1] + fb[:, 1] - 2 * margin > 2 * move)
            split = ~clear & (step.max(axis=1) > floor)
            if not split.any():
                return True
            a, b, fa, fb = a[split], b[split], fa[split], fb[split]
            mid = (a + b) / 2
            ok, fm = self._valid_parts(mid, self.CERTIFY_BOUND)
            if not ok.all():
                return False
            a, b = np.concatenate([a, mid]), np.concatenate([mid, b])
            fa, fb = np.concatenate([fa, fm]), np.concatenate([fm, fb])
        return True

    @staticmethod
    def _segment(q_from, q_to, resolution: float) -> np.ndarray:
        """The straight joint-space segment at ``resolution`` rad (max joint step), both ends in."""
        q_from, q_to = np.asarray(q_from, float), np.asarray(q_to, float)
        n = max(2, int(np.ceil(np.abs(q_to - q_from).max() / resolution)) + 1)
        s = np.linspace(0.0, 1.0, n)[:, None]
        return q_from + s * (q_to - q_from)

    def motion_valid(self, q_from, q_to, resolution: float = 0.02, first: int | None = None,
                     spread: bool = False, certify: float | None = None) -> bool:
        """Straight joint-space segment checked at ``resolution`` rad (max joint step);
        ``first``, ``spread``, ``certify``: as ``all_valid``'s."""
        return self.all_valid(self._segment(q_from, q_to, resolution), first, spread, certify)

    def first_valid_motion(self, q_from, q_tos, resolution: float = 0.02, first: int | None = None,
                           spread: bool = False, certify: float | None = None) -> int:
        """The index of the first of ``q_tos`` (K, 7) whose straight segment from ``q_from`` is
        valid (-1: none), with the answers and the ``n_checked`` of ``motion_valid`` called on
        each in turn until one is; but the first configurations of every segment (``first``,
        ``spread``: as ``all_valid``'s) are computed as one batch, so that a start whose direct
        segments all collide early (most searched problems) costs one batch, not one a goal.
        Each configuration's clearance does not depend on its batch: the same answers.
        ``certify``: as ``all_valid``'s (a valid segment not certified is not the answer)."""
        first = self.motion_check_first if first is None else first
        bound = None if certify is None else self.CERTIFY_BOUND
        segments = [self._segment(q_from, q_to, resolution) for q_to in np.asarray(q_tos, float).reshape(-1, 7)]
        if first <= 0 or not segments:  # each segment is checked whole: nothing to share
            return next((k for k, q in enumerate(segments) if self.all_valid(q, first, spread, certify)), -1)
        # a segment as short as its first batch is that batch whole
        heads = [h if (h := self._head(len(q), first, spread)) is not None else np.ones(len(q), bool) for q in segments]
        n0 = self.n_checked
        cuts = np.cumsum([int(h.sum()) for h in heads])[:-1]
        ok, facts = self._valid_parts(np.concatenate([q[h] for q, h in zip(segments, heads)]), bound)
        head_ok = np.split(ok, cuts)
        at_heads = np.split(facts, cuts) if facts is not None else [None] * len(segments)
        self.n_checked = n0  # counted below as motion_valid in turn counts: the segments up to the answer
        for k, (q, head, ok, at_head) in enumerate(zip(segments, heads, head_ok, at_heads)):
            if not ok.all():
                self.n_checked += int(self.robot.within_limits(q).sum())
                continue
            self.n_checked += int(self.robot.within_limits(q[head]).sum())
            if self._rest_valid(q, head, at_head, certify):
                return k
        return -1
