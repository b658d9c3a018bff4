"""Pictures and mesh exports of scenes (a separate file so pytest-xdist's ``loadfile``
gives the one-off shader compilation of the CPU renderer its own worker)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from conftest import reference_shelf
from PIL import Image

from fetchbench_ms import cli
from fetchbench_ms.scenes import generate, scene_types
from fetchbench_ms.scenes.export import export_scene, scene_to_trimesh
from fetchbench_ms.scenes.render import LABEL_COLORS, _view_points, camera_pose, render_scene, scene_extent


def _types():
    types = list(scene_types())
    if not types:
        pytest.fail("no scene types are registered")
    return types


def test_render_cli_writes_a_non_blank_png_of_the_asked_size(tmp_path):
    name = _types()[0]
    out = tmp_path / "scene.png"
    assert cli.main(["scenes", "render", name, "--seed", "2", "--out", str(out), "--width", "200", "--height", "150"]) == 0
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape == (150, 200, 3)
    # Not one flat colour: the furniture, floor and sky differ.
    assert image.reshape(-1, 3).std(axis=0).max() > 20
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50


def test_highlights_show_each_label_in_its_colour():
    spec = reference_shelf()
    plain = render_scene(spec, 160, 120, highlight=False).astype(int)
    marked = render_scene(spec, 160, 120, highlight=True, key=False).astype(int)
    changed = np.abs(plain - marked).sum(axis=-1) > 30
    assert changed.mean() > 0.05, "the shelf overlays must cover a visible part of the picture"
    # Where the overlay is, the picture moved toward the on_shelf colour (blue).
    blue = np.asarray(LABEL_COLORS["on_shelf"]) * 255
    closer = np.linalg.norm(marked[changed] - blue, axis=-1) < np.linalg.norm(plain[changed] - blue, axis=-1)
    assert closer.mean() > 0.9


@pytest.mark.parametrize("name", ["ReferenceShelf"] + list(scene_types()))
def test_camera_sees_every_support_surface(name):
    spec = reference_shelf() if name == "ReferenceShelf" else generate(name, 0)
    width, height = 320, 240
    pose = camera_pose(spec, width, height).to_transformation_matrix()
    rel = (_view_points(spec) - pose[:3, 3]) @ pose[:3, :3]  # camera frame: x forward, y left, z up
    assert (rel[:, 0] > 0.05).all(), "every support polygon is in front of the camera"
    fy = np.tan(np.deg2rad(50.0) / 2)
    fx = fy * width / height
    assert (np.abs(rel[:, 1] / rel[:, 0]) <= fx + 1e-9).all() and (np.abs(rel[:, 2] / rel[:, 0]) <= fy + 1e-9).all()
    # The camera stands on the robot's side of the furniture, above the robot region.
    assert pose[0, 3] < spec.camera_target.center[0] and pose[2, 3] > spec.robot_region.z_range[1]


@pytest.mark.parametrize("name", list(scene_types()))
def test_glb_export_loads_back_with_every_part(name, tmp_path):
    spec = generate(name, 1)
    path = export_scene(spec, tmp_path / f"{name}.glb")
    loaded = trimesh.load(path)
    assert isinstance(loaded, trimesh.Scene)
    assert sorted(loaded.geometry) == sorted(p.name for p in spec.parts)
    np.testing.assert_allclose(loaded.bounds, scene_extent(spec), atol=2e-3)
    # Part colours survive (as vertex colours).
    part = spec.parts[0]
    colors = loaded.geometry[part.name].visual.vertex_colors
    np.testing.assert_allclose(colors[0] / 255, part.material.rgba, atol=1 / 255)


def test_export_cli_obj_and_surfaces(tmp_path):
    spec = reference_shelf()
    obj = export_scene(spec, tmp_path / "shelf.obj")
    text = obj.read_text()
    assert text.count("\no ") == len(spec.parts)
    mesh = trimesh.load(obj, force="mesh")
    np.testing.assert_allclose(mesh.bounds, scene_extent(spec), atol=1e-6)
    with_surfaces = scene_to_trimesh(spec, with_surfaces=True)
    assert len(with_surfaces.geometry) == len(spec.parts) + len(spec.support_surfaces)
    name = _types()[0]
    out = tmp_path / "cli.glb"
    assert cli.main(["scenes", "export", name, "--seed", "0", "--out", str(out), "--with-surfaces"]) == 0
    s = generate(name, 0)
    assert len(trimesh.load(out).geometry) == len(s.parts) + len(s.support_surfaces)


def test_gallery_writes_pictures_page_and_statistics(tmp_path, capsys):
    import json

    out = tmp_path / "demo"
    assert cli.main(["scenes", "gallery", "--out", str(out), "--stat-seeds", "1", "--size", "64x48"]) == 0
    names = _types()
    pictures = sorted(p.stem for p in (out / "gallery").glob("*.png"))
    assert pictures == sorted(names)
    assert Image.open(out / "gallery" / f"{names[0]}.png").size == (64, 48)
    stats = json.loads((out / "scene_stats.json").read_text())
    assert [s["scene_type"] for s in stats] == names
    page = (out / "scenes.md").read_text()
    for name in names:
        assert f"![{name}, seed 0](gallery/{name}.png)" in page
    printed = capsys.readouterr().out
    assert f"total ({len(names)} types)" in printed


def test_a_maniskill_env_can_still_render_after_a_scene_picture():
    # SAPIEN renders on one device per process. A picture's scene is kept alive (see
    # render.py), so it must sit on the device ManiSkill's default backend asks for, or
    # every env made later in the process fails to create its renderer. Run in a fresh
    # process: the test session itself holds a renderer (conftest.py).
    import subprocess
    import sys

    code = (
        "import sapien\n"
        "from mani_skill.envs.utils.system.backend import parse_sim_and_render_backend\n"
        "from fetchbench_ms.scenes import generate, scene_types\n"
        "from fetchbench_ms.scenes.render import render_scene\n"
        "render_scene(generate(next(iter(scene_types())), 0), 32, 24)\n"
        "device = parse_sim_and_render_backend('physx_cpu', 'gpu').render_device\n"
        "sapien.render.RenderSystem(device)\n"
        "print('ok')\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip().endswith("ok"), run.stderr[-2000:]
