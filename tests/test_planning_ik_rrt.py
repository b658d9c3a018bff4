"""IK reaches what it claims, RRTConnect paths are collision-free against exact meshes,
time parametrisation respects the Panda's limits."""
import numpy as np
import pytest
import torch

from fetchbench_ms.planning.checker import Attachment, CollisionChecker
from fetchbench_ms.planning.demo_worlds import hand_pose, shelf_worlds
from fetchbench_ms.planning.exact import ExactRobot
from fetchbench_ms.planning.ik import POS_TOL, ROT_TOL, pose_errors, solve_ik
from fetchbench_ms.planning.robot import FINGER_OPEN, Q_DEFAULT
from fetchbench_ms.planning.rrt import densify, plan_rrtconnect
from fetchbench_ms.planning.timing import time_parametrize


@pytest.fixture(scope="module")
def shelf(robot):
    world, exact = shelf_worlds()
    return world, exact, CollisionChecker(robot, world)


def test_ik_reaches_reachable_poses_within_tolerance(robot):
    rng = np.random.default_rng(3)
    q_true = rng.uniform(robot.q_min, robot.q_max, (8, 7))
    targets = robot.link_poses(torch.as_tensor(q_true))["panda_hand_tcp"].numpy()
    result = solve_ik(robot, targets, n_seeds=32, rng=np.random.default_rng(0))
    assert set(result.target_index.tolist()) == set(range(8))
    e_pos, e_rot = pose_errors(robot, torch.as_tensor(result.q), torch.as_tensor(targets[result.target_index]))
    assert float(e_pos.max()) <= POS_TOL and float(e_rot.max()) <= ROT_TOL
    assert robot.within_limits(result.q).all()


def test_ik_unreachable_pose_has_no_solution(robot):
    far = hand_pose([1.4, 0.0, 0.4])  # beyond the Panda's ~0.85 m reach
    assert not solve_ik(robot, far, n_seeds=32).found


def test_ik_is_collision_aware(robot, shelf):
    world, exact, checker = shelf
    # Reachable without obstacles, but the TCP would sit inside the middle board.
    inside_board = hand_pose([0.62, 0.0, 0.3], approach=(0, 0, -1))
    assert solve_ik(robot, inside_board, n_seeds=32).found
    assert not solve_ik(robot, inside_board, checker=checker, n_seeds=32).found
    # Same reach, free space on the lower shelf: solutions exist and are collision-free.
    on_shelf = hand_pose([0.66, 0.05, 0.12])
    result = solve_ik(robot, on_shelf, checker=checker, q_seed=Q_DEFAULT, n_seeds=64)
    assert result.found
    exact_robot = ExactRobot(robot)
    assert all(not exact_robot.world_collisions(q, exact) for q in result.q)


def test_ik_same_seed_same_result(robot):
    target = hand_pose([0.5, 0.1, 0.3], approach=(0, 0, -1))
    a = solve_ik(robot, target, n_seeds=16, rng=np.random.default_rng(7))
    b = solve_ik(robot, target, n_seeds=16, rng=np.random.default_rng(7))
    assert np.array_equal(a.q, b.q)


def test_rrtconnect_into_shelf_is_collision_free_on_exact_meshes(robot, shelf):
    world, exact, checker = shelf
    goal_pose = hand_pose([0.68, -0.1, 0.12])
    goals = solve_ik(robot, goal_pose, checker=checker, q_seed=Q_DEFAULT, n_seeds=64)
    assert goals.found
    result = plan_rrtconnect(checker, Q_DEFAULT, goals.q[:4])
    assert result.success, result.status
    assert result.status == "solved"  # the straight segment hits the shelf: a real search
    assert np.allclose(result.path[0], Q_DEFAULT)
    assert np.allclose(result.path[-1], goals.q[result.goal_index])
    exact_robot = ExactRobot(robot)
    dense = densify(result.path, 0.01)
    collisions = [exact_robot.world_collisions(q, exact, FINGER_OPEN) for q in dense]
    assert not any(collisions), next(c for c in collisions if c)


