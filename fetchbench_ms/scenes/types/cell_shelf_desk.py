"""CellShelfDesk: a desk with a Kallax-like cell shelf (1-2 rows of open cells, some holding
fabric storage boxes pulled part-way out) standing on the back of its top; objects go on the
free desk top, in the cells, on the shelf's top and into the pulled-out part of the boxes."""
from __future__ import annotations

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, rect, robot_params
from ..pieces.storage import build_cell_shelf, cell_shelf_params, cell_shelf_width
from ..pieces.tables import build_desk, desk_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("desk", desk_params(width=(0.95, 1.2), depth=(0.55, 0.68))),
    *prefixed("cells", cell_shelf_params(rows=(1, 2), cols=(2, 4), depth=(0.25, 0.32))),
    ParamSpec("cells.slide", 0.0, 1.0, "1", "sideways position of the cell shelf on the desk (share of the free width)"),
    ParamSpec("cells.back_inset", 0.0, 0.03, "m", "cell shelf set in from the desk's back edge"),
    *robot_params(z_drop=(0.25, 0.45)),
)


def build(values):
    b = SceneBuilder()
    dv, cv = sub_params(values, "desk"), sub_params(values, "cells")
    top = build_desk(b, dv, "desk", 0.0, 0.0)
    cols = int(cv["cols"])
    while cols > 1 and cell_shelf_width(cv, cols) > top.y1 - top.y0 - 0.02:
        cols -= 1  # as many columns as fit on the desk
    width = cell_shelf_width(cv, cols)
    slack = top.y1 - top.y0 - 0.02 - width
    yc = top.y0 + 0.01 + width / 2 + cv["slide"] * slack
    x_front = top.x1 - cv["back_inset"] - cv["depth"]
    x0, x1, y0, y1, _, boxes = build_cell_shelf(b, cv, "cells", x_front, yc, top.z, cols)
    free = rect(top.x0 + 0.01, top.x1 - 0.01, top.y0 + 0.01, top.y1 - 0.01).difference(rect(x0 - 0.005, x1 + 0.1, y0 - 0.005, y1 + 0.005))
    for box in boxes:  # nothing on the desk under a pulled-out box
        free = free.difference(box.buffer(0.005))
    b.surface_region("desk_top", "on_table", free, top.z, top.part)
    return b.finish("CellShelfDesk", values)


register_scene_type(SceneType("CellShelfDesk", PARAMS, build, ("in_basket", "on_shelf", "on_table"), __doc__))
