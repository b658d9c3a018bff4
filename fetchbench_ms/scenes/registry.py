"""The scene-type registry: name -> generator, and the one entry point ``generate``."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from .params import sample_params
from .scene_type import REGISTERED, SceneType
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


def _ensure_loaded() -> None:
    # The type modules register themselves on import; importing the package loads them.
    from . import types  # noqa: F401


def get_scene_type(name: str) -> SceneType:
    _ensure_loaded()
    if name not in REGISTERED:
        raise ValueError(f"unknown scene type {name!r}; valid: {', '.join(sorted(REGISTERED))}")
    return REGISTERED[name]


def scene_types() -> dict[str, SceneType]:
    _ensure_loaded()
    return dict(sorted(REGISTERED.items()))


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
