"""The 13 procedural scene types: names, support categories, parameters, per-type geometry.

The generic geometric checks over all types (interpenetration, support, reach, SAPIEN
drops, determinism, bad input) live in test_scenes*.py; these tests pin down what each
type must be: the paper's categories, live parameters and furniture-specific rules.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from shapely.geometry import Polygon

from fetchbench_ms.scenes import SCENE_TYPES, generate, get_scene_type, scene_types
from fetchbench_ms.scenes.geometry import part_aabb
from fetchbench_ms.utils.io import canonical_json, sha256_bytes

#: The support categories of each type: the non-zero columns of the paper's appendix table
#: (Table "Statistics of different types of procedural scenes").
PAPER_LABELS = {
    "CellShelfDesk": {"on_table", "on_shelf", "in_basket"},
    "Desk": {"on_table"},
    "DeskWall": {"on_table", "on_shelf"},
    "DoubleDoorCabinet": {"on_shelf", "in_basket"},
    "Drawer": {"in_drawer"},
    "DrawerShelf": {"on_shelf", "in_drawer", "in_basket"},
    "EketShelf": {"on_shelf"},
    "LargeShelf": {"on_shelf", "in_basket"},
    "LargeShelfDesk": {"on_table", "on_shelf", "in_basket"},
    "LayerShelf": {"on_shelf", "in_basket"},
    "RoundTable": {"on_table", "in_basket"},
    "SingleDoorCabinetDesk": {"on_table", "on_shelf", "in_basket"},
    "TriangleShelfDesk": {"on_shelf"},
}
SEEDS = range(5)


def on_grid(expected):
    """Equal up to the scene grid: every derived number is stored to 1 um (SceneSpec.on_grid),
    so a sum of two of them may be off by about a micron."""
    return pytest.approx(expected, abs=2e-6)


def geometry_hash(spec) -> str:
    """Hash of everything a scene is made of, without the parameter values themselves."""
    d = spec.to_dict()
    d.pop("params")
    d.pop("seed")
    return sha256_bytes(canonical_json(d).encode())


def test_the_13_paper_types_are_registered():
    assert set(scene_types()) == set(SCENE_TYPES) == set(PAPER_LABELS)
    for name, st in scene_types().items():
        assert st.name == name
        assert set(st.support_labels) == PAPER_LABELS[name], name
        assert st.description.strip(), f"{name} has no description"


def test_parameter_count_reaches_the_papers_figure():
    counts = {name: len(st.params) for name, st in scene_types().items()}
    assert sum(counts.values()) >= 310, counts
    assert min(counts.values()) >= 20, counts
    for st in scene_types().values():
        for p in st.params:
            assert p.doc and p.unit in ("m", "rad", "count", "1"), (st.name, p)
            assert p.high > p.low, f"{st.name}.{p.name} has an empty range"


@pytest.mark.parametrize("name", SCENE_TYPES)
@pytest.mark.parametrize("seed", SEEDS)
def test_type_offers_the_papers_categories(name, seed):
    spec = generate(name, seed)
    assert set(spec.support_labels) == PAPER_LABELS[name]
    for s in spec.support_surfaces:
        assert s.free_height >= 0.08, (s.name, s.free_height)
        assert Polygon(s.polygon_xy).is_valid and s.area > 0.01, s.name
        assert (s.wall_top is not None) == (s.label in ("in_basket", "in_drawer")), s.name
        if s.wall_top is not None:
            assert s.wall_top > s.height + 0.04, s.name
    names = [p.name for p in spec.parts]
    assert len(names) == len(set(names))


@pytest.mark.parametrize("name", SCENE_TYPES)
def test_every_parameter_changes_the_scene(name):
    """No dead parameter: for each one, some seed's scene changes when only it changes."""
    st = get_scene_type(name)
    dead = []
    for p in st.params:
        if p.kind == "int":
            values = list(range(int(p.low), int(p.high) + 1))
        else:
            values = [p.low, (p.low + p.high) / 2, p.high]
        for seed in range(6):
            hashes = {geometry_hash(generate(name, seed, {p.name: value})) for value in values}
            if len(hashes) > 1:
                break
        else:
            dead.append(p.name)
    assert not dead, f"{name}: parameters that never change the scene: {dead}"


# ----------------------------------------------------------------------------- overrides
def test_desk_height_and_width_override_set_the_top():
    spec = generate("Desk", 3, {"desk.height": 0.7, "desk.width": 1.0})
    (top,) = spec.surfaces("on_table")
    assert top.height == on_grid(0.7)
    xs, ys = np.asarray(top.polygon_xy).T
    assert ys.max() - ys.min() == on_grid(1.0 - 0.02)
    part = spec.part("desk_top")
    assert part.position[2] + part.size[2] / 2 == on_grid(0.7)


