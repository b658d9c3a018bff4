"""EketShelf: open cubes (Eket-like) hung on a wall in 2-3 columns of one or two cubes,
some with a middle board; objects go on the cube floors, boards and tops."""
from __future__ import annotations

from ..params import prefixed, sub_params
from ..pieces.builder import SceneBuilder, robot_params
from ..pieces.racks import build_cube_wall, cube_wall_params
from ..pieces.storage import MAX_SUPPORT_SPAN
from ..pieces.tables import build_wall, wall_params
from ..scene_type import SceneType, register_scene_type

PARAMS = (
    *prefixed("cubes", cube_wall_params()),
    *wall_params(),
    *robot_params(z_drop=(0.1, 0.3), z_span=(0.03, 0.1)),
)


def build(values):
    b = SceneBuilder()
    cv = sub_params(values, "cubes")
    x_wall = cv["depth"]
    y0, y1, candidates = build_cube_wall(b, cv, "cube", x_wall, 0.0)
    build_wall(b, values, x_wall, y0, y1)
    lowest = min(s.z for s in candidates)
    for s in candidates:
        if s.z - lowest <= MAX_SUPPORT_SPAN:  # out of reach above that
            b.surface(s.name, "on_shelf", s.polygon, s.z, s.part)
    return b.finish("EketShelf", values)


register_scene_type(SceneType("EketShelf", PARAMS, build, ("on_shelf",), __doc__))
