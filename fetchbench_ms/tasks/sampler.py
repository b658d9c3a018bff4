"""Turn a seed into a ``TaskSpec`` the way FetchBench does.

1. Scene: a scene type (fixed, or drawn with the weights of the paper's test-scene mix
   among the types that offer the requested category) and a procedural scene from it.
2. Objects: up to 15 catalog objects, each placed by choosing a support label with the
   original's weights {in_basket .5, on_shelf .3, in_drawer .3, on_table .2} (among the
   labels the scene has), a surface of that label by area, a point on the surface
   polygon eroded by 0.1 x the object's largest extent, a random stable pose (by its
   probability) with random yaw, 5 mm above the surface. The footprint must lie on the
   surface, the object must fit under the board above, and its bounding box grown by
   5 mm must touch nothing (furniture or objects already placed); 100 attempts each.
   For the labels in ``SamplerConfig.fit_labels`` (the suite's drawers and baskets a
   scene still needs) the label is drawn first and, for a fit label, the object is
   drawn among those with a stable pose that fits the surface, turned along its long
   side, or across it where that fits too (so the open hand spans the long side), with
   a small yaw jitter, preferring objects whose top reaches over the walls (a hand
   cannot go down between a small basket's walls); a full surface falls back to the
   placement above.
3. Physics per object: density U(100, 400) kg/m^3, friction U(0.6, 1.2), restitution
   U(0, 0.1) (the original's ranges; PhysX has no rolling/torsion friction, so the
   original's 0.05 has no counterpart).
4. Robot base uniformly in the scene's robot region, facing +x; a box robot table
   (x U(0.4, 0.7) m, y U(0.6, 1.0) m) under it, top at the base height.
5. Two cameras, left and right of the robot (mirrored in y about the camera target),
   looking at the camera target region's centre plus an offset; of 32 candidate pairs
   the one that sees most of the support surfaces past the furniture and the robot
   (ray casts, ``camera_views``; labels weighted by ``camera_label_weights``) is kept.
6. Settle: the placed objects are simulated until at rest (``sim.settle``); objects
   that fall off their support or do not come to rest are dropped. The settled poses
   are stored, so an episode starts at rest.
Every draw comes from one ``numpy.random.Generator`` seeded by ``seed``.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import fcl
import numpy as np
import trimesh
from scipy.spatial import ConvexHull
from shapely.geometry import Point, Polygon

from ..objects.loading import collision_vertices, load_object, object_ids, object_source
from ..scenes import SCENE_TYPES, generate, get_scene_type
from ..utils.canonical import canonical_lengths, canonical_quat
from .camera_views import Occluders, camera_axes, sample_camera_pair
from .spec import CATEGORY_LABELS, DEFAULT_QPOS, CameraPose, ObjectPlacement, TaskSpec, category_name, matrix_to_pose

SAMPLER_VERSION = "4"  # 4: poses on the grids of utils.canonical (machine-independent); 3: on `fit_labels` objects that fit, turned, reaching over walls; camera label weights

#: The original's support-label weights for placing an object.
LABEL_WEIGHTS = {"in_basket": 0.5, "on_shelf": 0.3, "in_drawer": 0.3, "on_table": 0.2}
#: Test scenes per type in the original benchmark: the mix a random scene type follows.
SCENE_TYPE_MIX = {
    "CellShelfDesk": 10, "DrawerShelf": 10, "LargeShelf": 10, "LayerShelf": 10, "LargeShelfDesk": 9,
    "RoundTable": 9, "DeskWall": 7, "SingleDoorCabinetDesk": 7, "Desk": 6, "DoubleDoorCabinet": 6,
    "Drawer": 6, "EketShelf": 5, "TriangleShelfDesk": 5,
}
DENSITY_RANGE = (100.0, 400.0)  # kg/m^3
FRICTION_RANGE = (0.6, 1.2)
RESTITUTION_RANGE = (0.0, 0.1)
ROBOT_TABLE_X_RANGE = (0.4, 0.7)  # m
ROBOT_TABLE_Y_RANGE = (0.6, 1.0)  # m
ROBOT_TABLE_FRONT = 0.12  # m the table reaches in front of the base (the Panda's base is ~0.1 m in radius)
ROBOT_TABLE_MIN_HEIGHT = 0.01  # m: a base standing on the floor gets a 1 cm plate it sinks into


@dataclass(frozen=True)
class SamplerConfig:
    num_objects: int = 15
    object_split: str = "test"
    placement_attempts: int = 100
    clearance: float = 0.005  # m, between an object's box and everything else
    drop_height: float = 0.005  # m above the surface
    erosion: float = 0.1  # x the object's largest extent
    camera_tries: int = 32
    camera_fov_x: float = math.radians(70.0)
    camera_aspect: float = 4.0 / 3.0  # width / height of the sensor the FOV check assumes
    settle: bool = True
    scene_attempts: int = 20  # scenes tried before giving up (a category that no scene offers)
    #: Support-label weights for placing objects; None: the original's ``LABEL_WEIGHTS``.
    #: (The suite generator leans them toward the categories a scene still needs.)
    label_weights: tuple[tuple[str, float], ...] | None = None
    #: Labels (e.g. the drawers and baskets a suite scene still needs) whose objects are
    #: chosen to fit the drawn surface and turned to fit it (``_place_fitting``):
    #: with a random object and yaw, few objects fit a 17 cm basket. Empty: the original's.
    fit_labels: tuple[str, ...] = ()
    #: Yaw jitter (rad, +-) about the aligned yaw of a ``fit_labels`` placement.
    fit_yaw_jitter: float = math.radians(10.0)
    #: Turn a fit-label object across the surface where it fits that way (else along).
    fit_across: bool = True
    #: Prefer, on a walled fit-label surface, objects whose top reaches to this far (m)
    #: below the wall top: the open hand (23 cm by 8 cm) cannot go down between the walls
    #: of a small basket, so only fingers reaching down over the wall can grasp; and a
    #: top above the walls is what the cameras see. None: no preference.
    fit_wall_reach: float | None = 0.03
    #: Weights of the support labels in the camera view score (``camera_views.view_score``);
    #: None: every label alike. The suite leans the cameras toward the categories it needs.
    camera_label_weights: tuple[tuple[str, float], ...] | None = None

    def __post_init__(self):
        if self.label_weights is not None:
            unknown = sorted({label for label, _ in self.label_weights} - set(LABEL_WEIGHTS))
            if unknown:
                raise ValueError(f"unknown support labels {unknown}; valid: {', '.join(LABEL_WEIGHTS)}")
            if any(w < 0 for _, w in self.label_weights) or not any(w > 0 for _, w in self.label_weights):
                raise ValueError(f"label weights must be >= 0 and not all zero, got {self.label_weights}")
        for name, given in (("fit_labels", self.fit_labels),
                            ("camera_label_weights", [lab for lab, _ in self.camera_label_weights or ()])):
            unknown = sorted(set(given) - set(LABEL_WEIGHTS))
            if unknown:
                raise ValueError(f"unknown support labels {unknown} in {name}; valid: {', '.join(LABEL_WEIGHTS)}")
        if self.camera_label_weights is not None and any(w < 0 for _, w in self.camera_label_weights):
            raise ValueError(f"camera label weights must be >= 0, got {self.camera_label_weights}")
        if not 1 <= self.num_objects <= 64:
            raise ValueError(f"num_objects must be 1..64, got {self.num_objects}")
        if self.object_split not in ("train", "test"):
            raise ValueError(f"unknown object split {self.object_split!r}; valid: train, test")


def categories() -> tuple[str, ...]:
    return tuple(CATEGORY_LABELS)


def scene_types_for(category: str | None) -> tuple[str, ...]:
    """Scene types whose generator offers ``category``'s support label (all types if None)."""
    if category is None:
        return SCENE_TYPES
    label = _category_label(category)
    return tuple(t for t in SCENE_TYPES if label in get_scene_type(t).support_labels)


