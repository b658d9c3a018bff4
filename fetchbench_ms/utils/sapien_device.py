"""The one SAPIEN render device of a process, chosen as ManiSkill chooses it.

SAPIEN 3.0 renders on a single device per process: while any renderer is alive, asking
for another device fails ("current SAPIEN version only supports single-GPU rendering").
A plain ``sapien.Scene()`` takes the first Vulkan device it finds (e.g. ``pci:...``), but
ManiSkill's default render backend asks for ``cuda`` and falls back to ``cpu``
(``mani_skill/envs/utils/system/backend.py``). So code that renders outside an env (scene
pictures, tests) must use the same device, or a ManiSkill env made later in the same
process cannot render.
"""
from __future__ import annotations

import functools

import sapien


@functools.cache
def render_device() -> sapien.Device:
    """``cuda`` when SAPIEN finds one, else ``cpu``: ManiSkill's default choice."""
    try:
        return sapien.Device("cuda")
    except RuntimeError:
        return sapien.Device("cpu")


def new_scene(with_render: bool = True) -> sapien.Scene:
    """A CPU-physics SAPIEN scene whose renderer (if any) is on ``render_device()``."""
    systems = [sapien.physx.PhysxCpuSystem()]
    if with_render:
        systems.append(sapien.render.RenderSystem(render_device()))
    return sapien.Scene(systems)
