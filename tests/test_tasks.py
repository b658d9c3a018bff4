"""TaskSpec and the task sampler (no env needed)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from fetchbench_ms.scenes import SCENE_TYPES
from fetchbench_ms.tasks import CATEGORY_LABELS, SamplerConfig, TaskSpec, sample_task
from fetchbench_ms.objects.loading import collision_vertices, load_object
from fetchbench_ms.tasks.suite import TaskSuite, load_suite


@pytest.fixture(scope="module")
def task() -> TaskSpec:
    return sample_task(7)


def test_same_seed_same_bytes_and_different_seeds_differ(task):
    again = sample_task(7)
    assert again.to_json() == task.to_json()
    other = sample_task(8)
    assert other.to_json() != task.to_json()


def test_json_round_trip_is_identity(task):
    text = json.dumps(task.to_dict())
    back = TaskSpec.from_dict(json.loads(text))
    assert back == task
    assert back.content_hash() == task.content_hash()


def test_sampled_task_follows_the_rules(task):
    scene = task.scene()
    surfaces = {s.name: s for s in scene.support_surfaces}
    assert 1 <= len(task.objects) <= 15
    assert task.scene_type in SCENE_TYPES
    lo = np.array(task.robot_table_center) - np.array(task.robot_table_size) / 2
    hi = np.array(task.robot_table_center) + np.array(task.robot_table_size) / 2
    # The base stands on the robot table's top (at least a 1 cm plate), inside its footprint.
    assert hi[2] == pytest.approx(max(task.robot_base_position[2], 0.01))
    x, y, _ = np.array(task.robot_base_position) - np.array(task.robot_table_center)
    yaw = 2 * np.arctan2(task.robot_base_quat_wxyz[3], task.robot_base_quat_wxyz[0])
    along, across = x * np.cos(yaw) + y * np.sin(yaw), -x * np.sin(yaw) + y * np.cos(yaw)
    assert abs(along) <= task.robot_table_size[0] / 2 and abs(across) <= task.robot_table_size[1] / 2
    assert task.extra["camera_view_score"] > 0.3  # the cameras see a good part of the supports
    # Cameras mirror each other about the camera target's centre line and look towards it
    # (positions are stored on the 1 um grid: each side may round by half a micron).
    cy = scene.camera_target.center[1]
    assert task.camera_left.position[1] - cy == pytest.approx(cy - task.camera_right.position[1], abs=1.01e-6)
    region = scene.robot_region
    assert region.x_range[0] <= task.robot_base_position[0] <= region.x_range[1]
    for placement in task.objects:
        surface = surfaces[placement.support_surface]
        assert placement.support_label == surface.label
        assert 100 <= placement.density <= 400 and 0.6 <= placement.static_friction <= 1.2
        assert 0 <= placement.restitution <= 0.1
        # Settled: the object rests on its surface (lowest point within 1 cm of it).
        v = collision_vertices(load_object(placement.object_id))
        T = placement.transform()
        z = v @ T[:3, :3].T[:, 2] + T[2, 3]
        assert abs(z.min() - surface.height) < 0.01, placement


def test_objects_do_not_interpenetrate(task):
    manager = trimesh.collision.CollisionManager()
    for k, placement in enumerate(task.objects):
        for part in load_object(placement.object_id).convex_parts:
            manager.add_object(f"{k}:{id(part)}", part, transform=placement.transform())
    _, contacts = manager.in_collision_internal(return_data=True)
    # Settled objects may touch (resting against each other) but not overlap.
    depths = [c.depth for c in contacts if len({name.split(":")[0] for name in c.names}) == 2]
    assert max(depths, default=0.0) < 0.003


@pytest.mark.parametrize("category", list(CATEGORY_LABELS))
def test_category_gives_targets_of_that_category(category):
    for seed in range(3):
        task = sample_task(seed, category=category, config=SamplerConfig(num_objects=6))
        assert task.target_label == CATEGORY_LABELS[category]


def test_fixed_scene_type_is_respected():
    assert sample_task(1, scene_type="LargeShelf", config=SamplerConfig(num_objects=4)).scene_type == "LargeShelf"


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(scene_type="Shelfs"), "valid: CellShelfDesk"),
        (dict(category="Floor"), "valid: Table, Shelf, Drawer, Basket"),
    ],
)
def test_bad_sampler_input_names_valid_choices(kwargs, message):
    with pytest.raises(ValueError, match=message):
        sample_task(0, **kwargs)


def test_bad_sampler_config_is_refused():
    with pytest.raises(ValueError, match="num_objects must be 1..64"):
        SamplerConfig(num_objects=0)
    with pytest.raises(ValueError, match="valid: train, test"):
        SamplerConfig(object_split="val")


def test_malformed_task_dicts_are_rejected_with_the_valid_keys(task):
    d = task.to_dict()
    missing = {k: v for k, v in d.items() if k != "objects"}
    with pytest.raises(ValueError, match="missing objects"):
        TaskSpec.from_dict(missing)
    with pytest.raises(ValueError, match="unknown keys colour"):
        TaskSpec.from_dict({**d, "colour": 1})
    with pytest.raises(ValueError, match="unknown scene type 'Sofa'; valid: CellShelfDesk"):
        TaskSpec.from_dict({**d, "scene_type": "Sofa"})
    with pytest.raises(ValueError, match="target_index 99 out of range"):
        TaskSpec.from_dict({**d, "target_index": 99})
    bad_object = dict(d["objects"][0], quat_wxyz=[2, 0, 0, 0])
    with pytest.raises(ValueError, match="not unit length"):
        TaskSpec.from_dict({**d, "objects": [bad_object]})
    with pytest.raises(ValueError, match="version '0' is not supported"):
        TaskSpec.from_dict({**d, "version": "0"})


def test_stale_scene_generator_fails_loudly(task):
    stale = TaskSpec.from_dict({**task.to_dict(), "scene_hash": "0" * 64})
    with pytest.raises(ValueError, match="regenerates differently"):
        stale.scene()


def test_suite_round_trip_lookup_and_corruption(tmp_path, task):
    path = tmp_path / "suite.json"
    TaskSuite("mini", {"t0": task}).save(path)
    suite = load_suite(path)
    assert suite.get("t0") == task
    with pytest.raises(KeyError, match="unknown task id 'nope' in suite 'mini'; valid: t0"):
        suite.get("nope")
    path.write_text(path.read_text().replace('"mini"', '"edited"'))
    with pytest.raises(ValueError, match="corrupt"):
        load_suite(path)


def test_cli_samples_a_task_to_json_and_rejects_bad_categories(tmp_path, capsys):
    from fetchbench_ms.cli import main

    out = tmp_path / "task.json"
    assert main(["tasks", "sample", "--seed", "7", "-o", str(out)]) == 0
    # Train objects by default, as the envs' seeded resets.
    assert TaskSpec.from_dict(json.loads(out.read_text())) == sample_task(7, config=SamplerConfig(object_split="train"))
    assert main(["tasks", "sample", "--seed", "7", "--category", "Drawers"]) == 2
    assert "valid: Table, Shelf, Drawer, Basket" in capsys.readouterr().err


# ----------------------------------------------------------------------------- camera views
def _occluders(task):
    from fetchbench_ms.tasks.camera_views import Occluders

    return Occluders(task.scene(), task.robot_base_position, task.robot_base_quat_wxyz, task.robot_table_center,
                     task.robot_table_size)


def test_frustum_keeps_what_is_ahead_within_range():
    from fetchbench_ms.tasks.camera_views import FAR, in_frustum

    eye, target = np.zeros(3), np.array([1.0, 0.0, 0.0])
    points = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [1.0, 0.9, 0.0], [1.0, 0.0, 0.9], [FAR + 0.1, 0.0, 0.0]])
    inside = in_frustum(eye, target, points, np.radians(70), 4 / 3)
    # ahead; behind; 42 deg left (outside 35); 42 deg up (outside 27.7); too far
    assert inside.tolist() == [True, False, False, False, False]


def test_boards_and_the_robot_hide_what_is_behind_them():
    task = sample_task(3, scene_type="LargeShelf")
    occluders = _occluders(task)
    scene = task.scene()
    shelf = min((s for s in scene.surfaces("on_shelf")), key=lambda s: s.height)  # a board above it
    point = np.array([*shelf.polygon.centroid.coords[0], shelf.height + 0.03])
    above = point + [0.0, 0.0, 3.0]
    in_front = point + [-1.0, 0.0, 0.0]  # level with it, looking in from the open front
    assert not occluders.unobstructed(above, point[None])[0]
    # The robot or a divider may stand in between: some eye in front sees it.
    eyes = [in_front + [0, dy, dz] for dy in (-0.6, 0.0, 0.6) for dz in (0.0, 0.1)]
    assert any(occluders.unobstructed(e, point[None])[0] for e in eyes), "the lowest shelf is hidden from the front"
    # Through the middle of a robot sphere: hidden.
    center, radius = occluders.sphere_centers[40], occluders.sphere_radii[40]
    direction = np.array([0.0, 1.0, 0.0])
    eye, far_point = center - 0.5 * direction, center + 0.5 * direction
    assert not occluders.unobstructed(eye, far_point[None])[0]
    assert occluders.unobstructed(eye + [0, 0, 5 * radius + 1.0], (far_point + [0, 0, 5 * radius + 1.0])[None])[0]


@pytest.mark.parametrize("scene_type", ["Drawer", "DoubleDoorCabinet", "RoundTable"])
def test_chosen_cameras_see_more_than_a_random_candidate(scene_type):
    from fetchbench_ms.tasks.camera_views import sample_camera_pair

    task = sample_task(5, scene_type=scene_type, config=SamplerConfig(settle=False))
    occluders = _occluders(task)
    fov = np.radians(70)
    _, best, _ = sample_camera_pair(np.random.default_rng(1), task.scene(), occluders, fov, 4 / 3, tries=32)
    singles = [sample_camera_pair(np.random.default_rng(100 + k), task.scene(), occluders, fov, 4 / 3, tries=1)[1]
               for k in range(8)]
    assert best >= max(singles) - 0.1 and best > np.mean(singles)
    assert task.extra["camera_view_score"] > 0.3


# ----------------------------------------------------------------------------- fitting placement
def _slot_scene(long_side=0.30, short_side=0.10, angle=np.radians(30), wall=None):
    """A bare scene with one walled-less, narrow, turned support (label in_basket) and no furniture."""
    from types import SimpleNamespace

    from fetchbench_ms.scenes import SupportSurface

    c, s = np.cos(angle), np.sin(angle)
    corners = [(-long_side / 2, -short_side / 2), (long_side / 2, -short_side / 2), (long_side / 2, short_side / 2),
               (-long_side / 2, short_side / 2)]
    polygon = tuple((float(c * x - s * y + 1.0), float(s * x + c * y)) for x, y in corners)
    surface = SupportSurface("slot", "in_basket", polygon, height=0.5, free_height=0.3, supporting_part="none",
                             wall_top=None if wall is None else 0.5 + wall)
    return SimpleNamespace(parts=(), surfaces=lambda label: [surface] if label == "in_basket" else []), surface


def _footprint(placement):
    from shapely.geometry import MultiPoint

    from fetchbench_ms.tasks.spec import pose_matrix

    T = pose_matrix(placement.position, placement.quat_wxyz)
    v = collision_vertices(load_object(placement.object_id)) @ T[:3, :3].T + T[:3, 3]
    return MultiPoint(v[:, :2]).convex_hull


def test_aligned_yaw_makes_a_long_object_fit_a_narrow_support():
    from fetchbench_ms.tasks.sampler import _BoxWorld, _place_fitting, _place_one, _rectangle

    banana = "procedural/banana/0001"  # 19 x 3 cm: fits a 30 x 10 cm slot only along it
    config = SamplerConfig()
    fitted, uniform = 0, 0
    for seed in range(10):
        scene, slot = _slot_scene()
        placed = _place_fitting(np.random.default_rng(seed), scene, _BoxWorld(scene), [banana], "in_basket", config)
        if placed is not None:
            fitted += 1
            footprint = _footprint(placed)
            assert slot.polygon.buffer(1e-3).contains(footprint)  # inside the support
            length, _, angle = _rectangle(footprint)
            turn = (angle - np.radians(30)) % np.pi
            assert min(turn, np.pi - turn) < config.fit_yaw_jitter + np.radians(3)  # along the long side
            assert placed.position[2] > slot.height  # on it, not in it
        # The original's uniform yaw with as few attempts as the fitting placement gets (25).
        scene, _ = _slot_scene()
        few = SamplerConfig(placement_attempts=25)
        if _place_one(np.random.default_rng(seed), scene, _BoxWorld(scene), load_object(banana), ["in_basket"],
                      np.array([1.0]), few, None) is not None:
            uniform += 1
    assert fitted == 10
    assert uniform < fitted


def test_a_short_object_lies_across_so_the_hand_spans_the_long_side():
    """A top grasp closes the fingers over the object's short side: turned across a narrow
    support, the open hand (about 23 cm) lies along the support's long side."""
    from fetchbench_ms.tasks.sampler import _BoxWorld, _place_fitting, _rectangle

    marker = "procedural/marker/0024"  # 10 x 2 cm
    for fit_across, expected in ((True, np.pi / 2), (False, 0.0)):
        config = SamplerConfig(fit_across=fit_across)
        for seed in range(4):
            scene, slot = _slot_scene(long_side=0.30, short_side=0.15)
            placed = _place_fitting(np.random.default_rng(seed), scene, _BoxWorld(scene), [marker], "in_basket", config)
            assert placed is not None
            footprint = _footprint(placed)
            assert slot.polygon.buffer(1e-3).contains(footprint)
            turn = (_rectangle(footprint)[2] - np.radians(30) - expected) % np.pi
            assert min(turn, np.pi - turn) < config.fit_yaw_jitter + np.radians(3), (fit_across, seed)