def _category_label(category: str) -> str:
    return CATEGORY_LABELS[category_name(category)]  # Shelf or on_shelf alike


def sample_task(
    seed: int,
    scene_type: str | None = None,
    category: str | None = None,
    config: SamplerConfig = SamplerConfig(),
) -> TaskSpec:
    """Sample one task. ``scene_type`` fixes the furniture type; ``category`` (Table, Shelf,
    Drawer, Basket) makes the target rest on that kind of support. Same arguments, same task."""
    if scene_type is not None and scene_type not in SCENE_TYPES:
        raise ValueError(f"unknown scene type {scene_type!r}; valid: {', '.join(SCENE_TYPES)}")
    target_label = None if category is None else _category_label(category)
    rng = np.random.default_rng(int(seed))
    if scene_type is not None:
        candidates = (scene_type,)
    else:
        candidates = scene_types_for(category)
        if not candidates:
            raise ValueError(f"no scene type offers category {category!r}")
    weights = np.array([SCENE_TYPE_MIX[t] for t in candidates], dtype=float)
    ids = object_ids(config.object_split)
    for _ in range(config.scene_attempts):
        chosen_type = candidates[int(rng.choice(len(candidates), p=weights / weights.sum()))]
        scene_seed = int(rng.integers(2**31))
        task = _sample_in_scene(rng, chosen_type, scene_seed, target_label, ids, config)
        if task is not None:
            return replace(task, seed=int(seed))
    raise ValueError(
        f"could not sample a task for seed {seed} (scene type {scene_type}, category {category}) "
        f"in {config.scene_attempts} scenes"
    )


