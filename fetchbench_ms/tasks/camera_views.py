"""Choosing the camera pair of a task by what it can see of the supports.

The original samples the two cameras around the support region and keeps a pair whose
vertical field of view spans the supports' heights; the paper asks for "a good view of
the whole scene". Spanning the heights is not seeing: a camera level with a drawer sees
its front, one beside the robot sees the arm, one beside a cabinet sees its open door.
So each candidate pair is scored by ray casts: sample points a few centimetres above
every support surface (where objects sit), and count those that are inside both
cameras' frusta and unobstructed from both eyes by the furniture, the robot table and
the robot in its start configuration. Candidates are drawn on a sphere around the
camera target (distance, azimuth beside the robot, elevation), the right camera the
left's mirror image; the best-scoring of ``tries`` pairs wins. ``paper_camera_pair`` is
the original's heuristic itself (the envs' ``camera_placement="paper"``).

The score weights every support *label* equally (then every surface of a label), so a
scene's two baskets count as much as its eight shelf boards: the suite needs targets in
every category the scene has. The suite generator can weight the labels (``label_weights``)
toward the categories a scene still lacks.

Pure geometry (trimesh rays + spheres), no simulator: the sampler stays sim-free until
it settles the objects.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import trimesh

from .spec import DEFAULT_QPOS

NEAR, FAR = 0.15, 2.5  # m: the depth range the cameras keep (the original's)
POINT_LIFT = 0.03  # m above a support surface: about the middle of a small object
SURFACE_POINTS = 8  # sample points per surface besides its centroid
# The visibility filter wants > 500 px at 640x480 (70 deg): a 6 cm object covers that
# out to about 1.2 m. Points farther than this count less (by the square of the ratio,
# as pixel area does), so the score prefers cameras close enough to resolve objects.
RESOLVE_DISTANCE = 1.1  # m


@dataclass(frozen=True)
class CameraRanges:
    """Where candidate cameras are drawn, around the look-at target."""

    distance: tuple[float, float] = (0.6, 1.5)  # m from the target
    azimuth: tuple[float, float] = (math.radians(10), math.radians(70))  # off -x, toward the camera's side
    elevation: tuple[float, float] = (math.radians(0), math.radians(65))  # above the target
    target_jitter: float = 0.3  # fraction of the region's half size


def support_points(scene) -> tuple[np.ndarray, list[tuple[str, str]]]:
    """(P, 3) points above the support surfaces, and (label, surface name) of each."""
    points, owners = [], []
    for surface in scene.support_surfaces:
        polygon = np.asarray(surface.polygon_xy, dtype=float)
        centroid = np.asarray(surface.polygon.centroid.coords[0])
        corners = polygon[np.linspace(0, len(polygon) - 1, min(SURFACE_POINTS, len(polygon))).astype(int)]
        xy = np.concatenate([centroid[None], centroid + 0.6 * (corners - centroid)])
        z = surface.height + min(POINT_LIFT, 0.5 * surface.free_height)
        points.append(np.column_stack([xy, np.full(len(xy), z)]))
        owners += [(surface.label, surface.name)] * len(xy)
    return np.concatenate(points), owners


@functools.lru_cache(maxsize=1)
def _robot_spheres_base() -> tuple[np.ndarray, np.ndarray]:
    """Centres (S, 3) in the base frame and radii of the robot at its start configuration."""
    from ..planning.robot import panda

    robot = panda()
    centers = robot.sphere_centers(np.asarray(DEFAULT_QPOS[:7]), finger=DEFAULT_QPOS[7])[0].numpy()
    return centers, robot.spheres.radii.copy()


class Occluders:
    """The furniture, the robot table (triangles) and the robot (spheres) in the scene frame."""

    def __init__(self, scene, base_position, base_quat_wxyz, table_center, table_size):
        from scipy.spatial.transform import Rotation

        from ..scenes.export import scene_to_trimesh

        w, x, y, z = base_quat_wxyz
        R = Rotation.from_quat([x, y, z, w]).as_matrix()
        table = trimesh.creation.box(extents=table_size)
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, table_center
        table.apply_transform(T)
        furniture = scene_to_trimesh(scene).to_geometry()
        self.mesh = trimesh.util.concatenate([furniture, table])
        self.rays = trimesh.ray.ray_triangle.RayMeshIntersector(self.mesh)
        centers, radii = _robot_spheres_base()
        self.sphere_centers = centers @ R.T + np.asarray(base_position)
        self.sphere_radii = radii

    def unobstructed(self, eye: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(P,) whether the segment from ``eye`` to each point is free (the point's own 1 cm excepted)."""
        d = points - eye
        length = np.linalg.norm(d, axis=1)
        direction = d / length[:, None]
        free = np.ones(len(points), dtype=bool)
        hits, ray_index, _ = self.rays.intersects_location(np.tile(eye, (len(points), 1)), direction,
                                                           multiple_hits=False)
        if len(hits):
            hit_distance = np.linalg.norm(hits - eye, axis=1)
            free[ray_index[hit_distance < length[ray_index] - 0.01]] = False
        # Robot spheres: the closest point of each segment to each centre.
        t = np.clip(direction @ (self.sphere_centers - eye).T, 0.0, length[:, None])  # (P, S)
        closest = eye + t[..., None] * direction[:, None]
        blocked = (np.linalg.norm(closest - self.sphere_centers[None], axis=2) < self.sphere_radii[None]).any(axis=1)
        return free & ~blocked


