"""DeskWall: a desk pushed against a wall with one or two floating shelves (boards on
brackets) hanging on the wall above it; objects go on the desk and on the wall shelves."""
from __future__ import annotations

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, rect, robot_params
from ..pieces.tables import build_desk, build_wall, build_wall_shelf, desk_params, wall_params, wall_shelf_params
from ..scene_type import SceneType, register_scene_type

MAX_SHELVES = 2

PARAMS = (
    *prefixed("desk", desk_params(width=(0.9, 1.2), depth=(0.5, 0.62))),
    *wall_params(),
    ParamSpec("wall_gap", 0.0, 0.03, "m", "gap between the desk's back edge and the wall"),
    *prefixed("wall_shelf", wall_shelf_params()),
    ParamSpec("n_shelves", 1, MAX_SHELVES, "count", "wall shelves above the desk", kind="int"),
    *(
        spec
        for k in range(MAX_SHELVES)
        for spec in (
            ParamSpec(f"shelf_{k}_width_frac", 0.45, 0.95, "1", f"wall shelf {k} width as a share of the desk width"),
            ParamSpec(f"shelf_{k}_depth", 0.18, 0.28, "m", f"wall shelf {k} depth"),
            ParamSpec(f"shelf_{k}_rise", 0.32, 0.45, "m", f"height of wall shelf {k} above the surface below it"),
            ParamSpec(f"shelf_{k}_slide", 0.0, 1.0, "1", f"sideways position of wall shelf {k} (share of the free width)"),
        )
    ),
    *robot_params(z_drop=(0.2, 0.35)),
)


def build(values):
    b = SceneBuilder()
    dv = sub_params(values, "desk")
    top = build_desk(b, dv, "desk", 0.0, 0.0)
    x_wall = top.x1 + values["wall_gap"]
    build_wall(b, values, x_wall, top.y0, top.y1)
    b.surface("desk_top", "on_table", rect(top.x0 + 0.01, top.x1 - 0.01, top.y0 + 0.01, top.y1 - 0.01), top.z, top.part)
    sv = sub_params(values, "wall_shelf")
    z = top.z
    for k in range(int(values["n_shelves"])):
        width = values[f"shelf_{k}_width_frac"] * (top.y1 - top.y0)
        y0 = top.y0 + values[f"shelf_{k}_slide"] * (top.y1 - top.y0 - width)
        depth = values[f"shelf_{k}_depth"]
        z += values[f"shelf_{k}_rise"]
        board = build_wall_shelf(b, sv, f"wall_shelf_{k}", x_wall, depth, y0, y0 + width, z)
        b.surface(f"wall_shelf_{k}", "on_shelf", rect(x_wall - depth + 0.005, x_wall - 0.005, y0 + 0.005, y0 + width - 0.005), z, board)
    return b.finish("DeskWall", values)


register_scene_type(SceneType("DeskWall", PARAMS, build, ("on_shelf", "on_table"), __doc__))
