"""DoubleDoorCabinet: a kitchen wall cupboard hanging on a wall, both doors swung open, 2-3
compartments and a small basket on one board. The robot stands 0.2-0.5 m below its lowest
board, as in the paper (fetching from a cupboard above a counter)."""
from __future__ import annotations

from ..params import ParamSpec, prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.storage import build_doors, build_shelf_unit, door_params, shelf_unit_params
from ..pieces.tables import build_wall, wall_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed(
        "cabinet",
        shelf_unit_params(width=(0.66, 0.9), depth=(0.28, 0.36), n_layers=(2, 3), gap=(0.2, 0.3), plinth=None, max_baskets=1),
    ),
    *prefixed("cabinet", door_params(2)),
    ParamSpec("cabinet.mount_height", 0.9, 1.2, "m", "height of the cupboard's underside above the floor"),
    ParamSpec("cabinet.shift", -0.1, 0.1, "m", "sideways shift of the cupboard on the wall"),
    *wall_params(),
    *robot_params(y_half=(0.02, 0.07), y_shift=(-0.03, 0.03), z_drop=(0.2, 0.35), z_span=(0.05, 0.15)),
)


def build(values):
    b = SceneBuilder()
    cv = sub_params(values, "cabinet")
    z0 = cv["mount_height"]
    info = build_shelf_unit(b, cv, "cabinet", 0.0, cv["shift"], z0, with_top_surface=False)
    build_doors(b, cv, "cabinet", info, z0, ("left", "right"))
    wv = dict(values, wall_height=max(values["wall_height"], info.z_top + 0.1))
    build_wall(b, wv, info.x1, info.y0, info.y1)
    return b.finish("DoubleDoorCabinet", values)


register_scene_type(SceneType("DoubleDoorCabinet", PARAMS, build, ("in_basket", "on_shelf"), __doc__))