def camera_axes(eye, target) -> np.ndarray:
    """Rows: forward, left, up of a camera at ``eye`` looking at ``target`` (z up)."""
    forward = np.asarray(target, float) - np.asarray(eye, float)
    forward /= np.linalg.norm(forward)
    left = np.cross([0.0, 0.0, 1.0], forward)
    left /= np.linalg.norm(left)
    return np.stack([forward, left, np.cross(forward, left)])


def in_frustum(eye, target, points, fov_x: float, aspect: float) -> np.ndarray:
    """(P,) whether each point is inside the camera's field of view and depth range."""
    local = (points - eye) @ camera_axes(eye, target).T  # forward, left, up
    depth = local[:, 0]
    tan_x = math.tan(fov_x / 2)
    tan_y = tan_x / aspect
    with np.errstate(divide="ignore", invalid="ignore"):
        inside = (np.abs(local[:, 1]) < tan_x * depth) & (np.abs(local[:, 2]) < tan_y * depth)
    return inside & (depth > NEAR) & (np.linalg.norm(points - eye, axis=1) < FAR)


def seen_points(eye, target, points, occluders: Occluders, fov_x: float, aspect: float) -> np.ndarray:
    """(P,) how well the camera sees each point: 0 when outside the view or hidden, else
    1 up to ``RESOLVE_DISTANCE`` and falling with the squared distance beyond it."""
    inside = in_frustum(eye, target, points, fov_x, aspect)
    if inside.any():
        inside[inside] = occluders.unobstructed(np.asarray(eye, float), points[inside])
    distance = np.linalg.norm(points - np.asarray(eye, float), axis=1)
    return inside * np.minimum(1.0, (RESOLVE_DISTANCE / distance) ** 2)


def view_score(seen_both: np.ndarray, owners, label_weights: dict | None = None) -> float:
    """Mean over labels (weighted by ``label_weights``, default alike; a label it lacks
    weighs 1) of the mean over that label's surfaces of the points' view quality."""
    by_surface: dict = {}
    for ok, (label, name) in zip(seen_both, owners):
        by_surface.setdefault(label, {}).setdefault(name, []).append(ok)
    scores = [np.mean([np.mean(v) for v in surfaces.values()]) for surfaces in by_surface.values()]
    weights = [1.0 if label_weights is None else label_weights.get(label, 1.0) for label in by_surface]
    if sum(weights) <= 0:
        return float(np.mean(scores))
    return float(np.average(scores, weights=weights))


