"""One module per scene type; importing this package registers them all."""
from . import desk  # noqa: F401
