"""Shared test fixtures: a hand-made reference scene and the list of scenes to test.

``reference_shelf`` is a small bookshelf built by hand (not by a generator): the checks
must pass on it, and each of its deliberately broken variants in the tests must fail one
check. The scene cases cover it plus every registered scene type at a few seeds, so the
tests grow with the library.
"""
from __future__ import annotations

import os
import tempfile

import pytest

from fetchbench_ms.scenes import (
    CameraTargetRegion,
    Material,
    Part,
    RobotRegion,
    SceneSpec,
    SupportSurface,
    generate,
    scene_types,
)

# Keep the mesh cache (content-addressed, so safe to share between runs) out of the home folder.
os.environ.setdefault("FETCHBENCH_CACHE", os.path.join(tempfile.gettempdir(), "fetchbench_ms_test_cache"))

# SAPIEN renders on one device per process, and a plain ``sapien.Scene()`` picks the first
# device it finds while ManiSkill asks for "cuda", else "cpu". Holding a renderer on
# ManiSkill's device for the whole session makes every scene any test creates agree with
# the envs, whatever order the tests run in (and spares shader recompilation).
try:
    from fetchbench_ms.utils.sapien_device import render_device

    import sapien

    _SESSION_RENDERER = sapien.render.RenderSystem(render_device())
except RuntimeError:  # no Vulkan device at all: the rendering tests fail on their own
    _SESSION_RENDERER = None

#: Seeds every registered type is tested at (the default run; slow tests use more).
SEEDS = (0, 1, 2)

WOOD = Material((0.62, 0.45, 0.30, 1.0))


def reference_shelf(board_heights=(0.30, 0.65, 1.00), width=0.80, depth=0.35, front_x=0.35) -> SceneSpec:
    """A bookshelf of boards between two side panels, a back panel and a top board."""
    t = 0.02  # board thickness
    top_z = 1.30
    cx = front_x + depth / 2
    parts = [
        Part("side_left", "box", (depth, t, top_z), (cx, width / 2 + t / 2, top_z / 2), material=WOOD),
        Part("side_right", "box", (depth, t, top_z), (cx, -width / 2 - t / 2, top_z / 2), material=WOOD),
        Part("back", "box", (t, width + 2 * t, top_z), (front_x + depth + t / 2, 0.0, top_z / 2), material=WOOD),
        Part("top", "box", (depth, width, t), (cx, 0.0, top_z - t / 2), material=WOOD),
    ]
    surfaces = []
    tops = list(board_heights) + [top_z - t]
    for k, h in enumerate(board_heights):
        parts.append(Part(f"board_{k}", "box", (depth, width, t), (cx, 0.0, h - t / 2), material=WOOD))
        inset = 0.01
        polygon = (
            (front_x + inset, -width / 2 + inset),
            (front_x + depth - inset, -width / 2 + inset),
            (front_x + depth - inset, width / 2 - inset),
            (front_x + inset, width / 2 - inset),
        )
        free = tops[k + 1] - t - h if k + 1 < len(board_heights) else tops[k + 1] - h
        surfaces.append(SupportSurface(f"shelf_{k}", "on_shelf", polygon, h, free, f"board_{k}"))
    return SceneSpec(
        scene_type="ReferenceShelf",
        seed=None,
        params={"width": width, "depth": depth},
        parts=tuple(parts),
        support_surfaces=tuple(surfaces),
        robot_region=RobotRegion((-0.15, 0.0), (-0.1, 0.1), (0.15, 0.28)),
        camera_target=CameraTargetRegion((cx, 0.0, 0.65), (depth / 2, width / 2, 0.4)),
    )


def scene_cases(seeds=SEEDS):
    """(id, factory) for the reference shelf and every registered type at ``seeds``."""
    cases = [pytest.param(reference_shelf, id="ReferenceShelf")]
    for name in scene_types():
        for seed in seeds:
            cases.append(pytest.param(lambda name=name, seed=seed: generate(name, seed), id=f"{name}-{seed}"))
    return cases


@pytest.fixture(scope="module")
def robot():
    """The planners' Panda model (sphere model and batched kinematics), one torch thread as
    the planners run in the eval workers."""
    import torch

    from fetchbench_ms.planning.robot import panda

    torch.set_num_threads(1)
    return panda()


@pytest.fixture(scope="module")
def shelf_problem(robot):
    """The hand-made shelf world's planning problem: its checker, its exact meshes and four
    collision-free IK goals inside the shelf, which the straight segment from the default
    configuration does not reach."""
    import numpy as np

    from fetchbench_ms.planning.checker import CollisionChecker
    from fetchbench_ms.planning.demo_worlds import hand_pose, shelf_worlds
    from fetchbench_ms.planning.ik import solve_ik
    from fetchbench_ms.planning.robot import Q_DEFAULT

    world, exact = shelf_worlds()
    checker = CollisionChecker(robot, world)
    goals = solve_ik(robot, hand_pose([0.68, -0.1, 0.12]), checker=checker, q_seed=Q_DEFAULT, n_seeds=32,
                     rng=np.random.default_rng(1))
    assert goals.found
    return checker, exact, goals.q[:4]
