"""Collision spheres fitted to the Panda's link collision meshes.

Why hand-written: no installed library fits a conservative sphere set to a mesh
(CuRobo, which does, is not installable). The fit is small and deterministic:
dense surface + interior samples of the link's collision geometry are split into
k clusters (k-means), each cluster gets its minimum enclosing ball (Badoiu-Clarkson
iterations) and the radius grows by ``margin``. Every sample therefore lies inside a
sphere, and every mesh point lies within the sample spacing (< margin) of a sample,
so the union of spheres contains the mesh: the model is conservative.

Fitting all links takes ~10 s (interior sampling), so the result is a generated file
in ``$FETCHBENCH_CACHE/planning`` named by the hash of everything it depends on (fit
version, margin, seed, URDF and mesh bytes): changed inputs give a new name, so a stale
file is never read, and a file whose content hash does not match fails loudly.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.cluster.vq import kmeans2

from ..utils.io import atomic_write_text, canonical_json, sha256_bytes

FIT_VERSION = "2"
DEFAULT_MARGIN = 0.004  # m added to every radius; larger than the sample spacing
SPHERE_SPACING = 0.045  # m of link extent per sphere: sets k per link
# The fingers and the hand decide whether low objects can be grasped: fat spheres there
# would touch the board under a 3 cm can. More, tighter spheres (dense samples keep the
# spacing under a millimetre, so a smaller margin stays conservative).
LINK_FIT = {  # link: (spheres, margin)
    "panda_leftfinger": (10, 0.002),
    "panda_rightfinger": (10, 0.002),
    "panda_hand": (12, 0.003),
}


@dataclass(frozen=True)
class LinkSpheres:
    """Spheres of one link in the link frame."""

    link: str
    centers_link: np.ndarray  # (k, 3)
    radii: np.ndarray  # (k,)


def minimum_enclosing_ball(points: np.ndarray, iterations: int = 300) -> tuple[np.ndarray, float]:
    """(1+eps)-approximate smallest ball around ``points`` (Badoiu-Clarkson).

    The returned radius is the exact max distance from the returned centre, so the ball
    always contains every point even where the centre is not optimal.
    """
    center = points.mean(axis=0)
    for i in range(1, iterations + 1):
        far = points[np.argmax(np.linalg.norm(points - center, axis=1))]
        center = center + (far - center) / (i + 1)
    return center, float(np.linalg.norm(points - center, axis=1).max())


# Ray directions for the inside test: the first is trimesh's default; the others are
# fixed stand-ins for the random direction trimesh draws for ambiguous points.
_RAY_DIRECTIONS = np.array([[0.4395064455, 0.617598629942, 0.652231566745],
                            [-0.5773502692, 0.2672612419, 0.7715167498],
                            [0.8017837257, -0.5345224838, 0.2672612419],
                            [0.1825741858, 0.3651483717, -0.9128709292]])


def contains(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Which ``points`` lie inside the closed ``mesh``, deterministically.

    ``trimesh.Trimesh.contains`` re-tests points whose two opposite rays disagree (a ray
    through an edge or vertex) along a direction drawn from OS entropy, so the same call
    can answer differently from run to run. Here a convex mesh is tested against its face
    planes (exact), any other by ray parity along fixed directions in turn.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    if mesh.is_convex:
        normals = mesh.face_normals
        offsets = np.einsum("ij,ij->i", normals, mesh.triangles[:, 0])
        return (points @ normals.T <= offsets[None]).all(axis=1)
    inside = np.zeros(len(points), dtype=bool)
    todo = np.flatnonzero(trimesh.bounds.contains(mesh.bounds, points))
    for direction in _RAY_DIRECTIONS:
        if len(todo) == 0:
            break
        d = np.tile(direction / np.linalg.norm(direction), (len(todo), 1))
        _, index_ray, _ = mesh.ray.intersects_location(np.vstack([points[todo], points[todo]]),
                                                       np.vstack([d, -d]), multiple_hits=True)
        hits = np.bincount(index_ray, minlength=2 * len(todo)).reshape(2, -1)
        odd = hits % 2 == 1
        agree = odd[0] == odd[1]
        inside[todo[agree]] = odd[0][agree]
        # One ray escaping with no hit: outside. Otherwise ambiguous: try the next direction.
        todo = todo[~agree & ~(hits == 0).any(axis=0)]
    return inside


def volume_samples(mesh: trimesh.Trimesh, count: int, rng: np.random.Generator) -> np.ndarray:
    """Rejection samples of the solid (at most ``count``): ``trimesh.sample.volume_mesh``
    (same draws from ``rng``) with a deterministic inside test."""
    points = rng.random((count, 3)) * mesh.extents + mesh.bounds[0]
    return points[contains(mesh, points)][:count]


def sample_link_points(mesh: trimesh.Trimesh, seed: int, surface_count: int = 8000) -> np.ndarray:
    """Mesh vertices + even surface samples + interior samples (the balls must cover the solid)."""
    rng = np.random.default_rng(seed)
    surface, _ = trimesh.sample.sample_surface(mesh, surface_count, seed=rng)
    parts = [mesh.vertices, surface]
    if mesh.is_watertight:
        parts.append(volume_samples(mesh, surface_count // 4, rng))
    return np.concatenate(parts, axis=0)


def fit_balls(points: np.ndarray, n_balls: int, margin: float, rng: np.random.Generator,
              iterations: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """``n_balls`` balls covering ``points``: k-means clusters, each with its minimum
    enclosing ball grown by ``margin``. Returns (centers (k, 3), radii (k,))."""
    n_balls = min(n_balls, len(points))
    _, labels = kmeans2(points, n_balls, iter=iterations, minit="++", rng=rng)
    centers, radii = [], []
    for j in range(n_balls):
        members = points[labels == j]
        if len(members) == 0:
            continue
        c, r = minimum_enclosing_ball(members)
        centers.append(c)
        radii.append(r + margin)
    return np.asarray(centers).reshape(-1, 3), np.asarray(radii)


def fit_spheres(link: str, mesh: trimesh.Trimesh, margin: float = DEFAULT_MARGIN, seed: int = 0,
                n_spheres: int | None = None) -> LinkSpheres:
    points = sample_link_points(mesh, seed)
    if n_spheres is None:
        n_spheres = int(np.clip(np.ceil(mesh.extents.max() / SPHERE_SPACING) + 1, 2, 10))
    centers, radii = fit_balls(points, n_spheres, margin, np.random.default_rng(seed))
    return LinkSpheres(link, centers, radii)


def _to_json(fitted: list[LinkSpheres]) -> dict:
    return {s.link: {"centers_link": s.centers_link.round(6).tolist(), "radii": s.radii.round(6).tolist()}
            for s in fitted}


def load_or_fit(meshes: dict[str, trimesh.Trimesh], input_bytes: bytes, cache_root: Path,
                margin: float = DEFAULT_MARGIN, seed: int = 0, link_fit: dict | None = None,
                name: str = "panda") -> list[LinkSpheres]:
    """Spheres for every link in ``meshes`` (sorted by link name), from the cache or fitted now.

    ``input_bytes`` are the bytes the meshes came from (URDF + mesh files): part of the key.
    ``link_fit``: per-link (spheres, margin) overrides (the Panda's ``LINK_FIT`` by default);
    ``name`` names the robot in the cache file's name.
    """
    link_fit = LINK_FIT if link_fit is None else {k: tuple(v) for k, v in link_fit.items()}
    key = sha256_bytes(canonical_json({"version": FIT_VERSION, "margin": margin, "seed": seed,
                                       "link_fit": link_fit}).encode()
                       + input_bytes)[:24]
    path = Path(cache_root) / "planning" / f"{name}_spheres_{key}.json"
    if path.exists():
        record = json.loads(path.read_text())
        body = record.get("links")
        if record.get("version") != FIT_VERSION or record.get("key") != key or body is None \
                or sha256_bytes(canonical_json(body).encode()) != record.get("content_sha256"):
            raise ValueError(f"corrupt or stale sphere cache {path}: delete it to refit")
    else:
        body = _to_json([fit_spheres(l, meshes[l], link_fit.get(l, (None, margin))[1], seed,
                                     n_spheres=link_fit.get(l, (None, margin))[0]) for l in sorted(meshes)])
        record = {"version": FIT_VERSION, "key": key, "margin": margin, "seed": seed, "links": body,
                  "content_sha256": sha256_bytes(canonical_json(body).encode())}
        atomic_write_text(path, canonical_json(record))
    if sorted(body) != sorted(meshes):
        raise ValueError(f"sphere cache {path} covers links {sorted(body)}, expected {sorted(meshes)}")
    return [LinkSpheres(l, np.asarray(body[l]["centers_link"], dtype=float).reshape(-1, 3),
                        np.asarray(body[l]["radii"], dtype=float)) for l in sorted(body)]
