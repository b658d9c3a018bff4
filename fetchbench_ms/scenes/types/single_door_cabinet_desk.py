"""SingleDoorCabinetDesk: a desk with a small single-door cabinet standing on one end of its
top; the door hinges on the cabinet's outer edge and stands open. Objects go on the free
desk top, on the cabinet's boards and top, and into a small basket inside the cabinet."""
from __future__ import annotations

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, rect, robot_params
from ..pieces.storage import build_doors, build_shelf_unit, door_params, shelf_unit_params
from ..pieces.tables import build_desk, desk_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("desk", desk_params(width=(0.9, 1.1), depth=(0.5, 0.65))),
    *prefixed(
        "cabinet",
        shelf_unit_params(width=(0.32, 0.46), depth=(0.26, 0.34), n_layers=(2, 3), gap=(0.16, 0.26), plinth=None, max_baskets=1),
    ),
    *prefixed("cabinet", door_params(1)),
    ParamSpec("cabinet.side", 0, 1, "count", "0 cabinet on the desk's left end (-y), 1 on its right end", kind="int"),
    ParamSpec("cabinet.end_inset", 0.0, 0.04, "m", "cabinet set in from the desk's end"),
    ParamSpec("cabinet.back_inset", 0.0, 0.03, "m", "cabinet set in from the desk's back edge"),
    *robot_params(z_drop=(0.25, 0.45)),
)


def build(values):
    b = SceneBuilder()
    dv, cv = sub_params(values, "desk"), sub_params(values, "cabinet")
    top = build_desk(b, dv, "desk", 0.0, 0.0)
    side = "left" if int(cv["side"]) == 0 else "right"
    half = cv["width"] / 2 + cv["end_inset"]
    yc = top.y0 + half if side == "left" else top.y1 - half
    x_front = top.x1 - cv["back_inset"] - cv["depth"]
    info = build_shelf_unit(b, cv, "cabinet", x_front, yc, top.z)
    doors = build_doors(b, cv, "cabinet", info, top.z, (side,))
    free = rect(top.x0 + 0.01, top.x1 - 0.01, top.y0 + 0.01, top.y1 - 0.01).difference(
        rect(info.x0 - 0.005, top.x1 + 0.1, info.y0 - 0.005, info.y1 + 0.005)
    )
    for door in doors:
        free = free.difference(door)
    b.surface_region("desk_top", "on_table", free, top.z, top.part)
    return b.finish("SingleDoorCabinetDesk", values)


register_scene_type(SceneType("SingleDoorCabinetDesk", PARAMS, build, ("in_basket", "on_shelf", "on_table"), __doc__))
