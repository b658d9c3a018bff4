"""Where the shipped assets live.

In a source checkout (editable install, CI) they are the repository's top-level
``assets/`` folder; in an installed wheel the same files are packaged as
``fetchbench_ms/_assets`` (pyproject maps one onto the other).
"""
from __future__ import annotations

from pathlib import Path

_PACKAGE = Path(__file__).resolve().parents[1]


def assets_root() -> Path:
    # A checkout is recognised by its pyproject.toml beside the package: in an installed
    # wheel the package's parent is site-packages, where another distribution may have put
    # a top-level "assets" folder of its own.
    checkout = _PACKAGE.parent / "assets"
    if checkout.is_dir() and (_PACKAGE.parent / "pyproject.toml").is_file():
        return checkout
    return _PACKAGE / "_assets"
