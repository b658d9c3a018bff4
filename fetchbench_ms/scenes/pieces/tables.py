"""Tables and things that hang on walls: desks, round tables, walls, floating wall shelves."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from shapely.geometry import Polygon

from ..params import ParamSpec
from .builder import SceneBuilder, material, material_params, rect


@dataclass(frozen=True)
class TopInfo:
    """The usable top of a table: its part, extent and height."""

    part: str
    x0: float
    x1: float
    y0: float
    y1: float
    z: float

    @property
    def polygon(self) -> Polygon:
        return rect(self.x0, self.x1, self.y0, self.y1)


# --------------------------------------------------------------------------- desk
LEG_STYLES = ("square legs", "round legs", "side panels")


def desk_params(
    width=(0.9, 1.25), depth=(0.55, 0.72), height=(0.66, 0.78)
) -> tuple[ParamSpec, ...]:
    return (
        ParamSpec("width", *width, "m", "desk top width (along y)"),
        ParamSpec("depth", *depth, "m", "desk top depth (along x)"),
        ParamSpec("height", *height, "m", "height of the desk top surface"),
        ParamSpec("top_thickness", 0.02, 0.045, "m", "desk top thickness"),
        ParamSpec("leg_style", 0, 2, "count", "0 square legs, 1 round legs, 2 side panels", kind="int"),
        ParamSpec("leg_size", 0.035, 0.06, "m", "leg side / diameter / side-panel thickness"),
        ParamSpec("leg_inset_x", 0.0, 0.06, "m", "legs set back from the top's front and back edges"),
        ParamSpec("leg_inset_y", 0.0, 0.06, "m", "legs set in from the top's side edges"),
        ParamSpec("apron_height", 0.04, 0.1, "m", "height of the apron rails under the top"),
        ParamSpec("apron_setback", 0.0, 0.02, "m", "apron rails set back from the legs' outer faces"),
        ParamSpec("back_panel_frac", 0.25, 0.6, "1", "modesty panel height as a share of the leg height"),
        *material_params("top", "wood"),
        *material_params("frame", "metal"),
    )


def build_desk(b: SceneBuilder, v, name: str, x0: float, y0: float, z0: float = 0.0) -> TopInfo:
    """A desk whose top's front edge is at ``x0``, centred at ``y0``, standing at ``z0``."""
    W, D, H, tt = v["width"], v["depth"], v["height"], v["top_thickness"]
    top_mat, frame_mat = material(v, "top"), material(v, "frame")
    s, ix, iy = v["leg_size"], v["leg_inset_x"], v["leg_inset_y"]
    z_top, z_under = z0 + H, z0 + H - tt
    b.box_between(f"{name}_top", (x0, y0 - W / 2, z_under), (x0 + D, y0 + W / 2, z_top), top_mat)
    xf, xb = x0 + ix, x0 + D - ix  # outer faces of the leg frame
    yl, yr = y0 - W / 2 + iy, y0 + W / 2 - iy
    style = int(v["leg_style"])
    if style == 2:
        for side, (ya, yb_) in (("left", (yl, yl + s)), ("right", (yr - s, yr))):
            b.box_between(f"{name}_panel_{side}", (xf, ya, z0), (xb, yb_, z_under), frame_mat)
        panel_h = v["back_panel_frac"] * (z_under - z0)
        b.box_between(f"{name}_back_panel", (xb - 0.018, yl + s, z_under - panel_h), (xb, yr - s, z_under), frame_mat)
        return TopInfo(f"{name}_top", x0, x0 + D, y0 - W / 2, y0 + W / 2, z_top)
    corners = {"front_left": (xf, yl), "front_right": (xf, yr - s), "back_left": (xb - s, yl), "back_right": (xb - s, yr - s)}
    for leg, (lx, ly) in corners.items():
        if style == 0:
            b.box_between(f"{name}_leg_{leg}", (lx, ly, z0), (lx + s, ly + s, z_under), frame_mat)
        else:
            b.cylinder(f"{name}_leg_{leg}", s / 2, z0, z_under, (lx + s / 2, ly + s / 2), frame_mat)
    ah, at = v["apron_height"], 0.018
    sb = min(v["apron_setback"], s - at)  # rails of neighbouring sides must not cross
    za = z_under - ah
    # Rails between the legs (flush with the legs' inner faces, so they only touch).
    b.box_between(f"{name}_apron_front", (xf + sb, yl + s, za), (xf + sb + at, yr - s, z_under), frame_mat)
    b.box_between(f"{name}_apron_back", (xb - sb - at, yl + s, za), (xb - sb, yr - s, z_under), frame_mat)
    b.box_between(f"{name}_apron_left", (xf + s, yl + sb, za), (xb - s, yl + sb + at, z_under), frame_mat)
    b.box_between(f"{name}_apron_right", (xf + s, yr - sb - at, za), (xb - s, yr - sb, z_under), frame_mat)
    return TopInfo(f"{name}_top", x0, x0 + D, y0 - W / 2, y0 + W / 2, z_top)


