"""Procedural furniture scenes built from primitives (the 13 FetchBench scene types).

    from fetchbench_ms.scenes import generate
    spec = generate("LargeShelf", seed=3)            # a SceneSpec
    spec = generate("Desk", seed=3, overrides={"desk.height": 0.75})
"""
from .params import ParamSpec
from .registry import SCENE_TYPES, generate, get_scene_type, scene_types
from .scene_type import SceneType
from .spec import SUPPORT_LABELS, CameraTargetRegion, Material, Part, RobotRegion, SceneSpec, SupportSurface

__all__ = [
    "SCENE_TYPES",
    "SUPPORT_LABELS",
    "CameraTargetRegion",
    "Material",
    "ParamSpec",
    "Part",
    "RobotRegion",
    "SceneSpec",
    "SceneType",
    "SupportSurface",
    "generate",
    "get_scene_type",
    "scene_types",
]
