"""One module per scene type; importing this package registers them all."""
from . import cell_shelf_desk, desk, desk_wall, drawer, large_shelf  # noqa: F401