def test_rrtconnect_reports_unreachable_goal(robot, shelf):
    world, exact, checker = shelf
    q_bad = Q_DEFAULT.copy()
    q_bad[1] = 1.7  # arm folded down into the robot table
    result = plan_rrtconnect(checker, Q_DEFAULT, q_bad)
    assert not result.success and result.status == "no_valid_goal"


def test_attachment_blocks_motion_the_bare_hand_could_make(robot, shelf):
    world, exact, checker = shelf
    q = solve_ik(robot, hand_pose([0.68, 0.0, 0.12]), checker=checker, q_seed=Q_DEFAULT, n_seeds=64).q[0]
    # A 20 cm stick held along the approach axis, from the TCP forward.
    points_tcp = np.column_stack([np.zeros(50), np.zeros(50), np.linspace(0.0, 0.2, 50)])
    points_hand = points_tcp + [0.0, 0.0, 0.1034]
    T_tcp = robot.link_poses(q[None])["panda_hand_tcp"][0].numpy()
    carrying = CollisionChecker(robot, world, attachment=Attachment.from_points(points_hand, n_spheres=10))
    assert checker.valid(q)[0]
    assert not carrying.valid(q)[0]
    assert T_tcp[0, 3] + 0.2 > 0.55 + 0.32  # sanity: the stick's far end is past the back board


