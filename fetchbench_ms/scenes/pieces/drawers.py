"""A dresser: a carcass with rows x columns of drawers, one drawer per column pulled out.

Closed drawers are their front panels only (nothing behind them is ever visible or
reachable); a pulled-out drawer is a full open box (front, floor, sides, back) sliding on
the board below its opening. Its ``in_drawer`` surface is the part of its floor that is
out of the carcass, so it is open from above.
"""
from __future__ import annotations

from dataclasses import dataclass

from ..params import ParamSpec
from .builder import SceneBuilder, material, material_params, rect

MAX_ROWS = 4
MAX_COLS = 3


def dresser_params(
    width=(0.6, 1.0), depth=(0.38, 0.5), rows=(2, MAX_ROWS), cols=(1, MAX_COLS), row_height=(0.14, 0.26), pull=(0.55, 0.85)
) -> tuple[ParamSpec, ...]:
    specs = [
        ParamSpec("width", *width, "m", "outer width (along y)"),
        ParamSpec("depth", *depth, "m", "outer depth (along x)"),
        ParamSpec("rows", *rows, "count", "rows of drawers", kind="int"),
        ParamSpec("cols", *cols, "count", "columns of drawers", kind="int"),
    ]
    specs += [ParamSpec(f"row_{r}_height", *row_height, "m", f"clear height of drawer row {r} (from the bottom)") for r in range(rows[1])]
    specs += [
        ParamSpec("panel_thickness", 0.015, 0.025, "m", "carcass side / top / divider thickness"),
        ParamSpec("top_overhang", 0.0, 0.03, "m", "how far the top overhangs the sides and front"),
        ParamSpec("plinth_height", 0.04, 0.12, "m", "height of the plinth under the bottom"),
        ParamSpec("back_thickness", 0.004, 0.01, "m", "back panel thickness"),
        ParamSpec("front_thickness", 0.015, 0.025, "m", "drawer front thickness"),
        ParamSpec("front_gap", 0.002, 0.006, "m", "gap around each drawer front"),
        ParamSpec("drawer_wall", 0.008, 0.016, "m", "drawer box wall and floor thickness"),
        ParamSpec("drawer_clearance", 0.004, 0.015, "m", "side clearance of the drawer box in its opening"),
        ParamSpec("wall_drop", 0.015, 0.05, "m", "drawer box walls end this far below the opening's top"),
        ParamSpec("handle_style", 0, 1, "count", "0 bar handles, 1 knobs", kind="int"),
        ParamSpec("handle_width", 0.08, 0.2, "m", "bar handle length (knobs use a fixed share)"),
        ParamSpec("handle_depth", 0.015, 0.035, "m", "how far handles stand out of the fronts"),
        ParamSpec("handle_height", 0.5, 0.8, "1", "handle height on the front as a share of the front height"),
    ]
    for c in range(cols[1]):
        specs += [
            ParamSpec(f"open_{c}_row", 0, MAX_ROWS - 1, "count", f"pulled-out drawer of column {c} (modulo the rows)", kind="int"),
            ParamSpec(f"open_{c}_pull", *pull, "1", f"pull-out of that drawer as a share of its depth"),
        ]
    specs += list(material_params("carcass", "wood"))
    specs += list(material_params("front", "paint"))
    specs += list(material_params("handle", "metal"))
    specs += list(material_params("drawer", "wood"))
    return tuple(specs)


@dataclass(frozen=True)
class DresserInfo:
    """Outer extent of a built dresser (its top included)."""

    x0: float
    x1: float
    y0: float
    y1: float
    z_top: float


