"""The scene-type registry: name -> generator, and the one entry point ``generate``."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from .params import ParamSpec, sample_params
from .spec import SceneSpec

#: The 13 scene types of the FetchBench paper, in the paper's order.
SCENE_TYPES = (
    "CellShelfDesk",
    "Desk",
    "DeskWall",
    "DoubleDoorCabinet",
    "Drawer",
    "DrawerShelf",
    "EketShelf",
    "LargeShelf",
    "LargeShelfDesk",
    "LayerShelf",
    "RoundTable",
    "SingleDoorCabinetDesk",
    "TriangleShelfDesk",
)


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


_REGISTRY: dict[str, SceneType] = {}


def register_scene_type(scene_type: SceneType) -> SceneType:
    if scene_type.name in _REGISTRY:
        raise ValueError(f"scene type {scene_type.name!r} registered twice")
    _REGISTRY[scene_type.name] = scene_type
    return scene_type


def _ensure_loaded() -> None:
    # The type modules register themselves on import; importing the package loads them.
    from . import types  # noqa: F401


def get_scene_type(name: str) -> SceneType:
    _ensure_loaded()
    if name not in _REGISTRY:
        raise ValueError(f"unknown scene type {name!r}; valid: {', '.join(sorted(_REGISTRY))}")
    return _REGISTRY[name]


def scene_types() -> dict[str, SceneType]:
    _ensure_loaded()
    return dict(sorted(_REGISTRY.items()))


def as_rng(seed_or_rng: int | np.random.Generator) -> np.random.Generator:
    if isinstance(seed_or_rng, np.random.Generator):
        return seed_or_rng
    return np.random.default_rng(int(seed_or_rng))


def generate(
    scene_type: str,
    seed: int | np.random.Generator,
    overrides: Mapping[str, float] | None = None,
) -> SceneSpec:
    """Generate one scene of ``scene_type``: same seed and overrides, same ``SceneSpec`` bytes."""
    st = get_scene_type(scene_type)
    rng = as_rng(seed)
    values = sample_params(st.params, rng, overrides, owner=f"scene type {scene_type!r}")
    spec = st.build(values)
    if spec.scene_type != scene_type:
        raise AssertionError(f"generator for {scene_type} returned a {spec.scene_type}")
    import dataclasses

    # On the 1 um grid: the same bytes (and the same physics) on every CPU (SceneSpec.on_grid).
    return dataclasses.replace(spec.on_grid(), seed=None if isinstance(seed, np.random.Generator) else int(seed))
