"""Plain SAPIEN scenes that can live in the same process as ManiSkill envs.

SAPIEN 3 supports one render device per process. A bare ``sapien.Scene()`` picks its own
default device (on a CPU machine the lavapipe adapter by PCI id), and a ManiSkill env made
later in the same process then fails with "only supports single-GPU rendering" because
ManiSkill asks for "cuda" or "cpu". Every plain scene here therefore asks for the device
ManiSkill would choose.
"""
from __future__ import annotations

import sapien


def render_device() -> sapien.Device:
    """The device ManiSkill's default render backend resolves to on this machine."""
    import torch

    return sapien.Device("cuda" if torch.cuda.is_available() else "cpu")


def new_scene(render: bool = True) -> sapien.Scene:
    """A CPU-physics SAPIEN scene, with a renderer on ManiSkill's device when ``render``."""
    systems = [sapien.physx.PhysxCpuSystem()]
    if render:
        systems.append(sapien.render.RenderSystem(render_device()))
    return sapien.Scene(systems)