def _sample_in_scene(rng, scene_type, scene_seed, target_label, ids, config) -> TaskSpec | None:
    scene = generate(scene_type, scene_seed)
    if target_label is not None and not scene.surfaces(target_label):
        return None
    world = _BoxWorld(scene)
    placements = _place_objects(rng, scene, world, ids, config, target_label)
    if target_label is not None and not any(p.support_label == target_label for p in placements):
        return None
    if not placements:
        return None
    robot = _sample_robot(rng, scene, world)
    if robot is None:
        return None
    base_position, base_quat, table_center, table_size = robot
    cameras, view_score, covered = _sample_cameras(rng, scene, robot, config)
    extra = {"sampler_version": SAMPLER_VERSION, "placed_objects": len(placements),
             "camera_view_score": round(view_score, 6), "cameras_cover_supports": covered}
    if config.settle:
        from ..sim.settle import settle_placements  # the one simulator step of sampling

        placements, report = settle_placements(scene, placements, table_center, table_size)
        extra.update(report)
    else:
        placements = [p.canonical() for p in placements]
    eligible = [i for i, p in enumerate(placements) if target_label is None or p.support_label == target_label]
    if not eligible:
        return None
    target_index = int(eligible[int(rng.integers(len(eligible)))])
    return TaskSpec(
        scene_type=scene_type,
        scene_seed=scene_seed,
        scene_params=dict(scene.params),
        scene_hash=scene.content_hash(),
        objects=tuple(placements),
        target_index=target_index,
        robot_base_position=base_position,
        robot_base_quat_wxyz=base_quat,
        robot_table_center=table_center,
        robot_table_size=table_size,
        camera_left=cameras[0],
        camera_right=cameras[1],
        robot_init_qpos=DEFAULT_QPOS,
        object_source=object_source(),
        extra=extra,
    )


# ----------------------------------------------------------------------------- objects
class _BoxWorld:
    """Furniture primitives plus the boxes of placed objects, for exact overlap tests (FCL)."""

    def __init__(self, scene):
        self.manager = fcl.DynamicAABBTreeCollisionManager()
        self.objects = []
        for part in scene.parts:
            if part.shape == "box":
                geometry = fcl.Box(*part.size)
            elif part.shape == "cylinder":
                geometry = fcl.Cylinder(part.size[0], part.size[1])
            elif part.shape == "capsule":
                geometry = fcl.Capsule(part.size[0], part.size[1])
            else:
                hull = trimesh.Trimesh(np.asarray(part.mesh_vertices)).convex_hull
                geometry = fcl.BVHModel()
                geometry.beginModel(len(hull.vertices), len(hull.faces))
                geometry.addSubModel(hull.vertices, hull.faces)
                geometry.endModel()
            T = part.transform()
            self._add(fcl.CollisionObject(geometry, fcl.Transform(T[:3, :3], T[:3, 3])))

    def _add(self, obj) -> None:
        self.objects.append(obj)  # FCL keeps raw pointers: the Python objects must stay alive
        self.manager.registerObject(obj)
        self.manager.update()

    @staticmethod
    def box(size, rotation, center):
        return fcl.CollisionObject(fcl.Box(*size), fcl.Transform(np.asarray(rotation, float), np.asarray(center, float)))

    def hits(self, obj) -> bool:
        request = fcl.CollisionRequest()
        data = fcl.CollisionData(request, fcl.CollisionResult())
        self.manager.collide(obj, data, fcl.defaultCollisionCallback)
        return data.result.is_collision

    def add(self, obj) -> None:
        self._add(obj)


@functools.lru_cache(maxsize=4096)
def _rest_geometry(object_id: str, pose_index: int):
    """For one stable pose: vertices in the support frame, their box, and the 2D hull of the footprint."""
    asset = load_object(object_id)
    T = asset.stable_poses[pose_index]
    v = collision_vertices(asset) @ T[:3, :3].T + T[:3, 3]
    hull_xy = v[ConvexHull(v[:, :2]).vertices, :2]
    return v.min(axis=0), v.max(axis=0), hull_xy


