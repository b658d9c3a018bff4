"""DrawerShelf: a chest of drawers (one drawer per column pulled out) with an open shelf
hutch on top holding a basket; objects go into the open drawers, on the hutch boards and
into the basket."""
from __future__ import annotations

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.drawers import build_dresser, dresser_params
from ..pieces.storage import build_shelf_unit, shelf_unit_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("dresser", dresser_params(width=(0.7, 1.0), depth=(0.34, 0.42), rows=(2, 3), cols=(2, 3), row_height=(0.14, 0.24), pull=(0.5, 0.7))),
    *prefixed(
        "hutch",
        shelf_unit_params(width=(0.4, 0.75), depth=(0.24, 0.32), n_layers=(1, 2), gap=(0.22, 0.3), plinth=None, max_baskets=1),
    ),
    ParamSpec("hutch.slide", 0.0, 1.0, "1", "sideways position of the hutch on the chest (share of the free width)"),
    ParamSpec("hutch.front_inset", 0.0, 0.04, "m", "hutch set back from the chest's front edge"),
    *robot_params(z_drop=(0.0, 0.12), z_span=(0.03, 0.1)),
)


def build(values):
    b = SceneBuilder()
    dv, hv = sub_params(values, "dresser"), sub_params(values, "hutch")
    chest = build_dresser(b, dv, "dresser", 0.0, 0.0)
    hv = dict(hv, width=min(hv["width"], chest.y1 - chest.y0))  # no wider than the chest
    slack = chest.y1 - chest.y0 - hv["width"]
    yc = chest.y0 + hv["width"] / 2 + hv["slide"] * slack
    build_shelf_unit(b, hv, "hutch", chest.x0 + hv["front_inset"], yc, chest.z_top, with_top_surface=False)
    return b.finish("DrawerShelf", values)


register_scene_type(SceneType("DrawerShelf", PARAMS, build, ("in_basket", "in_drawer", "on_shelf"), __doc__))
