"""Open racks: a metal layer rack on four round posts, triangular corner shelves, wall cubes."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely import affinity
from shapely.geometry import Polygon

from ..params import ParamSpec
from .builder import SceneBuilder, material, material_params, rect
from .storage import MAX_SUPPORT_SPAN, layer_basket_params, place_baskets

MAX_RACK_LAYERS = 5


# --------------------------------------------------------------------------- layer rack
def rack_params() -> tuple[ParamSpec, ...]:
    """A metal rack: thin boards held by four round posts (the posts run in segments
    between the boards, which they touch; the boards' corners around the posts hold nothing)."""
    return (
        ParamSpec("width", 0.6, 0.9, "m", "board width (along y)"),
        ParamSpec("depth", 0.3, 0.45, "m", "board depth (along x)"),
        ParamSpec("n_layers", 3, MAX_RACK_LAYERS, "count", "number of boards", kind="int"),
        *(ParamSpec(f"gap_{k}", 0.22, 0.34, "m", f"clear height between boards {k} and {k + 1}") for k in range(MAX_RACK_LAYERS - 1)),
        ParamSpec("bottom_clearance", 0.05, 0.18, "m", "height of the lowest board's underside above the feet"),
        ParamSpec("board_thickness", 0.008, 0.02, "m", "board thickness"),
        ParamSpec("post_radius", 0.008, 0.018, "m", "post radius"),
        ParamSpec("post_inset", 0.0, 0.015, "m", "posts set in from the board corners"),
        ParamSpec("post_extension", 0.0, 0.08, "m", "how far the posts rise above the top board"),
        ParamSpec("foot_style", 0, 1, "count", "0 plain post ends, 1 capsule levelling feet", kind="int"),
        *layer_basket_params(1, 3, MAX_RACK_LAYERS),
        *material_params("post", "metal"),
        *material_params("board", "metal"),
    )


def build_rack(b: SceneBuilder, v, name: str, x0: float, y0: float) -> None:
    W, D, t, r = v["width"], v["depth"], v["board_thickness"], v["post_radius"]
    n = int(v["n_layers"])
    post_mat, board_mat = material(v, "post"), material(v, "board")
    ya, yb, x1 = y0 - W / 2, y0 + W / 2, x0 + D
    c = v["post_inset"] + r
    posts = {"front_left": (x0 + c, ya + c), "front_right": (x0 + c, yb - c), "back_left": (x1 - c, ya + c), "back_right": (x1 - c, yb - c)}
    foot = 2.6 * r + 0.015 if int(v["foot_style"]) == 1 else 0.0  # capsule feet are taller than wide
    z = foot + v["bottom_clearance"]
    layers = []
    z_prev = foot
    for k in range(n):
        for corner, xy in posts.items():
            if k == 0 and foot:
                b.cylinder(f"{name}_foot_{corner}", r * 1.3, 0.0, foot, xy, post_mat, shape="capsule")
            b.cylinder(f"{name}_post_{corner}_{k}", r, z_prev, z, xy, post_mat)
        board = f"{name}_board_{k}"
        b.box_between(board, (x0, ya, z), (x1, yb, z + t), board_mat)
        gap = v[f"gap_{k}"] if k < n - 1 else 0.3
        layers.append((board, z + t, gap))
        z_prev = z + t
        z = z_prev + gap
    if v["post_extension"] > 0.005:
        for corner, xy in posts.items():
            b.cylinder(f"{name}_post_{corner}_top", r, z_prev, z_prev + v["post_extension"], xy, post_mat)
    lowest = layers[0][1]
    reachable = [layer for layer in layers if layer[1] - lowest <= MAX_SUPPORT_SPAN]
    # The posts stand in the board corners: the usable board (and the baskets) lie between
    # the front and the back posts, over the full width.
    notch = c + r + 0.006
    place_baskets(b, v, name, reachable, (x0 + notch, x1 - notch), (ya, yb), "on_shelf")


# --------------------------------------------------------------------------- triangle corner shelf
def triangle_shelf_params() -> tuple[ParamSpec, ...]:
    return (
        ParamSpec("leg_a", 0.27, 0.36, "m", "length of the triangle's first straight edge"),
        ParamSpec("leg_b", 0.24, 0.32, "m", "length of the triangle's second straight edge"),
        ParamSpec("bulge", 0.0, 0.06, "m", "outward bulge of the front (curved) edge"),
        ParamSpec("n_boards", 2, 3, "count", "number of boards", kind="int"),
        ParamSpec("gap", 0.14, 0.24, "m", "clear height between boards"),
        ParamSpec("foot_height", 0.02, 0.08, "m", "height of the legs under the lowest board"),
        ParamSpec("board_thickness", 0.012, 0.025, "m", "board thickness"),
        ParamSpec("post_radius", 0.007, 0.014, "m", "radius of the posts"),
        ParamSpec("yaw", -math.pi, math.pi, "rad", "rotation of the shelf about the vertical"),
        ParamSpec("pos_u", 0.0, 1.0, "1", "position along x within its free room (share)"),
        ParamSpec("pos_v", 0.0, 1.0, "1", "position along y within its free room (share)"),
        *material_params("board", "wood"),
        *material_params("post", "metal"),
    )


def triangle_contour(a: float, b_len: float, bulge: float, n_arc: int = 6) -> Polygon:
    """Right triangle with legs ``a`` (x) and ``b_len`` (y) whose hypotenuse bulges outwards."""
    p1, p2 = np.array([a, 0.0]), np.array([0.0, b_len])
    normal = np.array([b_len, a]) / math.hypot(a, b_len)  # points away from the right angle
    arc = [p1 + (p2 - p1) * s + normal * bulge * 4 * s * (1 - s) for s in np.linspace(0, 1, n_arc + 1)]
    return Polygon([(0.0, 0.0), *map(tuple, arc)])


def build_triangle_shelf(b: SceneBuilder, v, name: str, room: Polygon, z0: float, support_part: str) -> Polygon:
    """A corner shelf standing on ``support_part`` at ``z0``, placed inside the box ``room``
    (rotated by its yaw, then moved by pos_u / pos_v within the room left); returns its footprint."""
    contour = affinity.rotate(triangle_contour(v["leg_a"], v["leg_b"], v["bulge"]), v["yaw"], origin=(0, 0), use_radians=True)
    rx0, ry0, rx1, ry1 = room.bounds
    cx0, cy0, cx1, cy1 = contour.bounds
    dx = rx0 - cx0 + v["pos_u"] * max(0.0, (rx1 - rx0) - (cx1 - cx0))
    dy = ry0 - cy0 + v["pos_v"] * max(0.0, (ry1 - ry0) - (cy1 - cy0))
    contour = affinity.translate(contour, dx, dy)
    r, t = v["post_radius"], v["board_thickness"]
    board_mat, post_mat = material(v, "board"), material(v, "post")
    # Posts stand in the three corners, just inside the edges.
    inset = contour.buffer(-(r + 0.003), join_style="mitre")
    inner = np.asarray(inset.exterior.coords)[:-1]
    outer = np.asarray(contour.exterior.coords)[:-1]
    corner_ids = [0, 1, len(outer) - 1]  # right angle, end of leg a, end of leg b
    post_xy = [inner[np.argmin(np.linalg.norm(inner - outer[i], axis=1))] for i in corner_ids]
    usable = contour.buffer(-(2 * r + 0.012), join_style="mitre")
    z = z0 + v["foot_height"]
    z_prev = z0
    for k in range(int(v["n_boards"])):
        for j, xy in enumerate(post_xy):
            b.cylinder(f"{name}_post_{j}_{k}", r, z_prev, z, xy, post_mat)
        board = f"{name}_board_{k}"
        b.prism(board, contour, z, z + t, board_mat)
        b.surface(f"{name}_board_{k}", "on_shelf", usable, z + t, board)
        z_prev = z + t
        z = z_prev + v["gap"]
    return contour


# --------------------------------------------------------------------------- wall cubes (Eket-like)
MAX_CUBE_COLUMNS = 3


def cube_wall_params() -> tuple[ParamSpec, ...]:
    specs = [
        ParamSpec("n_columns", 2, MAX_CUBE_COLUMNS, "count", "columns of cubes on the wall", kind="int"),
        ParamSpec("depth", 0.3, 0.36, "m", "depth of the cubes"),
        ParamSpec("panel_thickness", 0.012, 0.02, "m", "cube panel thickness"),
        ParamSpec("back_thickness", 0.004, 0.01, "m", "cube back panel thickness"),
    ]
    for k in range(MAX_CUBE_COLUMNS):
        specs += [
            ParamSpec(f"col_{k}_width", 0.3, 0.4, "m", f"width of the cubes in column {k}"),
            ParamSpec(f"col_{k}_height", 0.3, 0.38, "m", f"height of the cubes in column {k}"),
            ParamSpec(f"col_{k}_base", 0.35, 0.6, "m", f"height of the lowest cube's underside in column {k}"),
            ParamSpec(f"col_{k}_stacked", 0, 1, "count", f"1: a second cube hangs above the first in column {k}", kind="int"),
            ParamSpec(f"col_{k}_stack_gap", 0.1, 0.2, "m", f"gap between the cubes of column {k}"),
            ParamSpec(f"col_{k}_board", 0, 1, "count", f"1: the lower cube of column {k} has a middle board", kind="int"),
            ParamSpec(f"col_{k}_board_frac", 0.4, 0.6, "1", f"height of that middle board as a share of the cube"),
        ]
        if k < MAX_CUBE_COLUMNS - 1:
            specs.append(ParamSpec(f"col_{k}_spacing", 0.02, 0.15, "m", f"gap between column {k} and the next"))
    specs += list(material_params("cube", "paint"))
    return tuple(specs)


@dataclass(frozen=True)
class CubeSurface:
    name: str
    polygon: Polygon
    z: float
    part: str


def build_cube_wall(b: SceneBuilder, v, name: str, x_wall: float, y0: float) -> tuple[float, float, list[CubeSurface]]:
    """Cubes hanging on the wall face x = ``x_wall``, the row centred at ``y0``; returns the
    row's y extent and the candidate surfaces (the caller keeps the reachable ones)."""
    ncol = int(v["n_columns"])
    widths = [v[f"col_{k}_width"] for k in range(ncol)]
    total = sum(widths) + sum(v[f"col_{k}_spacing"] for k in range(ncol - 1))
    y = y0 - total / 2
    D, t, tb = v["depth"], v["panel_thickness"], v["back_thickness"]
    mat = material(v, "cube")
    x0 = x_wall - D
    surfaces: list[CubeSurface] = []
    for k in range(ncol):
        w, h = widths[k], v[f"col_{k}_height"]
        cubes = [v[f"col_{k}_base"]]
        if int(v[f"col_{k}_stacked"]):
            cubes.append(cubes[0] + h + v[f"col_{k}_stack_gap"])
        for j, zc in enumerate(cubes):
            cn = f"{name}_{k}_{j}"
            ya, yb = y, y + w
            b.box_between(f"{cn}_bottom", (x0, ya, zc), (x_wall, yb, zc + t), mat)
            b.box_between(f"{cn}_top", (x0, ya, zc + h - t), (x_wall, yb, zc + h), mat)
            b.box_between(f"{cn}_side_left", (x0, ya, zc + t), (x_wall, ya + t, zc + h - t), mat)
            b.box_between(f"{cn}_side_right", (x0, yb - t, zc + t), (x_wall, yb, zc + h - t), mat)
            b.box_between(f"{cn}_back", (x_wall - tb, ya + t, zc + t), (x_wall, yb - t, zc + h - t), mat)
            inside = rect(x0 + 0.003, x_wall - tb - 0.003, ya + t + 0.002, yb - t - 0.002)
            surfaces.append(CubeSurface(f"{cn}_floor", inside, zc + t, f"{cn}_bottom"))
            if j == 0 and int(v[f"col_{k}_board"]):
                zb = zc + t + v[f"col_{k}_board_frac"] * (h - 2 * t - t)
                b.box_between(f"{cn}_board", (x0, ya + t, zb), (x_wall - tb, yb - t, zb + t), mat)
                surfaces.append(CubeSurface(f"{cn}_board", inside, zb + t, f"{cn}_board"))
            surfaces.append(CubeSurface(f"{cn}_top", rect(x0 + 0.005, x_wall - 0.005, ya + 0.005, yb - 0.005), zc + h, f"{cn}_top"))
        y += w + (v[f"col_{k}_spacing"] if k < ncol - 1 else 0.0)
    return y0 - total / 2, y0 + total / 2, surfaces
