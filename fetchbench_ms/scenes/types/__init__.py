"""One module per scene type; importing this package registers them all."""
from . import (  # noqa: F401
    cell_shelf_desk,
    desk,
    desk_wall,
    double_door_cabinet,
    drawer,
    drawer_shelf,
    large_shelf,
    large_shelf_desk,
    round_table,
    single_door_cabinet_desk,
)
