"""LayerShelf: an open metal rack, thin boards on four round posts, with wire baskets on
some boards; objects go on the boards and into the baskets."""
from __future__ import annotations

from ..params import prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.racks import build_rack, rack_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("rack", rack_params()),
    *robot_params(z_drop=(0.0, 0.1), z_span=(0.03, 0.1)),
)


def build(values):
    b = SceneBuilder()
    build_rack(b, sub_params(values, "rack"), "rack", 0.0, 0.0)
    return b.finish("LayerShelf", values)


register_scene_type(SceneType("LayerShelf", PARAMS, build, ("in_basket", "on_shelf"), __doc__))