# --------------------------------------------------------------------------- round table
def round_table_params() -> tuple[ParamSpec, ...]:
    return (
        ParamSpec("radius", 0.28, 0.38, "m", "table top radius"),
        ParamSpec("height", 0.55, 0.78, "m", "height of the table top surface"),
        ParamSpec("top_thickness", 0.02, 0.05, "m", "table top thickness"),
        ParamSpec("leg_style", 0, 1, "count", "0 central pedestal on a foot disc, 1 separate legs", kind="int"),
        ParamSpec("n_legs", 3, 4, "count", "number of legs (leg style 1)", kind="int"),
        ParamSpec("leg_radius", 0.015, 0.03, "m", "radius of each leg (leg style 1)"),
        ParamSpec("leg_spread", 0.55, 0.85, "1", "legs' distance from the centre as a share of the radius"),
        ParamSpec("leg_phase", 0.0, 1.0, "1", "angular phase of the legs as a share of their spacing"),
        ParamSpec("pedestal_radius", 0.03, 0.07, "m", "radius of the central column (leg style 0)"),
        ParamSpec("foot_radius_frac", 0.45, 0.8, "1", "foot disc radius as a share of the top radius"),
        ParamSpec("foot_thickness", 0.015, 0.04, "m", "thickness of the foot disc"),
        *material_params("top", "wood"),
        *material_params("leg", "metal"),
    )


def round_polygon(cx: float, cy: float, radius: float, n: int = 48) -> Polygon:
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return Polygon(np.column_stack([cx + radius * np.cos(angles), cy + radius * np.sin(angles)]))


def build_round_table(b: SceneBuilder, v, name: str, x0: float, y0: float) -> tuple[str, Polygon, float]:
    """A round table whose front edge is at ``x0``; returns (top part, usable disc, top height)."""
    R, H, tt = v["radius"], v["height"], v["top_thickness"]
    cx, cy = x0 + R, y0
    top_mat, leg_mat = material(v, "top"), material(v, "leg")
    b.cylinder(f"{name}_top", R, H - tt, H, (cx, cy), top_mat)
    if int(v["leg_style"]) == 0:
        ft = v["foot_thickness"]
        b.cylinder(f"{name}_foot", v["foot_radius_frac"] * R, 0.0, ft, (cx, cy), leg_mat)
        b.cylinder(f"{name}_pedestal", v["pedestal_radius"], ft, H - tt, (cx, cy), leg_mat)
    else:
        n = int(v["n_legs"])
        rho = v["leg_spread"] * R
        for i in range(n):
            a = 2 * np.pi * (i + v["leg_phase"]) / n
            b.cylinder(f"{name}_leg_{i}", v["leg_radius"], 0.0, H - tt, (cx + rho * np.cos(a), cy + rho * np.sin(a)), leg_mat)
    # The usable disc stays 5 mm inside the rim (the rim of a rendered cylinder is faceted).
    return f"{name}_top", round_polygon(cx, cy, R - 0.005), H


# --------------------------------------------------------------------------- wall
def wall_params() -> tuple[ParamSpec, ...]:
    return (
        ParamSpec("wall_height", 2.2, 2.6, "m", "height of the wall behind the furniture"),
        ParamSpec("wall_margin", 0.3, 0.8, "m", "how far the wall reaches beyond the furniture on each side"),
        *material_params("wall", "wall"),
    )


def build_wall(b: SceneBuilder, v, x_face: float, y0: float, y1: float, thickness: float = 0.08) -> None:
    """A wall whose face is the plane x = ``x_face``, covering y0..y1 plus a margin."""
    m = v["wall_margin"]
    b.box_between("wall", (x_face, y0 - m, 0.0), (x_face + thickness, y1 + m, v["wall_height"]), material(v, "wall"))


# --------------------------------------------------------------------------- floating wall shelf
def wall_shelf_params() -> tuple[ParamSpec, ...]:
    return (
        ParamSpec("board_thickness", 0.018, 0.035, "m", "wall shelf board thickness"),
        ParamSpec("bracket_height", 0.06, 0.14, "m", "height of the brackets under each board"),
        ParamSpec("bracket_thickness", 0.008, 0.02, "m", "thickness of the brackets"),
        ParamSpec("bracket_inset", 0.03, 0.12, "m", "brackets set in from the board's ends"),
        ParamSpec("bracket_depth_frac", 0.6, 0.95, "1", "bracket arm length as a share of the board depth"),
        *material_params("board", "wood"),
        *material_params("bracket", "metal"),
    )


def build_wall_shelf(b: SceneBuilder, v, name: str, x_wall: float, depth: float, y0: float, y1: float, z_top: float) -> str:
    """A board hanging on the wall face x = ``x_wall`` on two brackets; returns the board's name."""
    t, bh, bt = v["board_thickness"], v["bracket_height"], v["bracket_thickness"]
    board = f"{name}_board"
    b.box_between(board, (x_wall - depth, y0, z_top - t), (x_wall, y1, z_top), material(v, "board"))
    arm = v["bracket_depth_frac"] * depth
    inset = min(v["bracket_inset"], (y1 - y0) / 2 - bt)
    for side, yc in (("left", y0 + inset), ("right", y1 - inset)):
        b.box_between(f"{name}_bracket_{side}", (x_wall - arm, yc - bt / 2, z_top - t - bh), (x_wall, yc + bt / 2, z_top - t), material(v, "bracket"))
    return board