def build_dresser(b: SceneBuilder, v, name: str, x0: float, y0: float, z0: float = 0.0) -> DresserInfo:
    W, D = v["width"], v["depth"]
    rows, cols = int(v["rows"]), int(v["cols"])
    t, tback, tf = v["panel_thickness"], v["back_thickness"], v["front_thickness"]
    gap, wall, clear = v["front_gap"], v["drawer_wall"], v["drawer_clearance"]
    carcass, fronts, handles, box_mat = (material(v, g) for g in ("carcass", "front", "handle", "drawer"))
    ya, yb = y0 - W / 2, y0 + W / 2
    yi0, yi1 = ya + t, yb - t
    x_back = x0 + D - tback
    plinth = v["plinth_height"]
    # Horizontal boards: the bottom, then one above every row; the last is under the top.
    z = z0 + plinth
    b.box_between(f"{name}_bottom", (x0, yi0, z), (x_back, yi1, z + t), carcass)
    z += t
    openings = []  # (z_bottom, z_top) per row
    for r in range(rows):
        zr = z + v[f"row_{r}_height"]
        openings.append((z, zr))
        if r < rows - 1:
            b.box_between(f"{name}_divider_{r}", (x0, yi0, zr), (x_back, yi1, zr + t), carcass)
        z = zr + t
    z_sides = openings[-1][1]
    for side, (lo, hi) in (("left", (ya, yi0)), ("right", (yi1, yb))):
        b.box_between(f"{name}_side_{side}", (x0, lo, z0), (x0 + D, hi, z_sides), carcass)
    oh = v["top_overhang"]
    z_top = z_sides + t
    b.box_between(f"{name}_top", (x0 - oh, ya - oh, z_sides), (x0 + D, yb + oh, z_top), carcass)
    b.box_between(f"{name}_back", (x_back, yi0, z0 + plinth), (x0 + D, yi1, z_sides), carcass)
    b.box_between(f"{name}_plinth", (x0 + 0.02, yi0, z0), (x0 + 0.038, yi1, z0 + plinth), carcass)
    # Columns: vertical dividers in every row.
    col_w = (yi1 - yi0 - (cols - 1) * t) / cols
    col_spans = [(yi0 + c * (col_w + t), yi0 + c * (col_w + t) + col_w) for c in range(cols)]
    for r, (zb, zt) in enumerate(openings):
        for c in range(1, cols):
            y_div = col_spans[c][0] - t
            b.box_between(f"{name}_post_{r}_{c}", (x0, y_div, zb), (x_back, y_div + t, zt), carcass)
    open_rows = {c: int(v[f"open_{c}_row"]) % rows for c in range(cols)}
    for r, (zb, zt) in enumerate(openings):
        for c, (cy0, cy1) in enumerate(col_spans):
            label = f"{name}_drawer_{r}_{c}"
            pull = 0.0
            if open_rows[c] == r:
                depth = x_back - 0.01 - (x0 + tf)
                pull = v[f"open_{c}_pull"] * depth
                _open_box(b, label, x0 + tf - pull, x0, depth, (cy0 + clear, cy1 - clear), zb, zt - v["wall_drop"], wall, box_mat)
            xf = x0 - pull
            b.box_between(f"{label}_front", (xf, cy0 + gap, zb + gap), (xf + tf, cy1 - gap, zt - gap), fronts)
            _handle(b, v, f"{label}_handle", xf, (cy0 + cy1) / 2, zb + gap + v["handle_height"] * (zt - zb - 2 * gap), handles, cy1 - cy0)
    return DresserInfo(x0 - oh, x0 + D, ya - oh, yb + oh, z_top)


def _open_box(b, name, x_start, x_carcass, depth, span_y, z_floor, z_wall_top, wall, mat) -> None:
    """The box of a pulled-out drawer, behind its front (which starts at ``x_start - tf``)."""
    ya, yb = span_y
    x_end = x_start + depth
    b.box_between(f"{name}_floor", (x_start, ya, z_floor), (x_end, yb, z_floor + wall), mat)
    zf = z_floor + wall
    b.box_between(f"{name}_side_left", (x_start, ya, zf), (x_end, ya + wall, z_wall_top), mat)
    b.box_between(f"{name}_side_right", (x_start, yb - wall, zf), (x_end, yb, z_wall_top), mat)
    b.box_between(f"{name}_back", (x_end - wall, ya + wall, zf), (x_end, yb - wall, z_wall_top), mat)
    # The reachable part: the floor out of the carcass, open from above.
    x_out = min(x_end - wall, x_carcass)
    b.surface(name, "in_drawer", rect(x_start, x_out, ya + wall, yb - wall), zf, f"{name}_floor", wall_top=z_wall_top)


def _handle(b, v, name, x_front, yc, zc, mat, front_width) -> None:
    hd = v["handle_depth"]
    if int(v["handle_style"]) == 0:
        hw = min(v["handle_width"], 0.8 * front_width)
        b.box(name, (hd, hw, 0.014), (x_front - hd / 2, yc, zc), mat)
    else:
        b.box(name, (hd, 0.025, 0.025), (x_front - hd / 2, yc, zc), mat)