def mirror_y(point, y_mirror: float) -> np.ndarray:
    out = np.array(point, dtype=float)
    out[1] = 2 * y_mirror - out[1]
    return out


def _draw_view(rng: np.random.Generator, center, half, ranges: "CameraRanges") -> tuple[np.ndarray, np.ndarray]:
    """One left camera (eye, aim point): the aim jittered in the target region, the eye at a
    drawn distance, azimuth and elevation from it (the draws in this order)."""
    target = center + rng.uniform(-ranges.target_jitter, ranges.target_jitter, size=3) * half
    distance = rng.uniform(*ranges.distance)
    azimuth = rng.uniform(*ranges.azimuth)
    elevation = rng.uniform(*ranges.elevation)
    eye = target + distance * np.array([
        -math.cos(elevation) * math.cos(azimuth),
        math.cos(elevation) * math.sin(azimuth),
        math.sin(elevation),
    ])
    return eye, target


def sample_camera_pair(rng: np.random.Generator, scene, occluders: Occluders, fov_x: float, aspect: float,
                       tries: int, ranges: CameraRanges = CameraRanges(), label_weights: dict | None = None):
    """The best of ``tries`` mirrored pairs: ((eye_l, target_l), (eye_r, target_r)), its score,
    and whether every support surface has a point both cameras see."""
    center = np.asarray(scene.camera_target.center, float)
    half = np.asarray(scene.camera_target.half_size, float)
    points, owners = support_points(scene)
    best = None
    for _ in range(tries):
        eye, target = _draw_view(rng, center, half, ranges)
        eye_right, target_right = mirror_y(eye, center[1]), mirror_y(target, center[1])
        seen_both = np.minimum(seen_points(eye, target, points, occluders, fov_x, aspect),
                               seen_points(eye_right, target_right, points, occluders, fov_x, aspect))
        score = view_score(seen_both, owners, label_weights)
        if best is None or score > best[1]:
            surfaces_seen = {name for ok, (_, name) in zip(seen_both, owners) if ok > 0}
            covered = len(surfaces_seen) == len(scene.support_surfaces)
            best = (((eye, target), (eye_right, target_right)), score, covered)
    return best


#: Draws of the original's camera heuristic (``paper_camera_pair``).
PAPER_CAMERA_TRIES = 20


def support_height_range(scene) -> tuple[float, float]:
    """Lowest and highest of the points above the support surfaces (``support_points``):
    the heights the original's cameras must span."""
    z = support_points(scene)[0][:, 2]
    return float(z.min()), float(z.max())


def paper_camera_pair(rng: np.random.Generator, scene, fov_x: float, aspect: float,
                      tries: int = PAPER_CAMERA_TRIES, ranges: CameraRanges = CameraRanges()):
    """The original FetchBench's camera heuristic: ((eye_l, target_l), (eye_r, target_r))
    and whether the pair passed its test.

    Each draw aims the left camera at the camera target region's centre plus an offset,
    from an eye drawn as ``sample_camera_pair`` draws them (``ranges``; the original's
    ranges are not in its release), and mirrors it in y for the right camera. The first
    draw whose vertical field of view spans the supports' heights
    (``support_height_range``) at the aim point, for both cameras and within their depth
    range, is kept; after ``tries`` failed draws, the last one. No occlusion scoring."""
    center = np.asarray(scene.camera_target.center, float)
    half = np.asarray(scene.camera_target.half_size, float)
    z_lo, z_hi = support_height_range(scene)
    pair = None
    for _ in range(tries):
        eye, target = _draw_view(rng, center, half, ranges)
        pair = ((eye, target), (mirror_y(eye, center[1]), mirror_y(target, center[1])))
        # The supports' lowest and highest heights above the aim point: in view?
        if all(in_frustum(e, t, np.array([[t[0], t[1], z_lo], [t[0], t[1], z_hi]]), fov_x, aspect).all()
               for e, t in pair):
            return pair, True
    return pair, False
