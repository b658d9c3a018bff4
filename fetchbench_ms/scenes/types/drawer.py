"""Drawer: a dresser with 2-4 rows and 1-2 columns of drawers; in every column one drawer is
pulled out (by a sampled share of its depth) and objects go into it."""
from __future__ import annotations

from ..params import prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.drawers import build_dresser, dresser_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("dresser", dresser_params(width=(0.7, 1.1), depth=(0.4, 0.52), cols=(1, 3), pull=(0.6, 0.85))),
    *robot_params(z_drop=(0.0, 0.15), z_span=(0.03, 0.1)),
)


def build(values):
    b = SceneBuilder()
    build_dresser(b, sub_params(values, "dresser"), "dresser", 0.0, 0.0)
    return b.finish("Drawer", values)


register_scene_type(SceneType("Drawer", PARAMS, build, ("in_drawer",), __doc__))