def test_fitting_placement_skips_objects_that_cannot_fit():
    from fetchbench_ms.tasks.sampler import _BoxWorld, _fitting_poses, _place_fitting

    scene, slot = _slot_scene(long_side=0.12, short_side=0.05)
    config = SamplerConfig()
    banana = "procedural/banana/0001"
    assert _fitting_poses(banana, slot, config) == []
    assert _place_fitting(np.random.default_rng(0), scene, _BoxWorld(scene), [banana], "in_basket", config) is None


def test_in_a_walled_basket_objects_reaching_over_the_wall_are_preferred():
    from fetchbench_ms.objects.loading import object_ids
    from fetchbench_ms.tasks.sampler import _BoxWorld, _place_fitting
    from fetchbench_ms.tasks.spec import pose_matrix

    ids = object_ids("test")
    tops = {}
    for reach in (0.03, None):
        config = SamplerConfig(fit_wall_reach=reach)
        tops[reach] = []
        for seed in range(6):
            scene, slot = _slot_scene(long_side=0.25, short_side=0.17, wall=0.12)
            placed = _place_fitting(np.random.default_rng(seed), scene, _BoxWorld(scene), ids, "in_basket", config)
            assert placed is not None
            v = collision_vertices(load_object(placed.object_id))
            T = pose_matrix(placed.position, placed.quat_wxyz)
            tops[reach].append(float((v @ T[:3, :3].T + T[:3, 3])[:, 2].max()) - slot.height)
    assert min(tops[0.03]) >= 0.12 - 0.03 - 0.01  # every top reaches over the wall (settling aside)
    assert min(tops[None]) < 0.09  # without the preference, low objects sit between the walls


