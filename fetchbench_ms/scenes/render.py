"""Render a ``SceneSpec`` with SAPIEN, its support surfaces highlighted by label.

The camera stands like the robot's: above and behind the middle of the robot region,
looking at the camera target region, pulled back just far enough that the support
surfaces and the camera target fit the picture. Each support surface is drawn as a thin
translucent slab 3 mm above its polygon, coloured by label (``LABEL_COLORS``); a colour
key is drawn in the picture's corner. Works with SAPIEN's CPU renderer (lavapipe).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import sapien

from ..utils.io import atomic_write_bytes
from ..utils.mesh_cache import mesh_file
from ..utils.sapien_device import new_scene
from .geometry import part_aabb, surface_slab
from .sapien_build import build_static_scene
from .spec import SUPPORT_LABELS, SceneSpec

#: Highlight colour of each support label (RGB, 0-1); the docs show the same key.
LABEL_COLORS = {
    "on_table": (1.00, 0.55, 0.00),
    "on_shelf": (0.10, 0.45, 1.00),
    "in_drawer": (0.10, 0.80, 0.20),
    "in_basket": (0.90, 0.10, 0.80),
}
assert set(LABEL_COLORS) == set(SUPPORT_LABELS)

OVERLAY_ALPHA = 0.7
OVERLAY_LIFT = 0.003  # m above the surface: clear of the board, below any object
OVERLAY_THICKNESS = 0.002
VERTICAL_FOV = np.deg2rad(50.0)
# Where the camera starts from, relative to the robot region's top centre (m): behind
# and above the base, as a head or shoulder camera would be.
EYE_OFFSET = np.array([-0.30, 0.0, 1.00])

# The last rendered scene, kept alive on purpose: when the only SAPIEN scene that uses
# the renderer is destroyed, the next picture recompiles every shader (~10 s on the CPU
# renderer instead of ~0.1 s). Replaced only after the next scene exists.
_KEEP_ALIVE: list = []


def look_at(eye, target) -> sapien.Pose:
    """SAPIEN camera pose at ``eye`` looking at ``target`` (camera x forward, z up)."""
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    left = np.cross([0.0, 0.0, 1.0], forward)
    if np.linalg.norm(left) < 1e-6:  # looking straight down
        left = np.array([0.0, 1.0, 0.0])
    left /= np.linalg.norm(left)
    up = np.cross(forward, left)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([forward, left, up])
    T[:3, 3] = eye
    return sapien.Pose(T)


def _view_points(spec: SceneSpec) -> np.ndarray:
    """Points the picture must contain: the camera target box and every support polygon
    (at its height and 8 cm above)."""
    c = np.asarray(spec.camera_target.center)
    h = np.asarray(spec.camera_target.half_size)
    points = [c + h * np.array([sx, sy, sz]) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
    for s in spec.support_surfaces:
        for x, y in s.polygon_xy:
            points += [(x, y, s.height), (x, y, s.height + 0.08)]
    return np.asarray(points)


def camera_pose(spec: SceneSpec, width: int, height: int, fovy: float = VERTICAL_FOV) -> sapien.Pose:
    """Robot-like viewpoint, moved back along its line of sight until everything fits."""
    region = spec.robot_region
    eye0 = np.array([np.mean(region.x_range), np.mean(region.y_range), region.z_range[1]]) + EYE_OFFSET
    target = np.asarray(spec.camera_target.center, float)
    forward = target - eye0
    forward /= np.linalg.norm(forward)
    pose0 = look_at(eye0, target).to_transformation_matrix()
    left, up = pose0[:3, 1], pose0[:3, 2]
    rel = _view_points(spec) - target
    tan_v = np.tan(fovy / 2) * 0.92  # keep a margin at the border
    tan_h = tan_v * width / height
    # A point p is inside when |p.left| <= tan_h * depth and |p.up| <= tan_v * depth,
    # depth = p.forward + d for the eye at distance d before the target.
    need = np.maximum(np.abs(rel @ left) / tan_h, np.abs(rel @ up) / tan_v) - rel @ forward
    distance = max(float(need.max()), float(np.linalg.norm(target - eye0)) * 0.5, 0.3)
    return look_at(target - distance * forward, target)


def _add_overlays(scene, spec: SceneSpec) -> None:
    builder = scene.create_actor_builder()
    for surface in spec.support_surfaces:
        slab = surface_slab(surface, OVERLAY_THICKNESS, lift=OVERLAY_LIFT)
        material = sapien.render.RenderMaterial(base_color=[*LABEL_COLORS[surface.label], OVERLAY_ALPHA])
        builder.add_visual_from_file(mesh_file(slab), material=material)
    if spec.support_surfaces:
        builder.build_static(name="support_overlays")


def _draw_key(image: np.ndarray, labels) -> np.ndarray:
    """Colour key of ``labels`` in the top-left corner (PIL's built-in font)."""
    from PIL import Image, ImageDraw

    picture = Image.fromarray(image)
    draw = ImageDraw.Draw(picture)
    size = max(8, image.shape[0] // 24)
    for k, label in enumerate(labels):
        y = 4 + k * (size + 4)
        rgb = tuple(int(255 * c) for c in LABEL_COLORS[label])
        draw.rectangle([4, y, 4 + size, y + size], fill=rgb, outline=(0, 0, 0))
        draw.text((8 + size, y - 1), label, fill=(0, 0, 0))
    return np.asarray(picture)


def render_scene(spec: SceneSpec, width: int = 640, height: int = 480, highlight: bool = True, key: bool = True) -> np.ndarray:
    """RGB picture [height, width, 3] uint8 of the furniture (with surface highlights)."""
    if width < 16 or height < 16:
        raise ValueError(f"picture size must be at least 16x16, got {width}x{height}")
    scene = new_scene()  # on ManiSkill's render device, so envs made later still render
    scene.set_ambient_light([0.45, 0.45, 0.45])
    scene.add_directional_light([0.4, 0.6, -1.0], [0.75, 0.75, 0.75], shadow=False)
    scene.add_directional_light([-0.6, -0.3, -0.5], [0.25, 0.25, 0.25], shadow=False)
    floor = sapien.render.RenderMaterial(base_color=[0.82, 0.82, 0.80, 1.0], roughness=0.9)
    scene.add_ground(0.0, render_material=floor)
    build_static_scene(scene, spec)
    if highlight:
        _add_overlays(scene, spec)
    # The camera shader and the pictures' formats are process-wide SAPIEN settings that
    # ManiSkill switches when it builds an env (its "minimal" sensors make "Color" 8-bit,
    # which this float picture read would clip): ask for ManiSkill's full pack here.
    from mani_skill.render.shaders import PREBUILT_SHADER_CONFIGS, set_shader_pack

    set_shader_pack(PREBUILT_SHADER_CONFIGS["default"])
    camera = scene.add_camera("view", width, height, VERTICAL_FOV, 0.02, 20.0)
    camera.entity.set_pose(camera_pose(spec, width, height))
    scene.update_render()
    camera.take_picture()
    rgba = np.asarray(camera.get_picture("Color"))
    _KEEP_ALIVE[:] = [scene]
    image = (np.clip(rgba[..., :3], 0.0, 1.0) * 255).round().astype(np.uint8)
    if highlight and key:
        image = _draw_key(image, [lab for lab in SUPPORT_LABELS if lab in spec.support_labels])
    return image


def save_png(image: np.ndarray, path: str | Path) -> None:
    """Write ``image`` as a PNG (atomically)."""
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG", optimize=True)
    atomic_write_bytes(path, buffer.getvalue())


def scene_extent(spec: SceneSpec) -> np.ndarray:
    """Bounds [[x0, y0, z0], [x1, y1, z1]] of all parts."""
    boxes = np.array([part_aabb(p) for p in spec.parts])
    return np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])
