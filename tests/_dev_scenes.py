"""Stand-in scene generators for the 13 scene-type names, registered only for names the
real generators (branch scene-types) do not provide yet. A table with a basket on it,
a shelf with boards, and a pre-opened drawer: every support label is present."""
from __future__ import annotations

from fetchbench_ms.scenes import registry
from fetchbench_ms.scenes.params import ParamSpec
from fetchbench_ms.scenes.spec import CameraTargetRegion, Part, RobotRegion, SceneSpec, SupportSurface


def _box(name, lo, hi):
    size = tuple(h - l for l, h in zip(lo, hi))
    centre = tuple((l + h) / 2 for l, h in zip(lo, hi))
    return Part(name=name, shape="box", size=size, position=centre)


def _rect(x0, x1, y0, y1):
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1))


def _build(name):
    def build(p):
        x0, t = p["x0"], 0.03
        h = p["table_h"]
        parts = [
            _box("table_top", (x0, -0.9, h - t), (x0 + 0.6, -0.1, h)),
            _box("table_leg", (x0 + 0.25, -0.55, 0), (x0 + 0.35, -0.45, h - t)),
            # basket on the table
            _box("basket_floor", (x0 + 0.1, -0.85, h), (x0 + 0.45, -0.55, h + 0.01)),
            _box("basket_w0", (x0 + 0.1, -0.85, h), (x0 + 0.11, -0.55, h + 0.08)),
            _box("basket_w1", (x0 + 0.44, -0.85, h), (x0 + 0.45, -0.55, h + 0.08)),
            _box("basket_w2", (x0 + 0.1, -0.85, h), (x0 + 0.45, -0.84, h + 0.08)),
            _box("basket_w3", (x0 + 0.1, -0.56, h), (x0 + 0.45, -0.55, h + 0.08)),
            # shelf with two boards
            _box("shelf_b0", (x0, 0.0, 0.45), (x0 + 0.4, 0.8, 0.47)),
            _box("shelf_b1", (x0, 0.0, 0.85), (x0 + 0.4, 0.8, 0.87)),
            _box("shelf_back", (x0 + 0.4, 0.0, 0.0), (x0 + 0.42, 0.8, 1.2)),
            _box("shelf_side0", (x0, -0.02, 0.0), (x0 + 0.42, 0.0, 1.2)),
            _box("shelf_side1", (x0, 0.8, 0.0), (x0 + 0.42, 0.82, 1.2)),
            # pre-opened drawer below the first board
            _box("drawer_floor", (x0 - 0.2, 0.1, 0.2), (x0 + 0.2, 0.7, 0.21)),
            _box("drawer_front", (x0 - 0.22, 0.1, 0.15), (x0 - 0.2, 0.7, 0.33)),
            _box("drawer_w0", (x0 - 0.2, 0.1, 0.21), (x0 + 0.2, 0.11, 0.3)),
            _box("drawer_w1", (x0 - 0.2, 0.69, 0.21), (x0 + 0.2, 0.7, 0.3)),
            _box("drawer_back", (x0 + 0.19, 0.1, 0.21), (x0 + 0.2, 0.7, 0.3)),
        ]
        surfaces = [
            SupportSurface("table", "on_table", _rect(x0 + 0.02, x0 + 0.58, -0.5, -0.12), h, 1.0, "table_top"),
            SupportSurface("basket", "in_basket", _rect(x0 + 0.11, x0 + 0.44, -0.84, -0.56), h + 0.01, 1.0, "basket_floor", h + 0.08),
            SupportSurface("shelf0", "on_shelf", _rect(x0 + 0.01, x0 + 0.39, 0.01, 0.79), 0.47, 0.38, "shelf_b0"),
            SupportSurface("shelf1", "on_shelf", _rect(x0 + 0.01, x0 + 0.39, 0.01, 0.79), 0.87, 0.33, "shelf_b1"),
            SupportSurface("drawer", "in_drawer", _rect(x0 - 0.19, x0 + 0.19, 0.11, 0.69), 0.21, 0.24, "drawer_floor", 0.3),
        ]
        return SceneSpec(
            scene_type=name, seed=None, params=dict(p), parts=tuple(parts), support_surfaces=tuple(surfaces),
            robot_region=RobotRegion((x0 - 0.75, x0 - 0.65), (-0.1, 0.1), (0.35, 0.45)),
            camera_target=CameraTargetRegion((x0 + 0.2, 0.0, 0.55), (0.25, 0.6, 0.35)),
        )

    return build


def ensure_registered() -> None:
    registry._ensure_loaded()
    for name in registry.SCENE_TYPES:
        if name not in registry._REGISTRY:
            registry.register_scene_type(registry.SceneType(
                name=name,
                params=(ParamSpec("x0", 0.5, 0.6, "m", "front of the furniture"),
                        ParamSpec("table_h", 0.55, 0.7, "m", "table height")),
                build=_build(name),
                support_labels=("in_basket", "in_drawer", "on_shelf", "on_table"),
            ))