def _place_objects(rng, scene, world, ids, config, target_label) -> list[ObjectPlacement]:
    weights = LABEL_WEIGHTS if config.label_weights is None else dict(config.label_weights)
    labels = [label for label in LABEL_WEIGHTS if scene.surfaces(label) and weights.get(label, 0.0) > 0]
    if not labels:
        return []
    label_p = np.array([weights[label] for label in labels])
    label_p = label_p / label_p.sum()
    chosen = rng.choice(len(ids), size=config.num_objects, replace=len(ids) < config.num_objects)
    fit = [label in config.fit_labels for label in labels]
    placements = []
    for k, id_index in enumerate(chosen):
        asset = load_object(ids[int(id_index)])
        # With a category, the first object goes on that label so the task has a target there.
        forced = target_label if (k == 0 and target_label is not None) else None
        placed = None
        if forced is None and any(fit):
            # The label first: a fit label gets an object chosen to fit it; the others keep
            # the original's placement among themselves (the same overall label weights).
            label = labels[int(rng.choice(len(labels), p=label_p))]
            if label in config.fit_labels:
                placed = _place_fitting(rng, scene, world, ids, label, config)
            elif not all(fit):
                others = np.array([0.0 if f else p for f, p in zip(fit, label_p)])
                placed = _place_one(rng, scene, world, asset, labels, others / others.sum(), config, None)
        if placed is None:  # the original's placement (also when the fit label had no room left)
            placed = _place_one(rng, scene, world, asset, labels, label_p, config, forced)
        if placed is not None:
            placements.append(placed)
    return placements


@functools.lru_cache(maxsize=256)
def _surface_rectangle(polygon_wkb: bytes) -> tuple[float, float, float]:
    """(long side, short side, angle of the long side) of a polygon's smallest rotated rectangle."""
    from shapely import wkb

    return _rectangle(wkb.loads(polygon_wkb))


def _rectangle(polygon) -> tuple[float, float, float]:
    corners = np.asarray(polygon.minimum_rotated_rectangle.exterior.coords)[:3]
    a, b = corners[1] - corners[0], corners[2] - corners[1]
    if np.linalg.norm(b) > np.linalg.norm(a):
        a, b = b, a
    return float(np.linalg.norm(a)), float(np.linalg.norm(b)), float(math.atan2(a[1], a[0]))


@functools.lru_cache(maxsize=4096)
def _rest_rectangle(object_id: str, pose_index: int) -> tuple[float, float, float, float]:
    """(long side, short side, angle of the long side, height) of a stable pose's footprint."""
    lo, hi, hull_xy = _rest_geometry(object_id, pose_index)
    return (*_rectangle(Polygon(hull_xy)), float(hi[2] - lo[2]))


def _fitting_poses(object_id: str, surface, config) -> list[tuple[int, bool, bool]]:
    """Stable poses of the object whose footprint, turned along the surface's long side,
    fits inside the surface shrunk by the sampler's erosion and clearance on every side,
    and whose height fits under the board above; with each, whether it also fits turned
    across (its long side along the surface's short side) and whether its top reaches
    up to ``fit_wall_reach`` below the surface's wall top (always, without walls)."""
    asset = load_object(object_id)
    margin = 2 * (config.erosion * float(max(asset.record.extents)) + config.clearance)
    long_side, short_side, _ = _surface_rectangle(surface.polygon.wkb)
    poses = []
    for pose_index in range(len(asset.stable_poses)):
        length, width, _, height = _rest_rectangle(object_id, pose_index)
        if (length + margin <= long_side and width + margin <= short_side
                and height + config.drop_height + config.clearance <= surface.free_height):
            reaches = (surface.wall_top is None or config.fit_wall_reach is None
                       or surface.height + height >= surface.wall_top - config.fit_wall_reach)
            poses.append((pose_index, length + margin <= short_side, reaches))
    return poses


