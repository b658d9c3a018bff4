"""Storage pieces: baskets, bookcases / cabinets (with optional open doors), cell shelves."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely import affinity
from shapely.geometry import Polygon

from ..params import ParamSpec
from .builder import SceneBuilder, material, material_params, rect, yaw_quat

#: Surfaces higher than this above a piece's lowest support are left out (out of the arm's
#: reach from any base that can reach the lowest one); the boards are still built.
MAX_SUPPORT_SPAN = 1.15


# --------------------------------------------------------------------------- basket
def basket_params(kind: str = "wicker") -> tuple[ParamSpec, ...]:
    return (
        ParamSpec("wall_thickness", 0.006, 0.014, "m", "basket wall thickness"),
        ParamSpec("floor_thickness", 0.006, 0.014, "m", "basket floor thickness"),
        *material_params("basket", kind),
    )


def build_basket(
    b: SceneBuilder, v, name: str, center_xy, size_xy, z0: float, height: float, yaw: float = 0.0,
    surface_clip: Polygon | None = None,
) -> Polygon:
    """An open box (floor + four walls) standing at ``z0``; adds its ``in_basket`` surface and
    returns its footprint (scene frame). ``size_xy`` is along the basket's own x / y before ``yaw``.
    ``surface_clip``: the surface is only the part of the floor inside it (scene frame)."""
    L, W = size_xy
    t, tf = v["wall_thickness"], v["floor_thickness"]
    mat = material(v, "basket")
    c, s = math.cos(yaw), math.sin(yaw)
    quat = yaw_quat(yaw)

    def place(part_name, lo, hi):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        mid = (lo + hi) / 2
        pos = (center_xy[0] + c * mid[0] - s * mid[1], center_xy[1] + s * mid[0] + c * mid[1], mid[2])
        b.box(part_name, hi - lo, pos, mat, quat=quat)

    zt = z0 + height
    place(f"{name}_floor", (-L / 2, -W / 2, z0), (L / 2, W / 2, z0 + tf))
    place(f"{name}_wall_left", (-L / 2, -W / 2, z0 + tf), (L / 2, -W / 2 + t, zt))
    place(f"{name}_wall_right", (-L / 2, W / 2 - t, z0 + tf), (L / 2, W / 2, zt))
    place(f"{name}_wall_front", (-L / 2, -W / 2 + t, z0 + tf), (-L / 2 + t, W / 2 - t, zt))
    place(f"{name}_wall_back", (L / 2 - t, -W / 2 + t, z0 + tf), (L / 2, W / 2 - t, zt))

    def to_scene(poly):
        return affinity.translate(affinity.rotate(poly, yaw, origin=(0, 0), use_radians=True), *center_xy)

    inner = to_scene(rect(-L / 2 + t, L / 2 - t, -W / 2 + t, W / 2 - t))
    if surface_clip is not None:
        inner = inner.intersection(surface_clip)
    b.surface(name, "in_basket", inner, z0 + tf, f"{name}_floor", wall_top=zt)
    return to_scene(rect(-L / 2, L / 2, -W / 2, W / 2))


# --------------------------------------------------------------------------- bookcase / cabinet
def shelf_unit_params(
    width=(0.6, 0.9),
    depth=(0.28, 0.4),
    n_layers=(3, 5),
    gap=(0.22, 0.34),
    plinth=(0.03, 0.1),
    max_baskets: int = 2,
    min_baskets: int = 1,
) -> tuple[ParamSpec, ...]:
    """A bookcase: side panels, a plinth, a bottom, ``n_layers`` compartments, a top, a back.

    ``gap_k`` is the clear height of compartment k; baskets stand in chosen compartments."""
    specs = [
        ParamSpec("width", *width, "m", "outer width (along y)"),
        ParamSpec("depth", *depth, "m", "outer depth (along x)"),
        ParamSpec("side_thickness", 0.015, 0.03, "m", "side panel thickness"),
        ParamSpec("board_thickness", 0.015, 0.03, "m", "shelf board thickness"),
        ParamSpec("top_thickness", 0.015, 0.035, "m", "top panel thickness"),
        ParamSpec("back_thickness", 0.004, 0.012, "m", "back panel thickness"),
        ParamSpec("board_setback", 0.0, 0.03, "m", "shelf boards set back from the front edge"),
        ParamSpec("n_layers", *n_layers, "count", "number of compartments", kind="int"),
    ]
    if plinth is not None:  # wall cabinets and units standing on something have none
        specs += [
            ParamSpec("plinth_height", *plinth, "m", "height of the plinth under the bottom board"),
            ParamSpec("plinth_setback", 0.0, 0.04, "m", "plinth board set back from the front"),
        ]
    specs += [ParamSpec(f"gap_{k}", *gap, "m", f"clear height of compartment {k}") for k in range(n_layers[1])]
    if max_baskets:
        specs += list(layer_basket_params(min_baskets, max_baskets, n_layers[1]))
    specs += list(material_params("carcass", "wood"))
    specs += list(material_params("back", "paint"))
    return tuple(specs)


def layer_basket_params(min_baskets: int, max_baskets: int, max_layers: int, kind: str = "wicker") -> tuple[ParamSpec, ...]:
    """Baskets standing on the boards of a shelf (see ``place_baskets``)."""
    specs = []
    if max_baskets > min_baskets:  # otherwise the count is fixed
        specs.append(ParamSpec("n_baskets", min_baskets, max_baskets, "count", "number of baskets on the shelves", kind="int"))
    specs += [
        ParamSpec("basket_width_frac", 0.3, 0.5, "1", "basket width as a share of the inner width"),
        ParamSpec("basket_depth_frac", 0.65, 0.92, "1", "basket depth as a share of the board depth"),
        ParamSpec("basket_height_frac", 0.3, 0.55, "1", "basket height as a share of its compartment"),
    ]
    for k in range(max_baskets):
        specs += [
            ParamSpec(f"basket_{k}_layer", 0, max_layers - 1, "count", f"board of basket {k} (modulo the reachable ones)", kind="int"),
            ParamSpec(f"basket_{k}_pos", 0.0, 1.0, "1", f"sideways position of basket {k} in its free span"),
        ]
    return (*specs, *basket_params(kind))


@dataclass(frozen=True)
class ShelfUnitInfo:
    """Outer extent of a built bookcase / cabinet."""

    x0: float
    x1: float
    y0: float
    y1: float
    z_top: float


def build_shelf_unit(
    b: SceneBuilder, v, name: str, x0: float, y0: float, z0: float = 0.0, label: str = "on_shelf", with_top_surface: bool = True
) -> ShelfUnitInfo:
    """A bookcase with its front at ``x0`` centred at ``y0``; adds its board surfaces and baskets."""
    W, D = v["width"], v["depth"]
    ts, tb, tt, tback = v["side_thickness"], v["board_thickness"], v["top_thickness"], v["back_thickness"]
    n = int(v["n_layers"])
    carcass, back = material(v, "carcass"), material(v, "back")
    ya, yb = y0 - W / 2, y0 + W / 2
    yi0, yi1 = ya + ts, yb - ts
    x_back = x0 + D - tback
    bx0 = x0 + v["board_setback"]
    plinth = v.get("plinth_height", 0.0)
    # Compartments: the bottom board, then boards stacked by their gaps, then the top.
    layers = []
    z = z0 + plinth
    b.box_between(f"{name}_bottom", (x0, yi0, z), (x_back, yi1, z + tb), carcass)
    z += tb
    layers.append((f"{name}_bottom", z, v["gap_0"]))
    for k in range(1, n):
        z += v[f"gap_{k - 1}"]
        b.box_between(f"{name}_board_{k}", (bx0, yi0, z), (x_back, yi1, z + tb), carcass)
        z += tb
        layers.append((f"{name}_board_{k}", z, v[f"gap_{k}"]))
    z += v[f"gap_{n - 1}"]
    z_sides = z
    z_top = z + tt
    for side, (y_lo, y_hi) in (("left", (ya, yi0)), ("right", (yi1, yb))):
        b.box_between(f"{name}_side_{side}", (x0, y_lo, z0), (x0 + D, y_hi, z_sides), carcass)
    b.box_between(f"{name}_top", (x0, ya, z_sides), (x0 + D, yb, z_top), carcass)
    b.box_between(f"{name}_back", (x_back, yi0, z0 + plinth), (x0 + D, yi1, z_sides), back)
    if plinth > 0.005:
        ps = v["plinth_setback"]
        b.box_between(f"{name}_plinth", (x0 + ps, yi0, z0), (x0 + ps + 0.018, yi1, z0 + plinth), carcass)
    info = ShelfUnitInfo(x0, x0 + D, ya, yb, z_top)
    # Supports: every compartment within reach of the lowest one, and the top if it is too.
    lowest = layers[0][1]
    reachable = [layer for layer in layers if layer[1] - lowest <= MAX_SUPPORT_SPAN]
    place_baskets(b, v, name, reachable, (bx0, x_back), (yi0, yi1), label)
    if with_top_surface and z_top - lowest <= MAX_SUPPORT_SPAN:
        b.surface(f"{name}_top", label, rect(x0 + 0.01, x0 + D - 0.01, ya + 0.01, yb - 0.01), z_top, f"{name}_top")
    return info


def place_baskets(b: SceneBuilder, v, name: str, layers, x_span, y_span, label: str) -> None:
    """Stand the ``basket_k`` baskets on the given layers and add every layer's free board area.

    ``layers`` are (board part, z of its top, clear height above); a layer's free area is
    x_span x y_span minus its baskets."""
    (x0, x1), (y0, y1) = x_span, y_span
    occupied: dict[int, list[tuple[float, float]]] = {}
    n_baskets = int(v["n_baskets"]) if "n_baskets" in v else sum(1 for key in v if key.startswith("basket_") and key.endswith("_layer"))
    for k in range(n_baskets):
        li = int(v[f"basket_{k}_layer"]) % len(layers)
        board, zb, gap = layers[li]
        bw = v["basket_width_frac"] * (y1 - y0)
        free = _free_span((y0 + 0.005, y1 - 0.005), occupied.get(li, []), bw)
        if free is None:
            continue  # no room left on that board
        yc = free[0] + bw / 2 + v[f"basket_{k}_pos"] * (free[1] - free[0] - bw)
        depth = v["basket_depth_frac"] * (x1 - x0)
        build_basket(b, v, f"{name}_basket_{k}", (x0 + 0.005 + depth / 2, yc), (depth, bw), zb, v["basket_height_frac"] * gap)
        occupied.setdefault(li, []).append((yc - bw / 2 - 0.005, yc + bw / 2 + 0.005))
    for li, (board, zb, gap) in enumerate(layers):
        region = rect(x0 + 0.002, x1 - 0.002, y0 + 0.002, y1 - 0.002)
        for lo, hi in occupied.get(li, []):
            region = region.difference(rect(x0 - 1, x1 + 1, lo, hi))
        b.surface_region(f"{name}_layer_{li}", label, region, zb, board)


def _free_span(span, occupied, width):
    """The widest part of ``span`` left between ``occupied`` intervals, if ``width`` fits in it."""
    edges = sorted(occupied)
    best, start = None, span[0]
    for lo, hi in edges + [(span[1], span[1])]:
        if lo - start >= width and (best is None or lo - start > best[1] - best[0]):
            best = (start, lo)
        start = max(start, hi)
    return best


# --------------------------------------------------------------------------- doors
def door_params(n_doors: int) -> tuple[ParamSpec, ...]:
    """Doors hinge on the cabinet's outer front edges (a single door: on the side its
    ``build_doors`` caller names), so they swing away from the middle."""
    specs = [
        ParamSpec("door_thickness", 0.015, 0.022, "m", "door thickness"),
        ParamSpec("handle_length", 0.06, 0.2, "m", "length of the door handle bar"),
        ParamSpec("handle_offset", 0.03, 0.07, "m", "handle distance from the door's free edge"),
    ]
    specs += [
        ParamSpec(f"door_{k}_angle", 1.95, 2.8, "rad", f"opening angle of door {k} (pi/2 = perpendicular)") for k in range(n_doors)
    ]
    specs += list(material_params("door", "paint"))
    specs += list(material_params("handle", "metal"))
    return tuple(specs)


def build_doors(b: SceneBuilder, v, name: str, info: ShelfUnitInfo, z0: float, hinges: tuple[str, ...]) -> list[Polygon]:
    """Open doors in front of a cabinet; returns their footprints (to keep surfaces clear of them).

    A door hinges on the front-outer edge of the cabinet and swings out by its angle past
    90 degrees, so it never covers the opening."""
    td = v["door_thickness"]
    x0, ya, yb = info.x0, info.y0, info.y1
    width = (yb - ya) / len(hinges)
    footprints = []
    h = info.z_top - z0 - 0.004
    zc = z0 + 0.002 + h / 2
    for k, side in enumerate(hinges):
        theta = v[f"door_{k}_angle"]
        if side == "left":  # hinge at y = ya, free edge towards +y when closed
            hinge = np.array([x0, ya])
            yaw = theta
            edge = np.array([-math.sin(theta), math.cos(theta)])
            normal = np.array([-math.cos(theta), -math.sin(theta)])
        else:
            hinge = np.array([x0, yb])
            yaw = -theta
            edge = np.array([-math.sin(theta), -math.cos(theta)])
            normal = np.array([-math.cos(theta), math.sin(theta)])
        center = hinge + edge * width / 2 + normal * td / 2
        b.box(f"{name}_door_{side}", (td, width, h), (center[0], center[1], zc), material(v, "door"), quat=yaw_quat(yaw))
        hd = 0.025
        hc = hinge + edge * (width - v["handle_offset"]) + normal * (td + hd / 2)
        hl = min(v["handle_length"], h - 0.02)
        b.box(f"{name}_door_{side}_handle", (hd, 0.014, hl), (hc[0], hc[1], zc), material(v, "handle"), quat=yaw_quat(yaw))
        corners = [hinge, hinge + edge * width, hinge + edge * width + normal * (td + hd), hinge + normal * (td + hd)]
        footprints.append(Polygon(corners).buffer(0.01))
    return footprints


# --------------------------------------------------------------------------- cell shelf (Kallax-like)
def cell_shelf_params(rows=(1, 2), cols=(2, 4), depth=(0.26, 0.36), max_boxes: int = 2) -> tuple[ParamSpec, ...]:
    specs = [
        ParamSpec("rows", *rows, "count", "rows of cells", kind="int"),
        ParamSpec("cols", *cols, "count", "columns of cells (fewer if they do not fit)", kind="int"),
        ParamSpec("cell_width", 0.27, 0.36, "m", "clear width of a cell"),
        ParamSpec("cell_height", 0.25, 0.36, "m", "clear height of a cell"),
        ParamSpec("depth", *depth, "m", "depth of the unit"),
        ParamSpec("outer_thickness", 0.025, 0.05, "m", "thickness of the outer frame"),
        ParamSpec("inner_thickness", 0.012, 0.02, "m", "thickness of the inner dividers"),
        ParamSpec("n_boxes", 1, max_boxes, "count", "number of storage boxes in the cells", kind="int"),
        ParamSpec("box_width_frac", 0.75, 0.95, "1", "box width as a share of the cell width"),
        ParamSpec("box_depth_frac", 0.7, 0.95, "1", "box depth as a share of the cell depth"),
        ParamSpec("box_height_frac", 0.45, 0.7, "1", "box height as a share of the cell height"),
        ParamSpec("box_pull", 0.5, 0.8, "1", "share of a box's depth pulled out of its cell (objects go in that part)"),
    ]
    specs += [ParamSpec(f"box_{k}_cell", 0, 7, "count", f"bottom-row cell of box {k} (modulo the number of columns)", kind="int") for k in range(max_boxes)]
    specs += list(basket_params("fabric"))
    specs += list(material_params("frame", "paint"))
    return tuple(specs)


def cell_shelf_width(v, cols: int) -> float:
    return cols * v["cell_width"] + (cols - 1) * v["inner_thickness"] + 2 * v["outer_thickness"]


def build_cell_shelf(b: SceneBuilder, v, name: str, x0: float, y0: float, z0: float, cols: int) -> tuple[float, float, float, float, float, list]:
    """A grid of open cells with its front at ``x0`` (the robot side), some holding a storage
    box pulled part-way out toward the robot; returns (x0, x1, y0, y1, z_top, the pulled-out
    boxes' footprints). A box's ``in_basket`` surface is only its part outside the cell: inside
    a cell the ceiling leaves no room for a hand over the box walls (in build version 4 no
    object in a pushed-in box passed the reachability and visibility filters)."""
    rows = int(v["rows"])
    cw, ch, D = v["cell_width"], v["cell_height"], v["depth"]
    to, ti = v["outer_thickness"], v["inner_thickness"]
    mat = material(v, "frame")
    W = cell_shelf_width(v, cols)
    H = rows * ch + (rows - 1) * ti + 2 * to
    ya, yb = y0 - W / 2, y0 + W / 2
    x1 = x0 + D
    b.box_between(f"{name}_bottom", (x0, ya, z0), (x1, yb, z0 + to), mat)
    b.box_between(f"{name}_top", (x0, ya, z0 + H - to), (x1, yb, z0 + H), mat)
    b.box_between(f"{name}_side_left", (x0, ya, z0 + to), (x1, ya + to, z0 + H - to), mat)
    b.box_between(f"{name}_side_right", (x0, yb - to, z0 + to), (x1, yb, z0 + H - to), mat)
    floors = []  # (part under the row, z of its top)
    for r in range(rows):
        z_floor = z0 + to + r * (ch + ti)
        floors.append((f"{name}_bottom" if r == 0 else f"{name}_board_{r}", z_floor))
        if r > 0:
            b.box_between(f"{name}_board_{r}", (x0, ya + to, z_floor - ti), (x1, yb - to, z_floor), mat)
        for c in range(1, cols):
            yc = ya + to + c * cw + (c - 1) * ti
            b.box_between(f"{name}_divider_{r}_{c}", (x0, yc, z_floor), (x1, yc + ti, z_floor + ch), mat)
    boxed, footprints = {}, []
    n_cells = rows * cols
    for k in range(int(v["n_boxes"])):
        # Boxes sit in the bottom row: a pulled-out box higher up is above the reach of a hand
        # coming down into it (build version 4 found no reachable object in upper-row boxes).
        cell = int(v[f"box_{k}_cell"]) % cols
        while cell in boxed:  # one box per cell: take the next free one
            cell = (cell + 1) % cols
        boxed[cell] = k
        if len(boxed) == cols:
            break
    for cell in range(n_cells):
        r, c = divmod(cell, cols)
        part, zf = floors[r]
        cy0 = ya + to + c * (cw + ti)
        if cell in boxed:
            bw, bd = v["box_width_frac"] * cw, v["box_depth_frac"] * D
            pull = v["box_pull"] * bd
            outside = rect(x0 - bd - 0.01, x0 - 0.005, cy0 - 0.01, cy0 + cw + 0.01)
            footprints.append(build_basket(b, v, f"{name}_box_{boxed[cell]}", (x0 + 0.005 + bd / 2 - pull, cy0 + cw / 2),
                                           (bd, bw), zf, v["box_height_frac"] * ch, surface_clip=outside))
            continue
        b.surface(f"{name}_cell_{r}_{c}", "on_shelf", rect(x0 + 0.003, x1 - 0.003, cy0 + 0.002, cy0 + cw - 0.002), zf, part)
    b.surface(f"{name}_top", "on_shelf", rect(x0 + 0.01, x1 - 0.01, ya + 0.01, yb - 0.01), z0 + H, f"{name}_top")
    return x0, x1, ya, yb, z0 + H, footprints
