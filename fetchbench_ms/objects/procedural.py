"""Procedural household objects built from convex pieces.

Each category declares its shape parameters (``ParamSpec``: range, unit, meaning, sized
after real objects) and a pure function from parameter values to convex parts, built
z-up with the object standing as it would on a table. An object is named
``procedural/<category>/<index>``; its parameters are drawn from a generator seeded by
a hash of that name, so the same name always regenerates the same bytes and nothing
but the name (and this code's version) needs storing.

A draw that breaks a fetchability limit (too big, too heavy, nothing narrow enough
for the hand) is redrawn from the same generator, so the object stays a pure function
of its name.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh

from ..scenes.params import ParamSpec, sample_params
from ..utils.io import sha256_bytes
from . import geometry as g

#: Bump when any generator changes the geometry it makes: the catalog index records
#: it, and an index built by another version is refused as stale.
GENERATOR_VERSION = 1

_MAX_DRAWS = 64


@dataclass(frozen=True)
class Category:
    name: str
    params: tuple[ParamSpec, ...]
    build: Callable[[dict], list[trimesh.Trimesh]]  # pure: parameter values -> convex parts
    colors: tuple[tuple[float, float, float], ...]  # plausible base colours (rgb 0-1)
    description: str


def P(name, low, high, doc, unit="m", kind="float"):
    return ParamSpec(name, low, high, unit, doc, kind)


# ----------------------------------------------------------------------------- builders


def _bottle(p):
    r, h = p["body_radius"], p["body_height"]
    neck_r = p["neck_radius"]
    z_sh = h + p["shoulder_height"]
    z_neck = z_sh + p["neck_height"]
    profile = [(0.0, r * 0.92), (0.006, r), (h, r), (z_sh, neck_r), (z_neck, neck_r)]
    parts = g.stacked_profile(profile, n=24, squash=p["squash"])
    parts.append(g.frustum(neck_r + 0.002, neck_r + 0.002, z_neck, z_neck + p["cap_height"], n=20))
    return parts


def _can(p):
    r, h, b = p["radius"], p["height"], p["bevel"]
    return [g.hull(np.concatenate([
        g.ellipse_points(r - b, r - b, 0.0, 32), g.ellipse_points(r, r, b, 32),
        g.ellipse_points(r, r, h - b, 32), g.ellipse_points(r - b, r - b, h, 32),
    ]))]


def _jar(p):
    r, h = p["radius"], p["body_height"]
    neck_r = r - p["shoulder_inset"]
    parts = g.stacked_profile([(0.0, r - 0.002), (0.004, r), (h, r), (h + 0.008, neck_r)], n=28)
    lid_r = neck_r + p["lid_overhang"]
    parts.append(g.frustum(lid_r, lid_r, h + 0.008, h + 0.008 + p["lid_height"], n=28))
    return parts


def _cup_shell(r_bottom, r_top, height, wall, base, sectors):
    rings = [(base, r_bottom), (0.5 * (base + height), 0.5 * (r_bottom + r_top)), (height, r_top)]
    parts = g.shell_of_revolution(rings, wall, sectors)
    parts.append(g.frustum(r_bottom - 0.001, r_bottom, 0.0, base, n=24))
    return parts


def _mug(p):
    r, h, wall = p["radius"], p["height"], p["wall"]
    parts = _cup_shell(r, r, h, wall, p["base"], sectors=12)
    # Handle: a half-ring in the xz plane on the +x side, swept as a tube.
    span = p["handle_span"] * h
    zc = 0.5 * h + p["handle_offset"] * h
    reach = p["handle_reach"]
    angles = np.linspace(-np.pi / 2, np.pi / 2, 7)
    path = np.stack([r - wall / 2 + reach * np.cos(angles), np.zeros_like(angles), zc + 0.5 * span * np.sin(angles)], axis=1)
    parts += g.swept_tube(path, [p["handle_thickness"]] * len(path), n=10, squash=1.6, up=(0.0, 1.0, 0.0))
    return parts


def _cup(p):
    r_top = p["top_radius"]
    return _cup_shell(r_top * p["taper"], r_top, p["height"], p["wall"], p["base"], sectors=12)


def _bowl(p):
    R, depth, wall = p["rim_radius"], p["depth"], p["wall"]
    foot_r = R * p["foot_share"]
    # Outer profile: from the foot ring up to the rim along a superellipse-like curve.
    t = np.linspace(0.0, 1.0, 5)
    radii = foot_r + (R - foot_r) * np.sin(t * np.pi / 2) ** p["roundness"]
    zs = p["foot_height"] + (depth - p["foot_height"]) * t
    parts = g.shell_of_revolution(list(zip(zs, radii)), wall, sectors=10)
    parts.append(g.frustum(foot_r, foot_r + 0.002, 0.0, p["foot_height"] + 0.002, n=24))
    return parts


def _plate(p):
    R, rim_h, wall = p["radius"], p["rim_height"], p["thickness"]
    inner = R * p["well_share"]
    parts = [g.frustum(inner - 0.004, inner, 0.0, wall, n=32)]
    parts += g.shell_of_revolution([(0.0, inner + wall * 0.2), (rim_h * 0.6, 0.5 * (inner + R) + 0.003), (rim_h, R)], wall, sectors=14)
    return parts


def _box(p):
    return [g.rounded_box((p["length"], p["width"], p["height"]), p["corner"], center=(0.0, 0.0, p["height"] / 2))]


def _food_bag(p):
    w, h, t = p["width"], p["length"], p["thickness"]
    seal = p["seal"]
    xs, ys = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(-1, 1, 9))
    bulge = (np.clip(1 - np.abs(xs) ** 4, 0, 1) * np.clip(1 - np.abs(ys) ** 3, 0, 1)) ** 0.5
    pts = []
    for sign in (1.0, -1.0):
        pts.append(np.stack([xs.ravel() * w / 2, ys.ravel() * (h / 2 - seal), sign * np.maximum(bulge.ravel() * t / 2, 0.0015)], axis=1))
    body = g.hull(np.concatenate(pts))
    seals = [g.box((w, seal, 0.003), (0.0, s * (h / 2 - seal / 2), 0.0)) for s in (1.0, -1.0)]
    return [body, *seals]  # lying on its wide face: thickness along z


def _handle(length, width, thickness, x0):
    return g.rounded_box((length, width, thickness), min(width, thickness) * 0.45, center=(x0 + length / 2, 0.0, thickness / 2))


def _fork(p):
    L, w, t = p["handle_length"], p["handle_width"], p["thickness"]
    parts = [_handle(L, w, t, 0.0)]
    head_w, neck = p["head_width"], p["neck_length"]
    parts.append(g.hull(np.concatenate([
        g.box((0.001, w * 0.5, t), (L, 0.0, t / 2)).vertices,
        g.box((0.001, head_w, t), (L + neck, 0.0, t / 2)).vertices,
    ])))
    n = int(p["tines"])
    tine_w = (head_w - 0.002 * (n - 1)) / n
    for i in range(n):
        y = -head_w / 2 + tine_w / 2 + i * (tine_w + 0.002)
        parts.append(g.box((p["tine_length"], tine_w, t * 0.8), (L + neck + p["tine_length"] / 2, y, t * 0.4)))
    return parts


def _spoon(p):
    L, w, t = p["handle_length"], p["handle_width"], p["thickness"]
    a, b, c = p["bowl_length"] / 2, p["bowl_width"] / 2, p["bowl_depth"] / 2
    return [
        _handle(L, w, t, 0.0),
        g.hull(np.concatenate([g.box((0.001, w * 0.6, t), (L, 0.0, t / 2)).vertices, g.box((0.001, w * 0.6, t), (L + 0.012, 0.0, c)).vertices])),
        g.ellipsoid((a, b, c), center=(L + 0.012 + a, 0.0, c), subdivisions=2),
    ]


def _knife(p):
    L, w, t = p["handle_length"], p["handle_width"], p["handle_thickness"]
    bl, bw, bt = p["blade_length"], p["blade_width"], p["blade_thickness"]
    x = np.linspace(0.0, 1.0, 8)
    top = np.full_like(x, bw / 2) - (x ** 3) * bw * 0.9
    profile = np.concatenate([
        np.stack([L + x * bl, top, np.zeros_like(x)], axis=1),
        np.stack([L + x * bl, np.full_like(x, -bw / 2) + (x ** 1.5) * bw * 0.1, np.zeros_like(x)], axis=1),
    ])
    blade = g.hull(np.concatenate([profile + [0, 0, t / 2 - bt / 2], profile + [0, 0, t / 2 + bt / 2]]))
    return [_handle(L, w, t, 0.0), blade]


def _tube(p):
    L, r = p["length"], p["radius"]
    flat_w = np.pi * r * p["crimp_spread"]
    cap_h = p["cap_length"]
    round_end = g.ellipse_points(r, r, 0.0, 20)
    crimp = np.array([[-flat_w / 2, -0.0015, L], [flat_w / 2, -0.0015, L], [-flat_w / 2, 0.0015, L], [flat_w / 2, 0.0015, L]])
    body = g.hull(np.concatenate([round_end, crimp]))
    cap = g.frustum(p["cap_radius"], p["cap_radius"] * 0.9, -cap_h, 0.0, n=16)
    # Lying on the table along x.
    turn = g.rotation_y(np.pi / 2)
    return [g.transformed(body, turn), g.transformed(cap, turn)]


def _ball(p):
    return [g.ellipsoid((p["radius"],) * 3, center=(0.0, 0.0, p["radius"]), subdivisions=2)]


def _block(p):
    a, b, c = p["size_x"], p["size_y"], p["size_z"]
    shape = int(p["shape"])
    if shape == 0:
        return [g.box((a, b, c), (0.0, 0.0, c / 2))]
    if shape == 1:
        return [g.frustum(a / 2, a / 2, 0.0, c, n=24)]
    if shape == 2:  # triangular prism lying on a rectangular face
        tri = np.array([[-a / 2, 0.0], [a / 2, 0.0], [0.0, c]])
        return [g.hull(np.concatenate([np.c_[tri[:, 0], np.full(3, -b / 2), tri[:, 1]], np.c_[tri[:, 0], np.full(3, b / 2), tri[:, 1]]]))]
    # arch: two legs and a lintel
    leg = a * 0.3
    return [
        g.box((leg, b, c * 0.6), (-a / 2 + leg / 2, 0.0, c * 0.3)),
        g.box((leg, b, c * 0.6), (a / 2 - leg / 2, 0.0, c * 0.3)),
        g.box((a, b, c * 0.4), (0.0, 0.0, c * 0.8)),
    ]


def _book(p):
    w, h, t = p["width"], p["height"], p["thickness"]
    cover = p["cover"]
    inset = 0.003
    pages = g.box((w - inset, h - 2 * inset, t - 2 * cover), (inset / 2, 0.0, t / 2))
    covers = [g.box((w, h, cover), (0.0, 0.0, z)) for z in (cover / 2, t - cover / 2)]
    spine = g.box((cover, h, t - 2 * cover), (-w / 2 + cover / 2, 0.0, t / 2))
    return [pages, *covers, spine]


def _remote(p):
    L, w, t = p["length"], p["width"], p["thickness"]
    body = g.rounded_box((L, w, t), min(w, t) * 0.35, center=(0.0, 0.0, t / 2))
    pad = g.frustum(w * 0.22, w * 0.2, t, t + 0.003, n=16)
    return [body, g.transformed(pad, trimesh.transformations.translation_matrix([L * 0.25, 0.0, 0.0]))]


def _spray_bottle(p):
    r, h, sq = p["body_radius"], p["body_height"], p["squash"]
    parts = g.stacked_profile([(0.0, r * 0.95), (0.005, r), (h, r), (h + 0.015, r * 0.55)], n=24, squash=sq)
    neck_top = h + 0.015 + p["neck_height"]
    parts.append(g.frustum(r * 0.45, r * 0.45, h + 0.015, neck_top, n=16))
    head_l, head_h = p["head_length"], p["head_height"]
    parts.append(g.box((head_l, r * 0.6, head_h), (head_l / 2 - r * 0.4, 0.0, neck_top + head_h / 2)))
    parts.append(g.box((0.008, r * 0.35, p["trigger_length"]), (r * 0.55, 0.0, neck_top - p["trigger_length"] / 2 + 0.004)))
    return parts


def _fruit(p):
    r = p["radius"]
    kind = int(p["kind"])
    if kind == 0:  # apple / orange / peach: a slightly squashed sphere
        body = [g.ellipsoid((r, r, r * p["elongation"] * 0.9), center=(0.0, 0.0, r * p["elongation"] * 0.9))]
        top = r * p["elongation"] * 1.8
    elif kind == 1:  # lemon: elongated with pointed ends, lying on its side
        e = p["elongation"] * 1.2
        ell = g.ellipsoid((r * e, r, r * 0.95), subdivisions=2)
        tips = np.array([[r * e + 0.006, 0.0, 0.0], [-r * e - 0.006, 0.0, 0.0]])
        body = [g.transformed(g.hull(np.concatenate([ell.vertices, tips])), trimesh.transformations.translation_matrix([0, 0, r * 0.95]))]
        return body
    else:  # pear: hull of a big and a small sphere
        big = g.ellipsoid((r, r, r), center=(0.0, 0.0, r))
        small = g.ellipsoid((r * 0.6,) * 3, center=(0.0, 0.0, r + r * p["elongation"]))
        body = [g.hull(np.concatenate([big.vertices, small.vertices]))]
        top = r + r * p["elongation"] + r * 0.6
    stem = g.frustum(0.002, 0.0015, top - 0.002, top + p["stem_length"], n=8)
    return body + [stem]


def _banana(p):
    L, r, bend = p["length"], p["radius"], p["bend"]
    n = 7
    angles = np.linspace(-bend / 2, bend / 2, n)
    R = L / bend
    path = np.stack([R * np.sin(angles), R * (1 - np.cos(angles)), np.zeros(n)], axis=1)
    radii = r * np.sin(np.linspace(0.15, np.pi - 0.15, n)) ** 0.5
    radii = np.maximum(radii, 0.004)
    parts = g.swept_tube(path, radii, n=10, squash=0.85, up=(0.0, 0.0, 1.0))
    return [g.transformed(m, trimesh.transformations.translation_matrix([0.0, 0.0, r])) for m in parts]


def _marker(p):
    r, L, cap = p["radius"], p["length"], p["cap_length"]
    barrel = g.frustum(r, r, 0.0, L, n=16)
    tip = g.frustum(r * 0.8, r * 0.3, L, L + p["tip_length"], n=12)
    capm = g.frustum(r + 0.0012, r + 0.0012, L - cap + p["tip_length"] + 0.004, L + p["tip_length"] + 0.004, n=16)
    parts = [barrel, tip, capm] if p["capped"] >= 0.5 else [barrel, tip]
    turn = g.rotation_y(np.pi / 2)  # lying on the table
    return [g.transformed(m, turn) for m in parts]


def _screwdriver(p):
    hr, hl, sr, sl = p["handle_radius"], p["handle_length"], p["shaft_radius"], p["shaft_length"]
    handle = g.stacked_profile([(0.0, hr * 0.8), (0.008, hr), (hl * 0.8, hr), (hl, hr * 0.6)], n=8)
    shaft = g.frustum(sr, sr, hl, hl + sl, n=10)
    tip = g.hull(np.concatenate([g.ellipse_points(sr, sr, hl + sl, 10), [[-sr * 1.1, -0.0006, hl + sl + 0.008], [sr * 1.1, -0.0006, hl + sl + 0.008], [-sr * 1.1, 0.0006, hl + sl + 0.008], [sr * 1.1, 0.0006, hl + sl + 0.008]]]))
    turn = g.rotation_y(np.pi / 2)
    return [g.transformed(m, turn) for m in [*handle, shaft, tip]]


def _hammer(p):
    L, hw, ht = p["handle_length"], p["handle_width"], p["handle_thickness"]
    head_l, head_s = p["head_length"], p["head_size"]
    handle = g.rounded_box((L, hw, ht), min(hw, ht) * 0.4, center=(L / 2, 0.0, head_s / 2))
    face = g.frustum(head_s / 2, head_s / 2, 0.0, head_l * 0.55, n=12)
    face = g.transformed(face, trimesh.transformations.translation_matrix([L + head_s / 2, 0.0, 0.0]) @ g.rotation_x(-np.pi / 2))
    face = g.transformed(face, trimesh.transformations.translation_matrix([0.0, 0.0, head_s / 2]))
    claw = g.hull(np.concatenate([
        g.box((head_s, 0.001, head_s), (L + head_s / 2, 0.0, head_s / 2)).vertices,
        g.box((head_s * 0.5, 0.001, head_s * 0.4), (L + head_s * 0.4, -head_l * 0.45, head_s * 0.3)).vertices,
    ]))
    return [handle, face, claw]


def _soap_bar(p):
    L, w, t = p["length"], p["width"], p["thickness"]
    return [g.rounded_box((L, w, t), min(w, t) * p["roundness"], center=(0.0, 0.0, t / 2))]


def _sponge(p):
    L, w, t = p["length"], p["width"], p["thickness"]
    scrub = t * p["scrub_share"]
    return [
        g.rounded_box((L, w, t - scrub), 0.004, center=(0.0, 0.0, (t - scrub) / 2)),
        g.box((L * 0.98, w * 0.98, scrub), (0.0, 0.0, t - scrub / 2)),
    ]


def _toy_car(p):
    L, w, h = p["length"], p["width"], p["body_height"]
    wr = p["wheel_radius"]
    wt = max(w * 0.18, 0.004)
    body_z = wr * 0.9
    body = g.rounded_box((L, w - 2 * wt, h), min(w, h) * 0.2, center=(0.0, 0.0, body_z + h / 2))
    cabin = g.hull(np.concatenate([
        g.box((L * 0.55, w * 0.6, 0.001), (-L * 0.05, 0.0, body_z + h)).vertices,
        g.box((L * 0.3, w * 0.5, 0.001), (-L * 0.08, 0.0, body_z + h + p["cabin_height"])).vertices,
    ]))
    wheels = []
    for x in (-L * 0.32, L * 0.32):
        for y in (-(w / 2 - wt / 2), w / 2 - wt / 2):
            wheel = g.frustum(wr, wr, -wt / 2, wt / 2, n=14)
            wheels.append(g.transformed(wheel, trimesh.transformations.translation_matrix([x, y, wr]) @ g.rotation_x(np.pi / 2)))
    return [body, cabin, *wheels]


def _phone(p):
    L, w, t = p["length"], p["width"], p["thickness"]
    return [g.rounded_box((L, w, t), min(p["corner"], t * 0.45), center=(0.0, 0.0, t / 2))]


def _computer_mouse(p):
    L, w, h = p["length"], p["width"], p["height"]
    shell = g.ellipsoid((L / 2, w / 2, h), subdivisions=2)
    pts = shell.vertices[shell.vertices[:, 2] >= 0.0]
    ring = g.ellipse_points(L / 2, w / 2, 0.0, 24)
    return [g.hull(np.concatenate([pts, ring]))]


def _flashlight(p):
    r, L = p["body_radius"], p["body_length"]
    head_r, head_l = p["head_radius"], p["head_length"]
    parts = g.stacked_profile([(0.0, r * 0.9), (0.004, r), (L, r), (L + head_l * 0.4, head_r), (L + head_l, head_r)], n=16)
    turn = g.rotation_y(np.pi / 2)
    return [g.transformed(m, turn) for m in parts]


def _pill_bottle(p):  # small cylinder with a slightly wider cap
    r, h = p["radius"], p["height"]
    return [g.frustum(r, r, 0.0, h, n=20), g.frustum(r + 0.0015, r + 0.0015, h, h + p["cap_height"], n=20)]


# ----------------------------------------------------------------------------- registry

_PALETTE_BRIGHT = ((0.85, 0.2, 0.2), (0.2, 0.5, 0.85), (0.95, 0.75, 0.15), (0.25, 0.7, 0.35), (0.6, 0.3, 0.7), (0.95, 0.5, 0.15))
_PALETTE_CERAMIC = ((0.95, 0.95, 0.92), (0.3, 0.45, 0.7), (0.75, 0.3, 0.25), (0.35, 0.35, 0.38), (0.9, 0.85, 0.6))
_PALETTE_METAL = ((0.75, 0.75, 0.78), (0.6, 0.6, 0.62), (0.85, 0.8, 0.65))
_PALETTE_PAPER = ((0.85, 0.2, 0.15), (0.15, 0.3, 0.6), (0.9, 0.8, 0.55), (0.2, 0.55, 0.3), (0.95, 0.95, 0.95))
_PALETTE_DARK = ((0.1, 0.1, 0.1), (0.25, 0.25, 0.28), (0.6, 0.6, 0.62), (0.85, 0.85, 0.85))

CATEGORIES: dict[str, Category] = {}


def _register(name, params, build, colors, description):
    CATEGORIES[name] = Category(name, tuple(params), build, colors, description)


_register("bottle", [
    P("body_radius", 0.022, 0.034, "radius of the body"), P("body_height", 0.08, 0.16, "height of the straight body"),
    P("shoulder_height", 0.015, 0.04, "height of the shoulder cone"), P("neck_radius", 0.01, 0.015, "radius of the neck"),
    P("neck_height", 0.01, 0.03, "height of the neck"), P("cap_height", 0.01, 0.02, "height of the cap"),
    P("squash", 0.65, 1.0, "depth over width of the body cross-section", unit="1"),
], _bottle, _PALETTE_BRIGHT, "water / soda / sauce bottle")
_register("can", [
    P("radius", 0.025, 0.034, "radius"), P("height", 0.05, 0.14, "height"), P("bevel", 0.002, 0.006, "rim bevel"),
], _can, _PALETTE_METAL + _PALETTE_BRIGHT, "drink or food can")
_register("jar", [
    P("radius", 0.025, 0.034, "body radius"), P("body_height", 0.05, 0.12, "body height"),
    P("shoulder_inset", 0.001, 0.006, "how much narrower the mouth is than the body"),
    P("lid_overhang", 0.0, 0.002, "lid radius beyond the mouth"), P("lid_height", 0.01, 0.02, "lid height"),
], _jar, _PALETTE_BRIGHT + _PALETTE_METAL, "jar with a screw lid")
_register("mug", [
    P("radius", 0.03, 0.045, "outer radius"), P("height", 0.07, 0.11, "height"), P("wall", 0.004, 0.007, "wall thickness"),
    P("base", 0.005, 0.01, "base thickness"), P("handle_span", 0.45, 0.7, "handle height over mug height", unit="1"),
    P("handle_offset", -0.05, 0.08, "handle centre above mid-height over mug height", unit="1"),
    P("handle_reach", 0.018, 0.032, "how far the handle sticks out"), P("handle_thickness", 0.004, 0.0065, "handle tube radius"),
], _mug, _PALETTE_CERAMIC, "mug with a handle")
_register("cup", [
    P("top_radius", 0.03, 0.045, "rim radius"), P("taper", 0.6, 0.9, "bottom over rim radius", unit="1"),
    P("height", 0.06, 0.13, "height"), P("wall", 0.003, 0.005, "wall thickness"), P("base", 0.004, 0.008, "base thickness"),
], _cup, _PALETTE_BRIGHT + _PALETTE_CERAMIC, "paper / plastic cup or tumbler")
_register("bowl", [
    P("rim_radius", 0.05, 0.09, "rim radius"), P("depth", 0.04, 0.08, "height"), P("wall", 0.004, 0.007, "wall thickness"),
    P("foot_share", 0.4, 0.6, "foot radius over rim radius", unit="1"), P("foot_height", 0.004, 0.01, "foot height"),
    P("roundness", 0.6, 1.2, "profile exponent (low: steep sides)", unit="1"),
], _bowl, _PALETTE_CERAMIC, "bowl")
_register("plate", [
    P("radius", 0.07, 0.12, "radius"), P("rim_height", 0.014, 0.03, "height of the rim"),
    P("thickness", 0.004, 0.007, "thickness"), P("well_share", 0.55, 0.75, "flat well radius over radius", unit="1"),
], _plate, _PALETTE_CERAMIC, "plate or saucer")
_register("box", [
    P("length", 0.06, 0.22, "length"), P("width", 0.03, 0.07, "width (the hand closes across it)"),
    P("height", 0.04, 0.22, "height"), P("corner", 0.001, 0.006, "corner rounding"),
], _box, _PALETTE_PAPER, "carton / packaged-food box")
_register("food_bag", [
    P("width", 0.08, 0.18, "width"), P("length", 0.1, 0.24, "length"), P("thickness", 0.02, 0.06, "filled thickness"),
    P("seal", 0.008, 0.015, "width of the crimped seals"),
], _food_bag, _PALETTE_BRIGHT, "chips / snack bag lying flat")
_register("fork", [
    P("handle_length", 0.08, 0.12, "handle length"), P("handle_width", 0.012, 0.02, "handle width"),
    P("thickness", 0.004, 0.006, "handle thickness"), P("neck_length", 0.015, 0.025, "neck length"),
    P("head_width", 0.02, 0.028, "width of the tines"), P("tine_length", 0.03, 0.045, "tine length"),
    P("tines", 3, 4, "number of tines", unit="count", kind="int"),
], _fork, _PALETTE_METAL, "fork")
_register("spoon", [
    P("handle_length", 0.08, 0.12, "handle length"), P("handle_width", 0.01, 0.018, "handle width"),
    P("thickness", 0.004, 0.006, "handle thickness"), P("bowl_length", 0.035, 0.06, "bowl length"),
    P("bowl_width", 0.025, 0.042, "bowl width"), P("bowl_depth", 0.008, 0.014, "bowl depth"),
], _spoon, _PALETTE_METAL, "spoon")
_register("knife", [
    P("handle_length", 0.08, 0.11, "handle length"), P("handle_width", 0.014, 0.022, "handle width"),
    P("handle_thickness", 0.008, 0.014, "handle thickness"), P("blade_length", 0.07, 0.11, "blade length"),
    P("blade_width", 0.016, 0.026, "blade width"), P("blade_thickness", 0.0025, 0.0035, "blade thickness"),
], _knife, _PALETTE_METAL + _PALETTE_DARK, "table or kitchen knife")
_register("tube", [
    P("length", 0.09, 0.17, "length without cap"), P("radius", 0.012, 0.02, "radius at the round end"),
    P("crimp_spread", 0.9, 1.1, "crimped end width over half the circumference", unit="1"),
    P("cap_length", 0.01, 0.02, "cap length"), P("cap_radius", 0.007, 0.012, "cap radius"),
], _tube, _PALETTE_BRIGHT, "toothpaste / cream tube")
_register("ball", [P("radius", 0.02, 0.034, "radius")], _ball, _PALETTE_BRIGHT, "toy / sports ball")
_register("block", [
    P("size_x", 0.025, 0.07, "size along x"), P("size_y", 0.025, 0.065, "size along y"), P("size_z", 0.025, 0.07, "height"),
    P("shape", 0, 3, "0 cuboid, 1 cylinder, 2 prism, 3 arch", unit="count", kind="int"),
], _block, _PALETTE_BRIGHT, "toy / wooden block")
_register("book", [
    P("width", 0.1, 0.16, "width"), P("height", 0.14, 0.22, "height"), P("thickness", 0.012, 0.05, "thickness"),
    P("cover", 0.004, 0.005, "cover board thickness"),
], _book, _PALETTE_PAPER, "book lying flat")
_register("remote", [
    P("length", 0.12, 0.2, "length"), P("width", 0.035, 0.055, "width"), P("thickness", 0.015, 0.025, "thickness"),
], _remote, _PALETTE_DARK, "remote control")
_register("spray_bottle", [
    P("body_radius", 0.025, 0.034, "body radius"), P("squash", 0.55, 0.9, "depth over width", unit="1"),
    P("body_height", 0.09, 0.15, "body height"), P("neck_height", 0.01, 0.02, "neck height"),
    P("head_length", 0.04, 0.06, "trigger head length"), P("head_height", 0.02, 0.03, "trigger head height"),
    P("trigger_length", 0.015, 0.025, "trigger length"),
], _spray_bottle, _PALETTE_BRIGHT, "spray / cleaner bottle")
_register("fruit", [
    P("radius", 0.022, 0.034, "radius"), P("elongation", 0.95, 1.3, "height over width", unit="1"),
    P("stem_length", 0.004, 0.012, "stem length"), P("kind", 0, 2, "0 round (apple, orange), 1 lemon, 2 pear", unit="count", kind="int"),
], _fruit, ((0.8, 0.15, 0.1), (0.95, 0.55, 0.1), (0.95, 0.85, 0.2), (0.55, 0.75, 0.2)), "fruit")
_register("banana", [
    P("length", 0.14, 0.2, "length along the curve"), P("radius", 0.014, 0.019, "radius"), P("bend", 0.6, 1.2, "arc angle", unit="rad"),
], _banana, ((0.95, 0.85, 0.2), (0.85, 0.8, 0.3)), "banana")
_register("marker", [
    P("radius", 0.006, 0.011, "barrel radius"), P("length", 0.09, 0.13, "barrel length"),
    P("cap_length", 0.025, 0.045, "cap length"), P("tip_length", 0.006, 0.012, "tip length"),
    P("capped", 0.0, 1.0, "above 0.5: cap on", unit="1"),
], _marker, _PALETTE_BRIGHT + _PALETTE_DARK, "marker or pen")
_register("screwdriver", [
    P("handle_radius", 0.011, 0.018, "handle radius"), P("handle_length", 0.07, 0.1, "handle length"),
    P("shaft_radius", 0.0025, 0.0035, "shaft radius"), P("shaft_length", 0.05, 0.12, "shaft length"),
], _screwdriver, _PALETTE_BRIGHT, "screwdriver")
_register("hammer", [
    P("handle_length", 0.16, 0.21, "handle length"), P("handle_width", 0.022, 0.03, "handle width"),
    P("handle_thickness", 0.014, 0.02, "handle thickness"), P("head_length", 0.07, 0.1, "head length"),
    P("head_size", 0.018, 0.026, "head cross-section"),
], _hammer, _PALETTE_DARK + _PALETTE_METAL, "small hammer")
_register("soap_bar", [
    P("length", 0.06, 0.1, "length"), P("width", 0.04, 0.06, "width"), P("thickness", 0.02, 0.035, "thickness"),
    P("roundness", 0.2, 0.45, "corner radius over the smaller side", unit="1"),
], _soap_bar, _PALETTE_CERAMIC, "bar of soap")
_register("sponge", [
    P("length", 0.07, 0.12, "length"), P("width", 0.045, 0.07, "width"), P("thickness", 0.02, 0.045, "thickness"),
    P("scrub_share", 0.15, 0.3, "scrub layer share of thickness", unit="1"),
], _sponge, ((0.95, 0.85, 0.2), (0.3, 0.7, 0.4), (0.9, 0.5, 0.6)), "kitchen sponge")
_register("toy_car", [
    P("length", 0.07, 0.15, "length"), P("width", 0.035, 0.065, "width"), P("body_height", 0.015, 0.03, "body height"),
    P("cabin_height", 0.01, 0.025, "cabin height"), P("wheel_radius", 0.007, 0.013, "wheel radius"),
], _toy_car, _PALETTE_BRIGHT, "toy car")
_register("phone", [
    P("length", 0.12, 0.17, "length"), P("width", 0.058, 0.08, "width"), P("thickness", 0.007, 0.012, "thickness"),
    P("corner", 0.003, 0.01, "corner rounding"),
], _phone, _PALETTE_DARK, "mobile phone")
_register("computer_mouse", [
    P("length", 0.09, 0.125, "length"), P("width", 0.055, 0.07, "width"), P("height", 0.03, 0.045, "height"),
], _computer_mouse, _PALETTE_DARK, "computer mouse")
_register("flashlight", [
    P("body_radius", 0.01, 0.018, "body radius"), P("body_length", 0.08, 0.16, "body length"),
    P("head_radius", 0.014, 0.026, "head radius"), P("head_length", 0.02, 0.04, "head length"),
], _flashlight, _PALETTE_DARK + _PALETTE_BRIGHT, "flashlight / torch")
_register("pill_bottle", [
    P("radius", 0.014, 0.026, "radius"), P("height", 0.05, 0.1, "height"), P("cap_height", 0.01, 0.018, "cap height"),
], _pill_bottle, ((0.9, 0.55, 0.15), (0.95, 0.95, 0.95), (0.3, 0.5, 0.8)), "pill / spice bottle")


# ----------------------------------------------------------------------------- objects


@dataclass(frozen=True)
class ProceduralObject:
    category: str
    index: int
    params: dict
    parts: tuple[trimesh.Trimesh, ...]  # built frame (z-up, resting on z = 0 where natural)
    rgb: tuple[float, float, float]
    draws: int  # how many parameter draws it took to satisfy the limits


def object_seed(object_id: str) -> int:
    """Seed of a procedural object: 64 bits of the hash of its id (stable across runs)."""
    return int(sha256_bytes(object_id.encode("utf-8"))[:16], 16)


def procedural_id(category: str, index: int) -> str:
    return f"procedural/{category}/{index:04d}"


def get_category(name: str) -> Category:
    if name not in CATEGORIES:
        raise ValueError(f"unknown procedural category {name!r}; valid: {', '.join(sorted(CATEGORIES))}")
    return CATEGORIES[name]


def generate(category: str, index: int) -> ProceduralObject:
    """Regenerate procedural object ``index`` of ``category`` (pure function of both)."""
    cat = get_category(category)
    if index < 0:
        raise ValueError(f"procedural object index must be >= 0, got {index}")
    rng = np.random.default_rng(object_seed(procedural_id(category, index)))
    problems: list[str] = []
    for draw in range(1, _MAX_DRAWS + 1):
        params = sample_params(cat.params, rng, owner=f"procedural category {category!r}")
        rgb_choice = int(rng.integers(len(cat.colors)))
        parts = cat.build(params)
        problems = object_problems(parts, topology=False)
        if not problems:
            return ProceduralObject(category, index, params, tuple(parts), cat.colors[rgb_choice], draw)
    raise RuntimeError(f"procedural {category} #{index}: no valid draw in {_MAX_DRAWS} tries; last: {problems}")


def object_problems(parts, topology: bool = True) -> list[str]:
    """Every reason these parts are not a valid fetchable object (empty when valid).
    ``topology=False``: parts come from ``geometry.hull`` (convex, watertight)."""
    out = []
    for i, part in enumerate(parts):
        out += [f"part {i}: {p}" for p in g.check_part(part, topology=topology).problems()]
    if out:
        return out
    points = np.concatenate([p.vertices for p in parts])
    extents = points.max(axis=0) - points.min(axis=0)
    volume, _ = g.mass_properties(parts)
    return g.limit_problems(extents, volume, g.grasp_width(parts), len(parts))