def test_fit_labels_put_more_objects_into_baskets_and_inside_them():
    """The suite's RoundTable case: one small basket. With fitting placement more of the
    same arrangements' objects land in it, and every one lies inside its floor polygon."""
    from fetchbench_ms.tasks import suite_build
    from fetchbench_ms.objects.loading import object_ids
    from fetchbench_ms.tasks.sampler import _sample_in_scene

    r = suite_build.recipe("test")
    plan = next(p for p in suite_build.plan_scenes(r) if p.scene_type == "RoundTable")
    weights = suite_build.placement_weights(plan.quota)
    counts = {}
    for fit in ((), ("in_basket",)):
        config = SamplerConfig(label_weights=weights, fit_labels=fit, settle=False)
        counts[fit] = 0
        for seed in range(4):
            task = _sample_in_scene(np.random.default_rng(seed), "RoundTable", plan.scene_seed, None,
                                    object_ids("test"), config)
            surfaces = {s.name: s for s in task.scene().support_surfaces}
            for placement in task.objects:
                if placement.support_label == "in_basket":
                    counts[fit] += 1
                    assert surfaces[placement.support_surface].polygon.buffer(1e-3).contains(_footprint(placement))
    assert counts[("in_basket",)] > counts[()], counts
    # Same seed, same arrangement, byte for byte (the fitting placement draws from the rng only).
    again = _sample_in_scene(np.random.default_rng(3), "RoundTable", plan.scene_seed, None, object_ids("test"), config)
    assert again.to_json() == task.to_json()


def test_camera_label_weights_lean_the_score():
    from fetchbench_ms.tasks.camera_views import view_score

    seen = np.array([1.0, 1.0, 0.0, 0.0])
    owners = [("on_table", "t"), ("on_table", "t"), ("in_basket", "b"), ("in_basket", "b")]
    assert view_score(seen, owners) == pytest.approx(0.5)
    assert view_score(seen, owners, {"on_table": 1.0, "in_basket": 3.0}) == pytest.approx(0.25)
    with pytest.raises(ValueError, match="valid: in_basket"):
        SamplerConfig(fit_labels=("in_box",))
