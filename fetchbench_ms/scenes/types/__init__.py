"""One module per scene type; importing this package registers them all."""
from . import (  # noqa: F401
    cell_shelf_desk,
    desk,
    desk_wall,
    double_door_cabinet,
    drawer,
    drawer_shelf,
    eket_shelf,
    large_shelf,
    large_shelf_desk,
    layer_shelf,
    round_table,
    single_door_cabinet_desk,
    triangle_shelf_desk,
)
