"""Desk: a plain work desk (square or round legs with apron rails, or side panels with a
modesty panel); objects stand on its top."""
from __future__ import annotations

from ..params import prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.tables import build_desk, desk_params
from ..scene_type import SceneType, register_scene_type
from ..spec import SceneSpec

PARAMS = (
    *prefixed("desk", desk_params(width=(0.9, 1.25), depth=(0.55, 0.72))),
    *robot_params(z_drop=(0.25, 0.45)),
)


def build(values) -> SceneSpec:
    b = SceneBuilder()
    top = build_desk(b, sub_params(values, "desk"), "desk", 0.0, 0.0)
    b.surface("desk_top", "on_table", top.polygon.buffer(-0.01, join_style="mitre"), top.z, top.part)
    return b.finish("Desk", values)


register_scene_type(SceneType("Desk", PARAMS, build, ("on_table",), __doc__))