def _place_fitting(rng, scene, world, ids, label, config, object_tries: int = 24, attempts: int = 25):
    """Place an object that fits a surface of ``label``: a surface by area, then catalog
    objects in random order (first those whose box could fit, by the catalog's extents)
    until one has a stable pose that fits (``_fitting_poses``), preferring one whose top
    reaches over the walls (else the first that fits of ``object_tries``); it is turned so its
    footprint's long side lies along the surface's, or across it where it fits that way
    (either way round, +- ``fit_yaw_jitter``), and placed with ``_place_one``'s checks.
    None if nothing fits or there is no room."""
    surfaces = scene.surfaces(label)
    areas = np.array([s.area for s in surfaces])
    surface = surfaces[int(rng.choice(len(surfaces), p=areas / areas.sum()))]
    long_side, short_side, surface_angle = _surface_rectangle(surface.polygon.wkb)
    records = _records(tuple(ids))
    # A cheap pre-test from the catalog's extents (no geometry loaded): the two smallest fit the surface.
    could_fit = [i for i, e in enumerate(records) if e[0] <= short_side and e[1] <= long_side]
    if not could_fit:
        return None
    chosen = None  # (object id, its fitting poses)
    for id_index in rng.permutation(could_fit)[:object_tries]:
        object_id = ids[int(id_index)]
        poses = _fitting_poses(object_id, surface, config)
        reaching = [p for p in poses if p[2]]
        if reaching:
            chosen = (object_id, reaching)
            break
        if poses and chosen is None:
            chosen = (object_id, poses)
    if chosen is not None:
        object_id, poses = chosen
        asset = load_object(object_id)
        pose_p = asset.stable_probs[[p[0] for p in poses]]
        pose_p = pose_p / pose_p.sum()
        for _ in range(attempts):
            pose_index, across, _ = poses[int(rng.choice(len(poses), p=pose_p))]
            # Across where it fits: a top grasp closes the fingers over the object's short
            # side, so the hand (23 cm from finger to finger) then spans the surface's long side.
            turn = math.pi / 2 if (across and config.fit_across) else 0.0
            yaw = (surface_angle + turn - _rest_rectangle(object_id, pose_index)[2] + math.pi * int(rng.integers(2))
                   + float(rng.uniform(-config.fit_yaw_jitter, config.fit_yaw_jitter)))
            placed = _try_place(rng, world, asset, surface, pose_index, yaw, config)
            if placed is not None:
                return placed
    return None  # nothing fits, or the surface is full: the caller places its object elsewhere


@functools.lru_cache(maxsize=8)
def _records(ids: tuple[str, ...]) -> list[tuple[float, float, float]]:
    """Sorted catalog extents of each id (no geometry loaded)."""
    from ..objects import catalog

    by_id = {r.object_id: r for r in catalog.list_objects()}
    return [tuple(sorted(by_id[i].extents)) for i in ids]


def _place_one(rng, scene, world, asset, labels, label_p, config, forced_label):
    stable_p = asset.stable_probs / asset.stable_probs.sum()
    for _ in range(config.placement_attempts):
        label = forced_label or labels[int(rng.choice(len(labels), p=label_p))]
        surfaces = scene.surfaces(label)
        areas = np.array([s.area for s in surfaces])
        surface = surfaces[int(rng.choice(len(surfaces), p=areas / areas.sum()))]
        pose_index = int(rng.choice(len(stable_p), p=stable_p))
        yaw = float(rng.uniform(0.0, 2 * math.pi))
        placed = _try_place(rng, world, asset, surface, pose_index, yaw, config)
        if placed is not None:
            return placed
    return None


def _try_place(rng, world, asset, surface, pose_index, yaw, config) -> ObjectPlacement | None:
    """One placement attempt: a point on the eroded surface, the stable pose turned by ``yaw``;
    the placement (added to ``world``) if it lies on the surface and touches nothing, else None."""
    c = config.clearance
    point = _sample_in_polygon(rng, _eroded(surface, config.erosion * float(max(asset.record.extents))))
    if point is None:
        return None
    lo, hi, hull_xy = _rest_geometry(asset.object_id, pose_index)
    if hi[2] - lo[2] + config.drop_height + c > surface.free_height:
        return None
    # Turn by the yaw about the box centre's vertical, put that centre over the point.
    R_yaw = _rot_z(yaw)
    center_xy = (lo[:2] + hi[:2]) / 2
    footprint = (hull_xy - center_xy) @ R_yaw[:2, :2].T + point
    if not surface.polygon.contains(Polygon(footprint)):
        return None
    # The stable pose's box, grown by the clearance except at the bottom (it must not
    # touch its own support), must not touch furniture or the objects placed so far.
    box_lo = lo - [c, c, -0.5 * config.drop_height]
    box_hi = hi + [c, c, c]
    z_shift = surface.height + config.drop_height - lo[2]
    box_center = np.array([point[0], point[1], (box_lo[2] + box_hi[2]) / 2 + z_shift])
    box = world.box(box_hi - box_lo, R_yaw, box_center)
    if world.hits(box):
        return None
    world.add(box)
    T_support_object = asset.stable_poses[pose_index]
    T_world_object = np.eye(4)
    T_world_object[:3, :3] = R_yaw @ T_support_object[:3, :3]
    offset = np.array([center_xy[0], center_xy[1], 0.0])
    T_world_object[:3, 3] = R_yaw @ (T_support_object[:3, 3] - offset) + [point[0], point[1], z_shift]
    position, quat = matrix_to_pose(T_world_object)
    friction = float(rng.uniform(*FRICTION_RANGE))
    return ObjectPlacement(
        object_id=asset.object_id,
        position=position,
        quat_wxyz=quat,
        density=float(rng.uniform(*DENSITY_RANGE)),
        static_friction=friction,
        dynamic_friction=friction,
        restitution=float(rng.uniform(*RESTITUTION_RANGE)),
        support_surface=surface.name,
        support_label=surface.label,
    )


