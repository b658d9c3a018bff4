"""Physics settings and object bodies shared by the env and the task sampler's settle step.

One place decides the simulation rates, solver settings and how an ``ObjectAsset``
becomes a SAPIEN body, so a task settled during sampling rests the same way when the
env loads it.

Rates: physics at 120 Hz with 20 position iterations (ManiSkill's note: >= 20 for stable
grasps) and control at 20 Hz (6 physics steps per action). The original simulated at
60 Hz; 120 Hz keeps small objects (2-5 cm) from tunnelling through the fingers and lets
the PD gripper squeeze without jitter. The envs' ``sim_freq=60`` kwarg runs the original's
rate instead (``envs.options``); the sampler's settle step always runs at ``SIM_FREQ``.
"""
from __future__ import annotations

import functools
import json
import os
from dataclasses import dataclass

import numpy as np
import sapien
from mani_skill.utils.structs.types import DefaultMaterialsConfig, SceneConfig, SimConfig

from ..utils.io import atomic_write_text, sha256_bytes
from ..utils.mesh_cache import cache_dir, mesh_file

SIM_FREQ = 120  # Hz
CONTROL_FREQ = 20  # Hz


def default_sim_config() -> SimConfig:
    return SimConfig(
        sim_freq=SIM_FREQ,
        control_freq=CONTROL_FREQ,
        scene_config=SceneConfig(solver_position_iterations=20, solver_velocity_iterations=1),
        # Robot fingers, floor and anything without its own material (objects and
        # furniture set theirs): the original's scene friction.
        default_materials_config=DefaultMaterialsConfig(static_friction=0.5, dynamic_friction=0.5, restitution=0.0),
    )


def apply_physx_config(sim_config: SimConfig) -> None:
    """Set SAPIEN's global PhysX defaults as ManiSkill's BaseEnv does (before a scene is made)."""
    sc = sim_config.scene_config
    sapien.physx.set_shape_config(contact_offset=sc.contact_offset, rest_offset=sc.rest_offset)
    sapien.physx.set_body_config(
        solver_position_iterations=sc.solver_position_iterations,
        solver_velocity_iterations=sc.solver_velocity_iterations,
        sleep_threshold=sc.sleep_threshold,
    )
    sapien.physx.set_scene_config(
        gravity=np.asarray(sc.gravity, dtype=np.float32), bounce_threshold=sc.bounce_threshold, enable_pcm=sc.enable_pcm,
        enable_tgs=sc.enable_tgs, enable_ccd=sc.enable_ccd, enable_enhanced_determinism=sc.enable_enhanced_determinism,
        enable_friction_every_iteration=sc.enable_friction_every_iteration, cpu_workers=sc.cpu_workers,
    )
    sapien.physx.set_default_material(**sim_config.default_materials_config.dict())


@dataclass(frozen=True)
class ObjectFiles:
    """What SAPIEN needs to build one catalog object: its convex parts' and visual mesh's
    files (content-addressed, ``utils.mesh_cache``) and its colour."""

    parts: tuple[str, ...]
    visual: str
    rgba: tuple[float, float, float, float]


#: Objects whose file records a process keeps (a few hundred bytes each; a miss reads one
#: small JSON file): more than the 748 test objects, so an evaluation never re-reads one,
#: while a run over the 5,219 train objects stays bounded.
OBJECT_FILES_KEPT = 1024


@functools.lru_cache(maxsize=OBJECT_FILES_KEPT)
def object_files(object_id: str) -> ObjectFiles:
    """The mesh files of ``object_id``, remembered in memory and on disk (next to the
    mesh files, under the catalog's version), so building a task's objects into a scene
    neither rebuilds the catalog's geometry (20-60 ms an object) nor re-hashes meshes.
    A record whose files have gone (cache cleared) is rebuilt."""
    from ..objects.loading import load_object, object_source

    key = sha256_bytes(f"{object_source()}|{object_id}".encode())[:32]
    path = cache_dir() / "object_files" / f"{key}.json"
    if path.exists():
        try:
            d = json.loads(path.read_text())
            files = ObjectFiles(tuple(d["parts"]), d["visual"], tuple(d["rgba"]))
            if d.get("object_id") == object_id and all(map(os.path.exists, files.parts + (files.visual,))):
                return files
        except (ValueError, KeyError, TypeError):
            pass  # unreadable: rebuilt below
    asset = load_object(object_id)
    files = ObjectFiles(tuple(mesh_file(p) for p in asset.convex_parts), mesh_file(asset.visual_mesh),
                        _object_rgba(asset))
    atomic_write_text(path, json.dumps({"object_id": object_id, "parts": files.parts, "visual": files.visual,
                                        "rgba": files.rgba}))
    return files


def add_object_shapes(builder, object_id: str, placement, with_visual: bool = True) -> None:
    """Collision (one convex shape per convex part, at the task's density and material)
    and visual shapes of one object, in the object frame."""
    files = object_files(object_id)
    material = sapien.physx.PhysxMaterial(placement.static_friction, placement.dynamic_friction, placement.restitution)
    for part in files.parts:
        builder.add_convex_collision_from_file(part, material=material, density=placement.density)
    if with_visual:
        builder.add_visual_from_file(files.visual, material=_render_material(files.rgba))


def _object_rgba(asset) -> tuple:
    rgba = getattr(asset, "rgba", None)
    if rgba is None:
        digest = bytes.fromhex(sha256_bytes(asset.object_id.encode())[:6])
        rgba = tuple(0.25 + 0.6 * b / 255 for b in digest[:3]) + (1.0,)
    return tuple(float(c) for c in rgba)


#: Render materials a process keeps, by colour. Procedural and blob objects each have their
#: own colour, so unbounded this grows by about a material per object a task builds (with
#: visuals: the camera obs modes), each holding renderer memory (the GPU's, on a GPU node).
#: 256 covers many tasks' objects; an evicted one that a built scene still uses lives on with
#: that scene, and a new one of the same colour renders the same.
RENDER_MATERIALS_KEPT = 256


@functools.lru_cache(maxsize=RENDER_MATERIALS_KEPT)
def _render_material(rgba: tuple):
    # Cached: creating a RenderMaterial costs ~40 ms on a CPU (lavapipe) renderer.
    return sapien.render.RenderMaterial(base_color=list(rgba), roughness=0.6, metallic=0.0)


def box_half_size(size) -> list[float]:
    return [float(s) / 2 for s in size]
