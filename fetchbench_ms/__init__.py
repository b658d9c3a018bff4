"""FetchBench-MS: the FetchBench fetching benchmark as a ManiSkill3 task-suite plugin.

Importing the package registers the FetchBench-*-v0 environments with ManiSkill and
gymnasium (once the envs sub-package is present).
"""
__version__ = "0.1.0"

import importlib.util as _util

if _util.find_spec("fetchbench_ms.envs") is not None:
    from . import envs  # noqa: F401  (registers the environments)
