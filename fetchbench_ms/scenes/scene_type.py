"""A scene type (``SceneType``: declared parameters and a pure build function) and the table
the type modules register themselves into on import. Below both the registry
(``registry``: lookups and ``generate``) and the type modules (``types``), so that the
registry can load the types without the types importing it back."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from .params import ParamSpec
from .spec import SceneSpec


@dataclass(frozen=True)
class SceneType:
    """A procedural generator: declared parameters + a pure function of their values."""

    name: str
    params: tuple[ParamSpec, ...]
    # Builds the scene from a complete dict of parameter values. Pure: no randomness.
    build: Callable[[dict[str, float]], SceneSpec]
    # Support labels this type always offers (the paper's appendix table).
    support_labels: tuple[str, ...]
    description: str = ""


#: name -> scene type, filled by ``register_scene_type`` as each type module is imported.
REGISTERED: dict[str, SceneType] = {}


def register_scene_type(scene_type: SceneType) -> SceneType:
    if scene_type.name in REGISTERED:
        raise ValueError(f"scene type {scene_type.name!r} registered twice")
    REGISTERED[scene_type.name] = scene_type
    return scene_type
