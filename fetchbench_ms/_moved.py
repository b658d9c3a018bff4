"""Old module paths that still import: a moved package answers to its old name as well, as the
same module objects (``import fetchbench_ms.grasps.store`` is ``fetchbench_ms.grasp_labels.store``),
so code, ``module:function`` strings (``fetchbench grasps build --loader``) and pickles written
before a move keep working. Installed by ``fetchbench_ms/__init__.py``; imports nothing of the
package itself."""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

#: old package -> the package it is now
MOVED = {
    "fetchbench_ms.grasps": "fetchbench_ms.grasp_labels",  # the annotated grasp labels
    "fetchbench_ms.grasping": "fetchbench_ms.grasp_prediction",  # Contact-GraspNet
}


def new_name(name: str) -> str | None:
    """The module an old dotted name stands for now, or None when it did not move."""
    for old, new in MOVED.items():
        if name == old or name.startswith(old + "."):
            return new + name[len(old):]
    return None


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Answers an old name with the module of its new one (first on ``sys.meta_path``, so that
    ``fetchbench_ms.grasps.store`` is never found a second time through the package's folder)."""

    def __init__(self):
        self._specs = {}  # old name -> the spec of the module it stands for

    def find_spec(self, name, path=None, target=None):
        if new_name(name) is None:
            return None
        return importlib.util.spec_from_loader(name, self, is_package=True)

    def create_module(self, spec):
        module = importlib.import_module(new_name(spec.name))
        self._specs[spec.name] = module.__spec__  # the import system sets the old name's spec on it next
        return module

    def exec_module(self, module):
        module.__spec__ = self._specs.pop(module.__spec__.name)  # already executed under its new name: its own spec back


def install() -> None:
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder())
