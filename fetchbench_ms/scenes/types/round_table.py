"""RoundTable: a round side table (a pedestal on a foot disc, or 3-4 legs) with one or two
baskets standing on it; objects go on the free table top and into the baskets."""
from __future__ import annotations

import math

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.storage import basket_params, build_basket
from ..pieces.tables import build_round_table, round_table_params
from ..registry import SceneType, register_scene_type

MAX_BASKETS = 2

PARAMS = (
    *prefixed("table", round_table_params()),
    ParamSpec("n_baskets", 1, MAX_BASKETS, "count", "baskets on the table (the second only where it fits)", kind="int"),
    ParamSpec("basket_length", 0.16, 0.26, "m", "basket length"),
    ParamSpec("basket_width", 0.12, 0.2, "m", "basket width"),
    ParamSpec("basket_height", 0.07, 0.14, "m", "basket height"),
    *(
        spec
        for k in range(MAX_BASKETS)
        for spec in (
            ParamSpec(f"basket_{k}_angle", -math.pi, math.pi, "rad", f"direction of basket {k} from the table centre"),
            ParamSpec(f"basket_{k}_radius", 0.0, 1.0, "1", f"distance of basket {k} from the centre (share of the room left)"),
            ParamSpec(f"basket_{k}_yaw", -0.6, 0.6, "rad", f"turn of basket {k} relative to its direction"),
        )
    ),
    *prefixed("basket", basket_params()),
    *robot_params(z_drop=(0.2, 0.4)),
)


def build(values):
    b = SceneBuilder()
    tv, bv = sub_params(values, "table"), sub_params(values, "basket")
    top_part, disc, z = build_round_table(b, tv, "table", 0.0, 0.0)
    cx, cy = tv["radius"], 0.0
    L, W = values["basket_length"], values["basket_width"]
    room = max(0.0, tv["radius"] - 0.015 - math.hypot(L, W) / 2)  # the basket stays on the top
    free = disc
    footprints = []
    for k in range(int(values["n_baskets"])):
        a, rho = values[f"basket_{k}_angle"], values[f"basket_{k}_radius"] * room
        center = (cx + rho * math.cos(a), cy + rho * math.sin(a))
        yaw = a + values[f"basket_{k}_yaw"]
        from shapely.geometry import Polygon
        from shapely import affinity

        probe = affinity.translate(affinity.rotate(Polygon([(-L / 2, -W / 2), (L / 2, -W / 2), (L / 2, W / 2), (-L / 2, W / 2)]), yaw, origin=(0, 0), use_radians=True), *center)
        if any(probe.buffer(0.01).intersects(f) for f in footprints):
            continue  # no room for this basket beside the others
        footprint = build_basket(b, bv, f"basket_{k}", center, (L, W), z, values["basket_height"], yaw)
        footprints.append(footprint)
        free = free.difference(footprint.buffer(0.005))
    b.surface_region("table_top", "on_table", free, z, top_part)
    return b.finish("RoundTable", values)


register_scene_type(SceneType("RoundTable", PARAMS, build, ("in_basket", "on_table"), __doc__))
