"""ManiSkill's warnings that are expected on a CPU machine, silenced (``quiet_maniskill``).

A pip install of ManiSkill warns "mani_skill is not installed with git" each time a recorder
asks for its commit (6 times a demo run); without CUDA it warns that the requested
``sapien_cuda`` render device was not found at every env creation; and an env made without a
renderer (``render_backend="none"``, as demos record) warns at every scene rebuild that its
render mode cannot render (13 times a replay). None of them asks anything of the user. The
first two are dropped, the render-device one is replaced by one line, once per run (its
worker processes inherit that it was said), naming the device that is used; every other
ManiSkill message passes unchanged.
"""
from __future__ import annotations

import logging
import os
import sys

NOTE_ENV = "FETCHBENCH_RENDER_NOTE_SHOWN"  # set once the one line is out (worker processes inherit it)
_MANISKILL_LOGGER = "mani_skill "  # (sic: mani_skill.utils.logging_utils names it with a space)


class _ExpectedOnCPU(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        if message.startswith("mani_skill is not installed with git"):
            return False  # a pip install: the recorder stores no commit, as intended
        if "does not support rendering" in message and 'device "None"' in message:
            return False  # render_backend="none" was asked for: no renderer, on purpose
        if "but CUDA device was not found" in message:
            _say_once()
            return False
        return True


def quiet_maniskill() -> None:
    """Install the filter on ManiSkill's logger (once a process; safe to call again)."""
    logger = logging.getLogger(_MANISKILL_LOGGER)
    if not any(isinstance(f, _ExpectedOnCPU) for f in logger.filters):
        logger.addFilter(_ExpectedOnCPU())


def announce_render_device() -> None:
    """The one line, said by a parent before it starts env workers (which then stay quiet),
    when there is no CUDA device; nothing where there is one."""
    if os.environ.get(NOTE_ENV):
        return
    from .sapien_device import render_device

    if not render_device().is_cuda():
        _say_once()


def _say_once() -> None:
    if not os.environ.get(NOTE_ENV):
        os.environ[NOTE_ENV] = "1"
        print("fetchbench: no CUDA device here: SAPIEN renders on the CPU (Vulkan CPU device) and simulates on "
              "the CPU", file=sys.stderr, flush=True)
