"""One module per scene type; importing this package registers them all."""
from . import desk, drawer, large_shelf  # noqa: F401