def test_time_parametrisation_respects_limits_and_path(robot):
    path = np.stack([Q_DEFAULT, Q_DEFAULT + 0.6, Q_DEFAULT + np.array([0.6, -0.2, 0.6, 0.3, 0.6, 0.1, 0.0])])
    dt = 1 / 60
    traj = time_parametrize(path, dt, robot.velocity_limits, robot.acceleration_limits, speed_scale=0.5)
    assert np.allclose(traj[-1], path[-1])
    full = np.vstack([path[:1], traj])
    v = np.diff(full, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    assert np.all(np.abs(v) <= robot.velocity_limits * 0.5 + 1e-9)
    assert np.all(np.abs(a) <= robot.acceleration_limits * 0.25 * 1.05 + 1e-6 / dt)
    # Every sample lies on one of the straight segments (the checked path).
    def on_path(q):
        for p0, p1 in zip(path[:-1], path[1:]):
            d = p1 - p0
            s = np.clip(np.dot(q - p0, d) / np.dot(d, d), 0, 1)
            if np.abs(p0 + s * d - q).max() < 1e-9:
                return True
        return False
    assert all(on_path(q) for q in traj)
    with pytest.raises(ValueError, match="speed_scale"):
        time_parametrize(path, dt, robot.velocity_limits, robot.acceleration_limits, speed_scale=2.0)


def test_attachment_spheres_cover_the_object():
    import trimesh

    mesh = trimesh.creation.box((0.06, 0.04, 0.1))
    attachment = Attachment.from_convex_parts([mesh], n_spheres=64, seed=0)
    probe, _ = trimesh.sample.sample_surface(mesh, 3000, seed=np.random.default_rng(9))
    d = np.linalg.norm(probe[:, None] - attachment.centers_hand[None], axis=2) - attachment.radii[None]
    # Every surface point (not only the fitted samples) is inside a sphere.
    assert d.min(axis=1).max() <= 0.0
    # Tight: the balls bulge less than the 2 cm lift past the faces, so a lifted object is
    # free of the board it stood on.
    reach = (np.abs(attachment.centers_hand) + attachment.radii[:, None]).max(axis=0)
    assert np.all(reach - np.array([0.03, 0.02, 0.05]) < 0.016)


def test_hand_clearance_without_ik(robot, shelf):
    world, exact, checker = shelf
    inside_board = hand_pose([0.62, 0.0, 0.3], approach=(0, 0, -1))
    above_shelf = hand_pose([0.62, 0.0, 0.75], approach=(0, 0, -1))
    to_hand = np.linalg.inv(hand_pose([0, 0, 0.1034], approach=(0, 0, 1)))  # TCP -> hand
    clear = checker.hand_clearance(np.stack([inside_board, above_shelf]) @ to_hand)
    assert clear[0] < 0 < clear[1]
    assert checker.hand_clearance(np.zeros((0, 4, 4))).shape == (0,)


def test_a_start_the_spheres_call_in_collision_is_escaped_not_deepened(robot, shelf):
    """At rest the conservative spheres may overlap furniture the real arm does not touch:
    the planner first moves out along a segment never deeper than the start."""
    from fetchbench_ms.planning.rrt import densify, escape_start
    from fetchbench_ms.planning.world import box_set, pose_matrix

    world, _, checker = shelf
    centers = robot.sphere_centers(torch.as_tensor(Q_DEFAULT[None]))[0].numpy()
    radii = checker.radii.numpy()
    top = int(np.argmax(centers[:, 2] + radii))  # the highest sphere: a box just above it
    T_box = pose_matrix(centers[top] + [0.0, 0.0, radii[top]])  # a 2 cm tall box on the sphere's top: 1 cm overlap
    world.add("intruder", box_set(T_box, [0.04, 0.04, 0.02]))
    try:
        start_check = CollisionChecker(robot, world)
        depth = -float(start_check.clearance(Q_DEFAULT[None])[0])
        assert 0.005 < depth < 0.02
        q_goal = Q_DEFAULT.copy()
        q_goal[0] += 0.6
        q_goal[1] -= 0.3
        assert start_check.valid(q_goal)[0]
        assert plan_rrtconnect(start_check, Q_DEFAULT, q_goal).status == "start_invalid"
        assert escape_start(start_check, Q_DEFAULT, tolerance=depth / 2) is None  # deeper than allowed
        result = plan_rrtconnect(start_check, Q_DEFAULT, q_goal, start_tolerance=0.05)
        assert result.success and result.start_escaped
        assert np.allclose(result.path[0], Q_DEFAULT) and np.allclose(result.path[-1], q_goal)
        first = densify(result.path[:2], 0.02)
        assert (start_check.clearance(first).numpy() >= -depth - 1e-4).all()  # never deeper
        assert start_check.valid(densify(result.path[1:], 0.02)).all()  # then collision-free
        # Same start, same escape.
        assert np.array_equal(escape_start(start_check, Q_DEFAULT, 0.05), escape_start(start_check, Q_DEFAULT, 0.05))
    finally:
        world.groups.pop("intruder")


def test_segment_checks_that_look_at_the_first_configurations_first_answer_and_count_the_same(robot, shelf):
    """``CollisionChecker.motion_check_first`` (the expert's fast3): every segment's answer and
    counted checks are those of the whole-segment batch, a segment that collides near its start
    computes only its first configurations (or, ``spread``, a first batch spread over it), and
    RRTConnect plans the same path with the same count of checks."""
    world = shelf[0]
    whole, first = CollisionChecker(robot, world), CollisionChecker(robot, world)
    first.motion_check_first = 16
    computed = []
    clearance = first._clearance_parts
    first._clearance_parts = lambda q, bound=None: (computed.append(len(q)), clearance(q, bound))[1]
    rng = np.random.default_rng(3)
    q_in = solve_ik(robot, hand_pose([0.68, -0.1, 0.12]), checker=whole, q_seed=Q_DEFAULT, n_seeds=64).q[0]
    pairs = [(Q_DEFAULT, q_in), (q_in, Q_DEFAULT)] + [
        (q_in, q_in + rng.normal(0, 0.6, 7)) for _ in range(30)] + [
        (Q_DEFAULT, Q_DEFAULT + rng.normal(0, 0.1, 7)) for _ in range(5)]
    answers, early_exits, spread_exits = [], 0, 0
    for a, b in pairs:
        n0, m0, k0 = whole.n_checked, first.n_checked, len(computed)
        answer = whole.motion_valid(a, b)
        assert first.motion_valid(a, b) == answer
        assert first.n_checked - m0 == whole.n_checked - n0
        early_exits += sum(computed[k0:]) < whole.n_checked - n0
        m1, k1 = first.n_checked, len(computed)  # the first batch spread over the segment
        assert first.motion_valid(a, b, spread=True) == answer and first.n_checked - m1 == whole.n_checked - n0
        spread_exits += sum(computed[k1:]) < whole.n_checked - n0
        answers.append(answer)
    assert any(answers) and not all(answers) and early_exits >= 5 and spread_exits >= 5
    plans = [plan_rrtconnect(c, Q_DEFAULT, q_in, seed=7) for c in (whole, first)]
    assert plans[0].status == plans[1].status == "solved"
    assert plans[0].n_checked == plans[1].n_checked and np.array_equal(plans[0].path, plans[1].path)


def test_the_first_valid_of_many_segments_is_found_in_one_first_batch_with_the_same_answer_and_count(robot, shelf):
    """``CollisionChecker.first_valid_motion`` (the optimiser's direct segments to its goals):
    the index and the counted checks of ``motion_valid`` called on each segment in turn until
    one is valid, but every segment's first configurations computed as one batch."""
    world = shelf[0]
    in_turn, batched = CollisionChecker(robot, world), CollisionChecker(robot, world)
    calls, turn_calls = [], []
    clearance, turn_clearance = batched._clearance_parts, in_turn._clearance_parts
    batched._clearance_parts = lambda q, bound=None: (calls.append(len(q)), clearance(q, bound))[1]
    in_turn._clearance_parts = lambda q, bound=None: (turn_calls.append(len(q)), turn_clearance(q, bound))[1]
    rng = np.random.default_rng(5)
    q_in = solve_ik(robot, hand_pose([0.68, -0.1, 0.12]), checker=in_turn, q_seed=Q_DEFAULT, n_seeds=64).q[0]
    near = [q_in + rng.normal(0, 0.5, 7) for _ in range(12)]
    judge = CollisionChecker(robot, world)
    goal_sets = [np.stack([g for g in near if not judge.motion_valid(Q_DEFAULT, g)]),  # all colliding
                 np.stack([q_in, Q_DEFAULT + rng.normal(0, 0.05, 7), q_in]),  # a valid one after one that collides
                 np.stack([Q_DEFAULT + rng.normal(0, 0.05, 7) for _ in range(3)]),  # short segments, valid
                 np.zeros((0, 7))]
    answers = []
    for goals in goal_sets:
        for first, spread in ((16, True), (16, False), (0, False)):
            n0, m0, k0, j0 = in_turn.n_checked, batched.n_checked, len(calls), len(turn_calls)
            expected = next((k for k, g in enumerate(goals) if in_turn.motion_valid(Q_DEFAULT, g, 0.02, first, spread)), -1)
            assert batched.first_valid_motion(Q_DEFAULT, goals, 0.02, first, spread) == expected
            assert batched.n_checked - m0 == in_turn.n_checked - n0
            answers.append(expected)
            if first and goals is goal_sets[0]:  # one first batch, then the rest of those that pass it
                assert expected == -1 and len(goals) >= 4 and len(calls) - k0 < len(turn_calls) - j0
    assert -1 in answers and 1 in answers and 0 in answers


def test_the_shortcut_keeps_the_waypoints_and_counts_of_checking_its_candidates_in_turn(robot, shelf):
    """``trajopt.shortcut`` asks ``first_valid_motion`` for the farthest valid of its candidate
    jumps: the same waypoints and counted checks as trying them farthest first, one by one."""
    from fetchbench_ms.planning.trajopt import shortcut

    def in_turn(checker, path, resolution, first):  # the candidates one motion_valid at a time
        keep, i, last = [0], 0, len(path) - 1
        while i < last:
            span = last - i
            for j in sorted({last, i + 3 * span // 4, i + span // 2, i + span // 4, i + 1}, reverse=True):
                if j == i + 1 or (j > i and checker.motion_valid(path[i], path[j], resolution, first, spread=True)):
                    break
            keep.append(j)
            i = j
        return path[keep]

    world = shelf[0]
    a, b = CollisionChecker(robot, world), CollisionChecker(robot, world)
    rng = np.random.default_rng(11)
    q_in = solve_ik(robot, hand_pose([0.68, -0.1, 0.12]), checker=a, q_seed=Q_DEFAULT, n_seeds=64).q[0]
    shortened = 0
    for _ in range(12):  # paths from the start into the shelf through random via points, 24 waypoints
        via = Q_DEFAULT + rng.normal(0, 0.4, 7)
        s = np.linspace(0, 1, 12)[:, None]
        path = np.concatenate([Q_DEFAULT + s * (via - Q_DEFAULT), via + s * (q_in - via)])
        for first in (16, 0):
            n0, m0 = a.n_checked, b.n_checked
            expected = in_turn(a, path, 0.02, first)
            got = shortcut(b, path, 0.02, first)
            assert np.array_equal(got, expected) and b.n_checked - m0 == a.n_checked - n0
            shortened += len(got) < len(path) - 1
    assert shortened >= 4


# A segment in the shelf world whose configurations at 0.02 rad are all valid but which
# grazes the shelf between two of them (found by sampling segments between IK solutions).
GRAZING = (np.array([-1.540007668654732, 1.1401490094113504, 0.9257619024343691, -2.162810301453754,
                     2.798101023949373, 2.386425013991971, 0.23859416246194587]),
           np.array([-1.2203688239487942, 1.4475002017957612, 1.09449417547454, -2.239731722457559,
                     2.661909308623716, 2.1437622703739323, 0.01647551396649166]))


def test_joint_reach_bounds_how_far_a_move_carries_every_sphere(robot):
    """``CollisionChecker.joint_reach`` and ``move_bound``: over random moves anywhere in the
    joint limits, no sphere centre moves farther than ``move_bound`` from the axis distances
    at the move's ends, which is at most ``abs(dq) @ joint_reach()`` (what ``certified`` rests
    on) and well under it; every joint moves something."""
    checker = CollisionChecker(robot, shelf_worlds()[0])
    reach = checker.joint_reach()
    assert reach.shape == (7,) and (reach > 0).all() and reach[0] >= reach[-1]
    rng = np.random.default_rng(0)
    q = rng.uniform(robot.q_min, robot.q_max, (300, 7))
    dq = rng.normal(0, 1, (300, 7)) * rng.uniform(0.005, 0.3, (300, 1))
    q2 = np.clip(q + dq, robot.q_min, robot.q_max)
    c1 = robot.sphere_centers(torch.as_tensor(q), checker.finger)
    c2 = robot.sphere_centers(torch.as_tensor(q2), checker.finger)
    moved = (c2 - c1).norm(dim=2).amax(dim=1).numpy()
    _, facts = checker._valid_parts(q, checker.CERTIFY_BOUND)
    _, facts2 = checker._valid_parts(q2, checker.CERTIFY_BOUND)
    bound = checker.move_bound(np.abs(q2 - q), facts[:, 2:], facts2[:, 2:])
    assert (moved <= bound + 1e-12).all() and (bound <= np.abs(q2 - q) @ reach + 1e-12).all()
    assert np.median(bound / (np.abs(q2 - q) @ reach)) < 0.8


def test_a_certified_check_rejects_a_segment_that_grazes_between_its_configurations(robot, shelf):
    """``certify``: the moves between a segment's checked configurations must be free too.
    The grazing segment passes the 0.02 rad check and fails a 0.001 one; certified, it fails,
    having checked midpoints (counted). Certified segments are free at 0.001 rad, and the
    default check's answers and counts do not change."""
    world = shelf[0]
    checker, plain = CollisionChecker(robot, world), CollisionChecker(robot, world)
    a, b = GRAZING
    assert checker.motion_valid(a, b, 0.02) and not checker.motion_valid(a, b, 0.001)
    n0 = checker.n_checked
    assert not checker.motion_valid(a, b, 0.02, certify=0.005)
    assert checker.n_checked - n0 > len(CollisionChecker._segment(a, b, 0.02))  # the midpoints it checked
    rng = np.random.default_rng(1)
    certified = 0
    for _ in range(40):
        a = np.clip(GRAZING[0] + rng.normal(0, 0.3, 7), robot.q_min, robot.q_max)
        b = np.clip(GRAZING[1] + rng.normal(0, 0.3, 7), robot.q_min, robot.q_max)
        n0, m0 = checker.n_checked, plain.n_checked
        answer = checker.motion_valid(a, b, 0.02)
        assert answer == plain.motion_valid(a, b, 0.02) and checker.n_checked - n0 == plain.n_checked - m0
        if checker.motion_valid(a, b, 0.02, certify=0.005):
            certified += 1
            assert answer and plain.motion_valid(a, b, 0.001)
    assert certified >= 5
    with pytest.raises(ValueError, match="certify needs a step floor > 0 rad, not 0"):
        checker.motion_valid(*GRAZING, 0.02, certify=0)
