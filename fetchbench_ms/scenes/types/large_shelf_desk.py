"""LargeShelfDesk: a desk with a tall bookcase (baskets on some boards) standing on the floor
right beside it, fronts aligned; objects go on the desk, on the shelves and into the baskets."""
from __future__ import annotations

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, rect, robot_params
from ..pieces.storage import build_shelf_unit, shelf_unit_params
from ..pieces.tables import build_desk, desk_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("desk", desk_params(width=(0.65, 0.9), depth=(0.5, 0.65))),
    *prefixed("shelf", shelf_unit_params(width=(0.45, 0.65), depth=(0.28, 0.36), n_layers=(3, 5), gap=(0.22, 0.32))),
    ParamSpec("shelf.side", 0, 1, "count", "0 bookcase on the desk's left (-y), 1 on its right", kind="int"),
    ParamSpec("shelf.gap", 0.0, 0.05, "m", "gap between desk and bookcase"),
    ParamSpec("shelf.front_offset", 0.0, 0.05, "m", "bookcase front set back from the desk front"),
    *robot_params(z_drop=(0.0, 0.1), z_span=(0.03, 0.1)),
)


def build(values):
    b = SceneBuilder()
    dv, sv = sub_params(values, "desk"), sub_params(values, "shelf")
    top = build_desk(b, dv, "desk", 0.0, 0.0)
    b.surface("desk_top", "on_table", rect(top.x0 + 0.01, top.x1 - 0.01, top.y0 + 0.01, top.y1 - 0.01), top.z, top.part)
    offset = sv["gap"] + sv["width"] / 2
    yc = top.y0 - offset if int(sv["side"]) == 0 else top.y1 + offset
    build_shelf_unit(b, sv, "shelf", sv["front_offset"], yc)
    return b.finish("LargeShelfDesk", values)


register_scene_type(SceneType("LargeShelfDesk", PARAMS, build, ("in_basket", "on_shelf", "on_table"), __doc__))
