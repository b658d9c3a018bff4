"""RoundTable: a round side table (a pedestal on a foot disc, or 3-4 legs) with one or two
baskets standing on it; objects go on the free table top and into the baskets."""
from __future__ import annotations

import math

from shapely import affinity

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, rect, robot_params
from ..pieces.storage import basket_params, build_basket
from ..pieces.tables import build_round_table, round_table_params
from ..scene_type import SceneType, register_scene_type

MAX_BASKETS = 2

PARAMS = (
    *prefixed("table", round_table_params()),
    ParamSpec("n_baskets", 1, MAX_BASKETS, "count", "baskets on the table (the second where it fits)", kind="int"),
    ParamSpec("basket_length_frac", 0.6, 0.9, "1", "basket length as a share of the table radius"),
    ParamSpec("basket_width_frac", 0.5, 0.75, "1", "basket width as a share of its length"),
    ParamSpec("basket_height", 0.08, 0.15, "m", "basket height"),
    ParamSpec("basket_0_angle", -math.pi, math.pi, "rad", "direction of the first basket from the table centre"),
    ParamSpec("basket_1_turn", -0.5, 0.5, "rad", "direction of the second basket from straight opposite the first"),
    *(
        spec
        for k in range(MAX_BASKETS)
        for spec in (
            ParamSpec(f"basket_{k}_radius", 0.0, 1.0, "1", f"distance of basket {k} from the centre (share of the room)"),
            ParamSpec(f"basket_{k}_yaw", -0.4, 0.4, "rad", f"turn of basket {k} from lying along the rim"),
        )
    ),
    *prefixed("basket", basket_params()),
    *robot_params(z_drop=(0.2, 0.4)),
)


def build(values):
    b = SceneBuilder()
    tv, bv = sub_params(values, "table"), sub_params(values, "basket")
    top_part, disc, z = build_round_table(b, tv, "table", 0.0, 0.0)
    cx, cy, R = tv["radius"], 0.0, tv["radius"]
    L = values["basket_length_frac"] * R
    W = values["basket_width_frac"] * L
    n = int(values["n_baskets"])
    free = disc
    footprints = []
    for k in range(n):
        a = values["basket_0_angle"] + (0.0 if k == 0 else math.pi + values["basket_1_turn"])
        turn = values[f"basket_{k}_yaw"]
        yaw = a + math.pi / 2 + turn  # lying along the rim, turned a little
        rho_max = _farthest_out(R - 0.015, L, W, turn)
        share = values[f"basket_{k}_radius"] if n == 1 else 0.7 + 0.3 * values[f"basket_{k}_radius"]
        for rho in (share * rho_max, rho_max):  # pushed out to the rim if it collides
            center = (cx + rho * math.cos(a), cy + rho * math.sin(a))
            probe = affinity.translate(affinity.rotate(rect(-L / 2, L / 2, -W / 2, W / 2), yaw, origin=(0, 0), use_radians=True), *center)
            if not any(probe.buffer(0.01).intersects(f) for f in footprints):
                break
        else:
            continue  # no room for this basket beside the others
        footprint = build_basket(b, bv, f"basket_{k}", center, (L, W), z, values["basket_height"], yaw)
        footprints.append(footprint)
        free = free.difference(footprint.buffer(0.005))
    b.surface_region("table_top", "on_table", free, z, top_part)
    return b.finish("RoundTable", values)


def _farthest_out(radius: float, L: float, W: float, turn: float) -> float:
    """Largest distance from the centre at which an L x W basket (length along the rim,
    turned by ``turn``) keeps every corner within ``radius``."""
    axis_l = (-math.sin(turn), math.cos(turn))  # (radial, tangential) components
    axis_w = (math.cos(turn), math.sin(turn))
    limits = []
    for sl in (-0.5, 0.5):
        for sw in (-0.5, 0.5):
            cu = sl * L * axis_l[0] + sw * W * axis_w[0]
            cv = sl * L * axis_l[1] + sw * W * axis_w[1]
            limits.append(-cu + math.sqrt(max(radius**2 - cv**2, 0.0)))
    return max(0.0, min(limits))


register_scene_type(SceneType("RoundTable", PARAMS, build, ("in_basket", "on_table"), __doc__))