@functools.lru_cache(maxsize=4096)
def _eroded_wkb(polygon_wkb: bytes, distance: float):
    from shapely import wkb

    return wkb.loads(polygon_wkb).buffer(-distance)


def _eroded(surface, distance: float):
    """The surface's polygon shrunk by ``distance`` (cached: surfaces and objects repeat)."""
    return _eroded_wkb(surface.polygon.wkb, distance)


def _sample_in_polygon(rng, polygon, tries: int = 50):
    """A uniform point in ``polygon`` (rejection in its bounding box), or None."""
    if polygon.is_empty or polygon.area <= 0:
        return None
    x0, y0, x1, y1 = polygon.bounds
    for _ in range(tries):
        x, y = rng.uniform(x0, x1), rng.uniform(y0, y1)
        if polygon.contains(Point(x, y)):
            return float(x), float(y)
    return None


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# ----------------------------------------------------------------------------- robot
def _sample_robot(rng, scene, world: _BoxWorld, tries: int = 20):
    region = scene.robot_region
    for _ in range(tries):
        x = float(rng.uniform(*region.x_range))
        y = float(rng.uniform(*region.y_range))
        z = float(rng.uniform(*region.z_range))
        yaw = float(rng.uniform(*region.yaw_range))
        size_x = float(rng.uniform(*ROBOT_TABLE_X_RANGE))
        size_y = float(rng.uniform(*ROBOT_TABLE_Y_RANGE))
        R = _rot_z(yaw)
        # Table top at the base height (the base stands on it), front edge just ahead of the base.
        height = max(z, ROBOT_TABLE_MIN_HEIGHT)
        center = np.array([x, y, 0.0]) + R @ np.array([ROBOT_TABLE_FRONT - size_x / 2, 0.0, 0.0])
        center[2] = height / 2
        if world.hits(world.box((size_x, size_y, height), R, center)):
            continue
        quat = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        # On the grids of ``utils.canonical``: trigonometry's last bits differ between
        # machines, and the robot table goes into the settling simulation.
        return (canonical_lengths((x, y, z)), canonical_quat(quat), canonical_lengths(center),
                canonical_lengths((size_x, size_y, height)))
    return None


# ----------------------------------------------------------------------------- cameras
def look_at_quat(eye, target) -> tuple[float, float, float, float]:
    """wxyz rotation of a SAPIEN camera (x forward, y left, z up) at ``eye`` looking at ``target``."""
    T = np.eye(4)
    T[:3, :3] = camera_axes(eye, target).T
    return matrix_to_pose(T)[1]


def _sample_cameras(rng, scene, robot, config) -> tuple[tuple[CameraPose, CameraPose], float, bool]:
    """The camera pair that sees most of the supports (``camera_views``), its score, and
    whether every support surface has a point both cameras see."""
    base_position, base_quat, table_center, table_size = robot
    occluders = Occluders(scene, base_position, base_quat, table_center, table_size)
    weights = None if config.camera_label_weights is None else dict(config.camera_label_weights)
    pair, score, covered = sample_camera_pair(rng, scene, occluders, config.camera_fov_x, config.camera_aspect,
                                              config.camera_tries, label_weights=weights)
    left, right = (CameraPose(canonical_lengths(eye), canonical_quat(look_at_quat(eye, target)), config.camera_fov_x)
                   for eye, target in pair)
    return (left, right), score, covered
