"""FetchBench-MS: the FetchBench fetching benchmark as a ManiSkill3 task-suite plugin.

Importing the package registers the FetchBench-*-v0 environments with gymnasium (and, at the
first ``gym.make`` of one, with ManiSkill). The import is light: torch and the simulator
load when an env is made or a sub-package that needs them is used, so a command answers a
bad flag at once. Sub-packages load on first use (``fetchbench_ms.envs.fetch_clouds``).
"""
__version__ = "0.1.0"

import importlib as _importlib
import importlib.util as _util

from . import _moved

_moved.install()  # moved packages still import by their old names (fetchbench_ms/_moved.py)

if _util.find_spec("fetchbench_ms.envs") is not None:
    from . import envs  # noqa: F401  (registers the environments)


def __getattr__(name: str):
    if not name.startswith("_") and _util.find_spec(f"{__name__}.{name}") is not None:
        return _importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
