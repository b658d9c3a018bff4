"""The scene library: every registered type (at several seeds) and a hand-made reference
scene pass the geometric checks and load into SAPIEN so that objects rest on every
support surface; generation is deterministic; bad input fails with the valid choices.
The checks themselves are tested on deliberately broken scenes (they must catch them)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import sapien
from conftest import reference_shelf, scene_cases
from shapely.ops import polylabel

from fetchbench_ms import cli
from fetchbench_ms.scenes import Part, SceneSpec, SupportSurface, generate, get_scene_type, scene_types
from fetchbench_ms.scenes.checks import (
    assert_scene_ok,
    check_scene,
    penetrations,
    reachable_fractions,
)
from fetchbench_ms.scenes.sapien_build import build_static_scene
from fetchbench_ms.utils.sapien_device import new_scene

# ---------------------------------------------------------------------------------------
# Every scene passes every check.


@pytest.mark.parametrize("make_spec", scene_cases())
def test_scene_passes_geometric_checks(make_spec):
    assert_scene_ok(make_spec())


@pytest.mark.slow
@pytest.mark.parametrize("make_spec", scene_cases(seeds=range(3, 40)))
def test_scene_passes_geometric_checks_many_seeds(make_spec):
    assert_scene_ok(make_spec())


def test_every_registered_type_offers_its_declared_labels():
    for name, st in scene_types().items():
        seen = set()
        for seed in range(4):
            seen |= set(generate(name, seed).support_labels)
        assert set(st.support_labels) <= seen, f"{name} declares {st.support_labels}, seeds 0-3 give {sorted(seen)}"


# ---------------------------------------------------------------------------------------
# The checks catch what they are meant to catch.


def _with_parts(spec: SceneSpec, *parts: Part) -> SceneSpec:
    return dataclasses.replace(spec, parts=spec.parts + parts)


def _with_surface(spec: SceneSpec, index: int, **changes) -> SceneSpec:
    surfaces = list(spec.support_surfaces)
    surfaces[index] = dataclasses.replace(surfaces[index], **changes)
    return dataclasses.replace(spec, support_surfaces=tuple(surfaces))


def test_reference_shelf_is_clean():
    assert check_scene(reference_shelf()) == {
        "interpenetration": [],
        "floor": [],
        "support": [],
        "free_height": [],
        "reachability": [],
        "robot_region": [],
    }


def test_interpenetration_depth_is_measured_and_groups_are_ignored():
    shelf = reference_shelf()
    # A 4 cm cube sunk 15 mm into the middle board (board top at z=0.65).
    cube = Part("cube", "box", (0.04, 0.04, 0.04), (0.5, 0.0, 0.65 + 0.02 - 0.015))
    [found] = penetrations(_with_parts(shelf, cube))
    assert {found.part_a, found.part_b} == {"board_1", "cube"}
    assert found.depth == pytest.approx(0.015, abs=1e-4)
    # Resting exactly on the board is not a penetration, 0.5 mm is within tolerance.
    for sink in (0.0, 0.0005):
        resting = dataclasses.replace(cube, position=(0.5, 0.0, 0.67 - sink))
        assert penetrations(_with_parts(shelf, resting)) == []
    # A tilted cylinder through a side panel, measured by GJK/EPA.
    rod = Part("rod", "cylinder", (0.01, 0.2), (0.5, 0.40 + 0.01 + 0.01 - 0.004, 0.9), quat_wxyz=(0.7071068, 0.7071068, 0, 0))
    # (axis along y, centred at y = 0.416: it crosses the left panel, y in [0.40, 0.42])
    depths = {frozenset((p.part_a, p.part_b)): p.depth for p in penetrations(_with_parts(shelf, rod))}
    assert frozenset(("rod", "side_left")) in depths
    # Parts of one group may overlap (e.g. a woven basket's slats).
    a = Part("slat_a", "box", (0.1, 0.02, 0.02), (0.5, 0.0, 0.2), group="basket")
    b = Part("slat_b", "box", (0.02, 0.1, 0.02), (0.5, 0.0, 0.2), group="basket")
    assert penetrations(_with_parts(shelf, a, b)) == []
    c = dataclasses.replace(b, group="other")
    assert [p.depth for p in penetrations(_with_parts(shelf, a, c))] == [pytest.approx(0.02, abs=1e-4)]


def test_support_check_finds_floating_surfaces_and_intruders():
    shelf = reference_shelf()
    floating = _with_surface(shelf, 1, height=0.66)
    assert any("top under" in p for p in check_scene(floating)["support"])
    buried = _with_surface(shelf, 1, height=0.64)  # inside the board (z 0.63-0.65)
    assert any("top under" in p and "is at z=0.6500" in p for p in check_scene(buried)["support"])
    wrong_part = _with_surface(shelf, 1, supporting_part="board_0")
    assert check_scene(wrong_part)["support"]
    missing_part = _with_surface(shelf, 1, supporting_part="no_such_board")
    assert any("does not exist" in p for p in check_scene(missing_part)["support"])
    # The polygon sticks out 5 cm past the front of its board.
    polygon = ((0.30, -0.39), (0.69, -0.39), (0.69, 0.39), (0.30, 0.39))
    overhang = _with_surface(shelf, 0, polygon_xy=polygon)
    assert any("not above" in p for p in check_scene(overhang)["support"])
    # A crossbar 5 cm above the bottom shelf: inside the 8 cm an object needs.
    bar = Part("crossbar", "box", (0.02, 0.8, 0.02), (0.5, 0.0, 0.36))
    problems = check_scene(_with_parts(shelf, bar))["support"]
    assert any("crossbar" in p and "shelf_0" in p for p in problems)
    # ... but 9 cm above it is fine for the support check.
    high_bar = dataclasses.replace(bar, position=(0.5, 0.0, 0.40))
    assert check_scene(_with_parts(shelf, high_bar))["support"] == []


def test_support_check_handles_non_convex_polygons():
    shelf = reference_shelf()
    # An L-shaped usable area; a post standing in its cut-out corner is allowed,
    # the same post inside the L is not.
    l_shape = ((0.36, -0.39), (0.69, -0.39), (0.69, 0.0), (0.50, 0.0), (0.50, 0.39), (0.36, 0.39))
    spec = _with_surface(shelf, 1, polygon_xy=l_shape)
    assert check_scene(spec)["support"] == []
    post_outside = Part("post", "box", (0.04, 0.04, 0.1), (0.60, 0.2, 0.70))
    assert check_scene(_with_parts(spec, post_outside))["support"] == []
    post_inside = dataclasses.replace(post_outside, position=(0.43, 0.2, 0.70))
    assert any("post" in p for p in check_scene(_with_parts(spec, post_inside))["support"])


def test_free_height_reachability_floor_and_robot_region_checks():
    shelf = reference_shelf()
    low = _with_surface(shelf, 2, free_height=0.05)
    assert check_scene(low)["free_height"] == ["surface 'shelf_2': free height 0.050 m < 0.08 m"]
    # The robot 1 m further back: the shelves are out of reach.
    far = dataclasses.replace(shelf, robot_region=dataclasses.replace(shelf.robot_region, x_range=(-1.15, -1.0)))
    assert len(check_scene(far)["reachability"]) == 3
    assert max(reachable_fractions(far).values()) < 0.1
    # A base higher than a surface cannot reach down to it (band is 0-1.3 m above the base).
    high = dataclasses.replace(shelf, robot_region=dataclasses.replace(shelf.robot_region, z_range=(0.5, 0.6)))
    assert [p.split("'")[1] for p in check_scene(high)["reachability"]] == ["shelf_0"]
    sunk = _with_parts(shelf, Part("sunk", "box", (0.1, 0.1, 0.1), (2.0, 2.0, 0.03)))
    assert check_scene(sunk)["floor"] == ["part 'sunk' reaches 20.0 mm below the floor"]
    in_the_way = _with_parts(shelf, Part("stool", "box", (0.3, 0.3, 0.3), (-0.1, 0.0, 0.15)))
    assert [p.split("'")[1] for p in check_scene(in_the_way)["robot_region"]] == ["stool"]
    # Shelf 0 claims 0.5 m of free height, but the next board (z 0.63-0.65) is in the way.
    overclaimed = _with_surface(shelf, 0, free_height=0.5)
    [problem] = check_scene(overclaimed)["free_height"]
    assert "part 'board_1' intrudes" in problem and "its claimed free height of 0.500 m" in problem
    with pytest.raises(AssertionError, match=r"\[free_height\] surface 'shelf_2'"):
        assert_scene_ok(low)
    with pytest.raises(ValueError, match="valid: interpenetration, floor"):
        check_scene(shelf, ("nonsense",))


# ---------------------------------------------------------------------------------------
# Physics: the scene loads as static bodies and objects rest on every surface.

BOX_HALF = 0.02  # a 4 cm cube
SIM_DT = 1 / 120
SETTLE_S = 1.5


def _drop_boxes(spec: SceneSpec):
    """Load ``spec`` into SAPIEN, drop a box 5 mm above a point well inside each surface,
    simulate, and return (furniture entity, [(surface, start xy, end pose, speed)])."""
    scene = new_scene()
    scene.set_timestep(SIM_DT)
    furniture = build_static_scene(scene, spec)
    drops = []
    material = sapien.physx.PhysxMaterial(0.8, 0.8, 0.0)
    for surface in spec.support_surfaces:
        # The pole of inaccessibility: the point farthest inside the polygon.
        centre = polylabel(surface.polygon, tolerance=1e-3)
        builder = scene.create_actor_builder()
        builder.add_box_collision(half_size=[BOX_HALF] * 3, material=material, density=300)
        builder.add_box_visual(half_size=[BOX_HALF] * 3)
        box = builder.build(name=f"box_{surface.name}")
        box.set_pose(sapien.Pose([centre.x, centre.y, surface.height + BOX_HALF + 0.005]))
        drops.append((surface, np.array([centre.x, centre.y]), box))
    for _ in range(int(SETTLE_S / SIM_DT)):
        scene.step()
    results = []
    for surface, start_xy, box in drops:
        body = box.find_component_by_type(sapien.physx.PhysxRigidDynamicComponent)
        results.append((surface, start_xy, box.get_pose(), float(np.linalg.norm(body.get_linear_velocity()))))
    return furniture, results


def _assert_boxes_rest(spec: SceneSpec):
    furniture, results = _drop_boxes(spec)
    static = furniture.find_component_by_type(sapien.physx.PhysxRigidStaticComponent)
    assert static is not None, "furniture must be one static body"
    assert len(static.get_collision_shapes()) == len(spec.parts)
    for surface, start_xy, pose, speed in results:
        where = f"{spec.scene_type} seed {spec.seed}, surface {surface.name!r}"
        bottom = pose.p[2] - BOX_HALF
        assert abs(bottom - surface.height) < 0.003, f"{where}: box bottom at {bottom:.4f}, surface at {surface.height:.4f}"
        assert np.linalg.norm(pose.p[:2] - start_xy) < 0.01, f"{where}: box slid {pose.p[:2] - start_xy}"
        assert speed < 0.01, f"{where}: box still moves at {speed:.3f} m/s"


@pytest.mark.parametrize("make_spec", scene_cases(seeds=(0, 1)))
def test_objects_rest_on_every_support_surface(make_spec):
    _assert_boxes_rest(make_spec())


@pytest.mark.slow
@pytest.mark.parametrize("make_spec", scene_cases(seeds=range(2, 12)))
def test_objects_rest_on_every_support_surface_many_seeds(make_spec):
    _assert_boxes_rest(make_spec())


def test_drop_test_notices_a_missing_board():
    # The board under shelf 1 is gone: the box falls to the board below.
    shelf = reference_shelf()
    spec = dataclasses.replace(shelf, parts=tuple(p for p in shelf.parts if p.name != "board_1"))
    with pytest.raises(AssertionError, match="surface 'shelf_1'"):
        _assert_boxes_rest(spec)


# ---------------------------------------------------------------------------------------
# Determinism and serialisation.


@pytest.mark.parametrize("name", list(scene_types()) or ["<none registered>"])
def test_same_seed_same_bytes_different_seed_differs(name):
    if name not in scene_types():
        pytest.fail("no scene types are registered")
    a, b = generate(name, 11), generate(name, 11)
    assert a.content_hash() == b.content_hash()
    assert json.dumps(a.to_dict(), sort_keys=True) == json.dumps(b.to_dict(), sort_keys=True)
    hashes = {generate(name, seed).content_hash() for seed in (11, 12, 13)}
    assert len(hashes) == 3
    # A generator given the same Generator state draws the same scene.
    c = generate(name, np.random.default_rng(11))
    assert c.parts == a.parts and c.seed is None


@pytest.mark.parametrize("make_spec", scene_cases(seeds=(4,)))
def test_json_round_trip(make_spec):
    spec = make_spec()
    text = json.dumps(spec.to_dict())
    back = SceneSpec.from_dict(json.loads(text))
    assert back == spec
    assert back.content_hash() == spec.content_hash()


def test_override_changes_only_that_parameter():
    for name, st in scene_types().items():
        base = generate(name, 3)
        param = next(p for p in st.params if p.kind == "float")
        value = (param.low + param.high) / 2
        changed = generate(name, 3, overrides={param.name: value})
        assert changed.params[param.name] == value
        assert {k: v for k, v in changed.params.items() if k != param.name} == {
            k: v for k, v in base.params.items() if k != param.name
        }


# ---------------------------------------------------------------------------------------
# Bad input: the API and the CLI name what is valid.


def _a_type():
    types = scene_types()
    if not types:
        pytest.fail("no scene types are registered")
    return next(iter(types.values()))


def test_bad_input_through_the_api():
    st = _a_type()
    with pytest.raises(ValueError, match=rf"unknown scene type 'Shelfs'; valid: .*{st.name}"):
        generate("Shelfs", 0)
    with pytest.raises(ValueError, match=rf"no parameter 'nonsense'; valid: .*{st.params[0].name}"):
        generate(st.name, 0, overrides={"nonsense": 1.0})
    p = st.params[0]
    with pytest.raises(ValueError, match=rf"{p.name}.*out of range \[{p.low}, {p.high}\]"):
        generate(st.name, 0, overrides={p.name: p.high + 1.0})
    with pytest.raises(ValueError, match="unknown support label 'on_floor'; valid: on_table"):
        generate(st.name, 0).surfaces("on_floor")
    with pytest.raises(ValueError, match="unknown part shape 'sphere'; valid: box"):
        Part("ball", "sphere", (0.1,), (0, 0, 0))


@pytest.mark.parametrize(
    "argv_tail, message",
    [
        (["render", "Shelfs", "--out", "x.png"], "unknown scene type 'Shelfs'; valid: "),
        (["export", "Shelfs", "--out", "x.glb"], "unknown scene type 'Shelfs'; valid: "),
        (["generate", "{type}", "--set", "nonsense=1"], "has no parameter 'nonsense'; valid: "),
        (["generate", "{type}", "--set", "{param}=1e6"], "is out of range"),
        (["generate", "{type}", "--set", "{param}"], "--set takes NAME=VALUE"),
        (["export", "{type}", "--out", "x.stl"], "valid suffixes: .glb, .obj"),
        (["render", "{type}", "--out", "x.jpg"], "must name a .png file"),
        (["params", "Shelfs"], "unknown scene type 'Shelfs'; valid: "),
        (["check", "{type}", "--only", "nonsense"], "unknown scene check(s) ['nonsense']; valid: "),
    ],
)
def test_bad_input_through_the_cli(argv_tail, message, capsys, tmp_path):
    st = _a_type()
    argv = ["scenes"] + [a.format(type=st.name, param=st.params[0].name) for a in argv_tail]
    argv = [str(tmp_path / a) if a.startswith("x.") else a for a in argv]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("fetchbench: error: ") and message in err
    assert len(err.strip().splitlines()) == 1  # one line, no traceback
    assert not any(tmp_path.iterdir()), "nothing is written on bad input"


def test_cli_rejects_negative_seeds(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["scenes", "generate", _a_type().name, "--seed", "-1"])
    assert exit_info.value.code == 2
    assert "a seed is an integer >= 0, got -1" in capsys.readouterr().err


def test_cli_entry_point_exit_code_and_stderr(tmp_path):
    import subprocess
    import sys

    run = subprocess.run(
        [sys.executable, "-m", "fetchbench_ms", "scenes", "export", "Shelfs", "--out", str(tmp_path / "x.glb")],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 2
    assert "unknown scene type 'Shelfs'; valid:" in run.stderr and run.stdout == ""


def test_cli_list_generate_and_check(capsys, tmp_path):
    types = scene_types()
    assert cli.main(["scenes", "list", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in rows] == list(types)
    for row in rows:
        st = get_scene_type(row["name"])
        assert row["n_params"] == len(st.params) and row["support_labels"] == list(st.support_labels)
    st = _a_type()
    out = tmp_path / "spec.json"
    assert cli.main(["scenes", "generate", st.name, "--seed", "5", "--out", str(out)]) == 0
    assert SceneSpec.from_dict(json.loads(out.read_text())).content_hash() == generate(st.name, 5).content_hash()
    capsys.readouterr()
    assert cli.main(["scenes", "check", st.name, "--seeds", "0-1"]) == 0
    assert capsys.readouterr().out.splitlines() == [f"{st.name} seed 0: ok", f"{st.name} seed 1: ok"]


def test_support_surface_validation():
    with pytest.raises(ValueError, match="polygon of >= 3 vertices"):
        SupportSurface("s", "on_table", ((0, 0), (1, 0)), 0.5, 0.3, "top")


def test_type_stats_summarise_the_generated_scenes():
    from fetchbench_ms.scenes.stats import stats_table, type_stats

    name = _a_type().name
    specs = [generate(name, seed) for seed in range(3)]
    stats = type_stats(name, range(3))
    assert stats.n_params == len(get_scene_type(name).params)
    assert stats.parts_mean == pytest.approx(np.mean([len(s.parts) for s in specs]))
    for label in ("on_table", "on_shelf", "in_drawer", "in_basket"):
        assert stats.surfaces_mean[label] == pytest.approx(np.mean([len(s.surfaces(label)) for s in specs]))
    heights = [surface.height for s in specs for surface in s.support_surfaces]
    assert stats.height_range == (min(heights), max(heights))
    assert 0.5 <= stats.reach_min <= 1.0  # the reachability check passes on these seeds
    assert stats_table([stats]).splitlines()[2].startswith(name)