def test_shelf_layer_count_override_sets_the_boards():
    for n in (3, 4, 5):
        spec = generate("LargeShelf", 1, {"shelf.n_layers": n})
        boards = [p for p in spec.parts if p.name.startswith("shelf_board_")]
        assert len(boards) == n - 1


def test_colour_override_sets_the_material():
    spec = generate("LayerShelf", 2, {"rack.post_r": 0.2, "rack.post_g": 0.3, "rack.post_b": 0.4})
    posts = [p for p in spec.parts if "_post_" in p.name]
    assert posts and all(p.material.rgba[:3] == (0.2, 0.3, 0.4) for p in posts)


def test_door_angle_override_turns_the_door():
    for angle in (2.0, 2.6):
        spec = generate("DoubleDoorCabinet", 4, {"cabinet.door_0_angle": angle})
        door = spec.part("cabinet_door_left")
        w, _, _, z = door.quat_wxyz
        assert 2 * math.atan2(z, w) == on_grid(angle)


def test_drawer_pull_override_moves_the_drawer_surface():
    fronts = []
    for pull in (0.6, 0.85):
        spec = generate("Drawer", 6, {"dresser.open_0_pull": pull, "dresser.cols": 1})
        (surface,) = spec.surfaces("in_drawer")
        fronts.append(min(x for x, _ in surface.polygon_xy))
    assert fronts[1] < fronts[0] - 0.05  # pulled further out towards the robot


def test_robot_offset_override_moves_the_region():
    near = generate("Desk", 0, {"robot.x_gap": 0.12}).robot_region
    far = generate("Desk", 0, {"robot.x_gap": 0.18}).robot_region
    assert near.x_range[1] - far.x_range[1] == on_grid(0.06)


# ----------------------------------------------------------------------------- per-type rules
def _aabb_xy(part) -> Polygon:
    (x0, y0, _), (x1, y1, _) = part_aabb(part)
    return Polygon([(x0, y0), (x1, y0), (x1, y1), (x0, y1)])


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("name", ["Drawer", "DrawerShelf"])
def test_open_drawer_surface_is_inside_the_drawer_and_out_of_the_carcass(name, seed):
    spec = generate(name, seed)
    carcass_front = spec.part("dresser_side_left").position[0] - spec.part("dresser_side_left").size[0] / 2
    drawers = spec.surfaces("in_drawer")
    assert 1 <= len(drawers) == int(spec.params["dresser.cols"])
    for s in drawers:
        floor = spec.part(s.supporting_part)
        assert s.supporting_part.endswith("_floor")
        poly = Polygon(s.polygon_xy)
        assert _aabb_xy(floor).buffer(1e-6).contains(poly)
        assert poly.bounds[2] <= carcass_front + 1e-6  # open from above
        assert poly.bounds[2] - poly.bounds[0] > 0.12  # pulled out far enough to put things in
        assert s.height == on_grid(floor.position[2] + floor.size[2] / 2)
        for side in ("side_left", "side_right", "back"):
            wall = spec.part(s.supporting_part.replace("_floor", f"_{side}"))
            assert wall.position[2] + wall.size[2] / 2 == on_grid(s.wall_top)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("name, cabinet", [("DoubleDoorCabinet", "cabinet"), ("SingleDoorCabinetDesk", "cabinet")])
def test_open_doors_do_not_cover_the_opening(name, cabinet, seed):
    spec = generate(name, seed)
    left, right = spec.part(f"{cabinet}_side_left"), spec.part(f"{cabinet}_side_right")
    x_front = left.position[0] - left.size[0] / 2
    y_in0 = left.position[1] + left.size[1] / 2
    y_in1 = right.position[1] - right.size[1] / 2
    # The space right in front of the opening, as far out as a door can reach.
    approach = Polygon([(x_front - 0.6, y_in0), (x_front, y_in0), (x_front, y_in1), (x_front - 0.6, y_in1)])
    doors = [p for p in spec.parts if "_door_" in p.name]
    assert len(doors) == (4 if name == "DoubleDoorCabinet" else 2)  # doors and their handles
    for door in doors:
        corners = np.array([[sx, sy, 0] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5)]) * [*door.size[:2], 0]
        T = door.transform()
        shadow = Polygon((corners @ T[:3, :3].T + T[:3, 3])[:, :2][[0, 1, 3, 2]])
        assert shadow.intersection(approach).area < 1e-6, door.name


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("name", [n for n, labels in PAPER_LABELS.items() if "in_basket" in labels])
def test_basket_surface_lies_inside_its_walls(name, seed):
    spec = generate(name, seed)
    baskets = spec.surfaces("in_basket")
    assert baskets
    for s in baskets:
        floor = spec.part(s.supporting_part)
        poly = Polygon(s.polygon_xy)
        walls = [spec.part(s.supporting_part.replace("_floor", f"_wall_{w}")) for w in ("left", "right", "front", "back")]
        for wall in walls:
            assert wall.position[2] + wall.size[2] / 2 == on_grid(s.wall_top)
            assert _aabb_xy(wall).intersection(poly).area < 1e-6 or abs(floor.quat_wxyz[3]) > 1e-9
        if abs(floor.quat_wxyz[3]) < 1e-9:  # axis-aligned: the walls stand on the floor's rim, the surface on the floor
            outer = Polygon(_aabb_xy(floor))
            assert outer.buffer(1e-6).contains(poly)
            assert all(outer.buffer(0.01).contains(Polygon(_aabb_xy(w)).centroid) for w in walls)
        # The basket stands on a surface of the furniture: its floor's underside touches a part.
        underside = floor.position[2] - floor.size[2] / 2
        assert any(
            abs(part_aabb(p)[1, 2] - underside) < 2e-6 for p in spec.parts if p.name != floor.name and "basket" not in p.name
        )


