"""TriangleShelfDesk: a desk carrying two triangular corner shelves (2-3 boards with a curved
front edge on three thin posts), each placed and turned freely on its half of the desk;
objects go on the triangle shelves' boards (as in the paper, the desk top offers none)."""
from __future__ import annotations

from ..params import prefixed, sub_params
from ..pieces.builder import SceneBuilder, rect, robot_params
from ..pieces.racks import build_triangle_shelf, triangle_shelf_params
from ..pieces.tables import build_desk, desk_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("desk", desk_params(width=(1.05, 1.25), depth=(0.55, 0.68))),
    *prefixed("shelf_a", triangle_shelf_params()),
    *prefixed("shelf_b", triangle_shelf_params()),
    *robot_params(z_drop=(0.25, 0.45)),
)


def build(values):
    b = SceneBuilder()
    top = build_desk(b, sub_params(values, "desk"), "desk", 0.0, 0.0)
    y_mid = (top.y0 + top.y1) / 2
    halves = {"shelf_a": (top.y0 + 0.005, y_mid - 0.005), "shelf_b": (y_mid + 0.005, top.y1 - 0.005)}
    for name, (ya, yb) in halves.items():
        build_triangle_shelf(b, sub_params(values, name), name, rect(top.x0 + 0.005, top.x1 - 0.005, ya, yb), top.z, top.part)
    return b.finish("TriangleShelfDesk", values)


register_scene_type(SceneType("TriangleShelfDesk", PARAMS, build, ("on_shelf",), __doc__))
