"""LargeShelf: a tall bookcase (Billy/Hemnes-like) with 3-5 compartments of sampled heights
and one or two baskets standing on chosen boards. Boards higher than the arm can reach
from a base that reaches the lowest one are built but offer no support surface."""
from __future__ import annotations

from ..params import prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.storage import build_shelf_unit, shelf_unit_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("shelf", shelf_unit_params(width=(0.6, 0.9), depth=(0.28, 0.4), n_layers=(3, 5), gap=(0.22, 0.34), plinth=(0.03, 0.12))),
    *robot_params(z_drop=(0.0, 0.1), z_span=(0.03, 0.1)),
)


def build(values):
    b = SceneBuilder()
    build_shelf_unit(b, sub_params(values, "shelf"), "shelf", 0.0, 0.0)
    return b.finish("LargeShelf", values)


register_scene_type(SceneType("LargeShelf", PARAMS, build, ("in_basket", "on_shelf"), __doc__))
