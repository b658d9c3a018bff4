"""Where the shipped assets live.

In a source checkout (editable install, CI) they are the repository's top-level
``assets/`` folder; in an installed wheel the same files are packaged as
``fetchbench_ms/_assets`` (pyproject maps one onto the other).
"""
from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]


def assets_root() -> Path:
    checkout = _PACKAGE.parent / "assets"
    if checkout.is_dir():
        return checkout
    return _PACKAGE / "_assets"
