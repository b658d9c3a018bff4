"""Scripts and baselines as modules in tests (they are files, not a package).

``import_script`` imports a file by its name with its folder on ``sys.path`` for the import
(its sibling modules, such as a trainer's ``common``, resolve), and keeps it in ``sys.modules``
as Python does: a second call returns the same module. ``load_script`` executes the file
afresh each call (a test that changes module state gets a clean copy), registered in
``sys.modules`` under ``name`` because dataclasses look their module up there.
"""
from __future__ import annotations

import importlib
import importlib.util
import sys
from pathlib import Path


def import_script(path: Path, name: str | None = None):
    folder = str(Path(path).parent)
    sys.path.insert(0, folder)
    try:
        return importlib.import_module(name or Path(path).stem)
    finally:
        sys.path.remove(folder)


def load_script(path: Path, name: str | None = None):
    name = name or Path(path).stem
    folder = str(Path(path).parent)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    sys.path.insert(0, folder)
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path.remove(folder)
    return module