@pytest.mark.parametrize("seed", SEEDS)
def test_layer_shelf_boards_stand_on_four_round_posts(seed):
    spec = generate("LayerShelf", seed)
    n = int(spec.params["rack.n_layers"])
    for k in range(n):
        board = spec.part(f"rack_board_{k}")
        under = board.position[2] - board.size[2] / 2
        posts = [p for p in spec.parts if p.name.startswith("rack_post_") and p.name.endswith(f"_{k}")]
        assert len(posts) == 4 and all(p.shape == "cylinder" for p in posts)
        assert all(p.position[2] + p.size[1] / 2 == on_grid(under) for p in posts)


@pytest.mark.parametrize("seed", SEEDS)
def test_triangle_shelves_are_triangles_on_the_desk(seed):
    spec = generate("TriangleShelfDesk", seed)
    desk = Polygon(_aabb_xy(spec.part("desk_top")))
    shelves = {}
    for p in spec.parts:
        if "_board_" in p.name:
            assert p.shape == "convex_mesh"
            shelves.setdefault(p.name.split("_board_")[0], []).append(p)
    assert set(shelves) == {"shelf_a", "shelf_b"}
    footprints = []
    for boards in shelves.values():
        verts = np.asarray(boards[0].mesh_vertices)[:, :2] + boards[0].position[:2]
        footprint = Polygon(verts).convex_hull
        assert desk.contains(footprint)
        footprints.append(footprint)
    assert footprints[0].intersection(footprints[1]).area == 0.0


@pytest.mark.parametrize("seed", SEEDS)
def test_round_table_baskets_stand_on_the_table_and_the_free_top_avoids_them(seed):
    spec = generate("RoundTable", seed)
    top = spec.part("table_top")
    radius = top.size[0]
    centre = np.asarray(top.position[:2])
    baskets = spec.surfaces("in_basket")
    for s in baskets:
        assert np.linalg.norm(np.asarray(s.polygon_xy) - centre, axis=1).max() < radius
    for table in spec.surfaces("on_table"):
        for s in baskets:
            assert Polygon(table.polygon_xy).intersection(Polygon(s.polygon_xy)).area < 1e-9


@pytest.mark.parametrize("name", ["LargeShelf", "LayerShelf", "EketShelf", "LargeShelfDesk", "DrawerShelf"])
def test_tall_furniture_keeps_its_supports_within_one_reach_band(name):
    for seed in SEEDS:
        spec = generate(name, seed)
        heights = [s.height for s in spec.support_surfaces]
        assert max(heights) - min(heights) <= 1.25
        z_lo, z_hi = spec.robot_region.z_range
        assert z_hi <= min(heights) and max(heights) - z_lo <= 1.3


@pytest.mark.parametrize("name", SCENE_TYPES)
def test_surfaces_are_mostly_reachable_from_every_corner_of_the_robot_region(name):
    """Stricter than the averaged check of test_scenes: from each corner of the base region
    (the worst poses), at least half of nearly every surface lies in the Franka's band."""
    from itertools import product

    from shapely.geometry import Point

    worst = []
    for seed in range(3):
        spec = generate(name, seed)
        region = spec.robot_region
        for s in spec.support_surfaces:
            shares = []
            for x, y, z in product(region.x_range, region.y_range, region.z_range):
                band = Point(x, y).buffer(0.85, 64).difference(Point(x, y).buffer(0.25, 64))
                in_height = 0.0 <= s.height - z <= 1.3
                shares.append(s.polygon.intersection(band).area / s.area if in_height else 0.0)
            worst.append(min(shares))
    worst = np.asarray(worst)
    assert worst.min() >= 0.3 and np.mean(worst >= 0.5) >= 0.9, np.round(np.sort(worst)[:5], 2)
