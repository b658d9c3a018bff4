"""FetchBench's three task filters, run on the env (the simulator) for one object arrangement.

An *arrangement* is a scene with its placed, settled objects, robot and cameras: every
object in it can be a task's target. One ``check_arrangement`` call judges all of them
at once, as the original filters every placed object of a scene:

1. **Stable** (the whole arrangement): from the task's start state, 2 s of physics with
   the robot holding its start configuration; every object must have moved < 5 cm and
   be slower than 0.05 m/s at the end (the original: 120 steps at 60 Hz).
2. **Visible** (per object): the object covers more than 500 pixels at 640x480 (the same
   fraction of the image at other resolutions) in *both* of the env's segmentation
   cameras, as rendered at the start state.
3. **Reachable** (per object): a collision-free IK solution of the arm exists for at
   least one annotated grasp of the object, in the oracle mesh world of the start state
   with that object's own collisions ignored (``planning.ik.solve_ik`` with a
   ``CollisionChecker``), seeded from the start configuration.

The env is created once per process (``FilterEnv``) and re-used for every arrangement.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STABLE_SECONDS = 2.0
STABLE_MAX_MOVE = 0.05  # m
STABLE_MAX_SPEED = 0.05  # m/s
VISIBLE_PIXELS_640x480 = 500
VISIBLE_FRACTION = VISIBLE_PIXELS_640x480 / (640 * 480)
FILTER_NAMES = ("stable", "visible", "reachable")


@dataclass(frozen=True)
class ArrangementCheck:
    """Filter results for every object of an arrangement (index = object index)."""

    stable: bool
    max_move: float  # m, largest object displacement after the stability run
    max_speed: float  # m/s, largest object speed at its end
    pixels: np.ndarray  # (N, 2) target pixels in the left / right camera
    min_pixels: int  # the visibility threshold at the camera resolution used
    reachable: dict  # object index -> bool, for the objects that were checked

    def visible(self, k: int) -> bool:
        return bool((self.pixels[k] > self.min_pixels).all())

    def passes(self, k: int) -> bool:
        return self.stable and self.visible(k) and bool(self.reachable.get(k, False))

    def rejection(self, k: int) -> str | None:
        """The first filter object ``k`` fails (stable, visible, reachable), or None."""
        if not self.stable:
            return "stable"
        if not self.visible(k):
            return "visible"
        if not self.reachable.get(k, False):
            return "reachable"
        return None


class FilterEnv:
    """One FetchBench env with segmentation cameras, reused to judge arrangements."""

    def __init__(self, camera_width: int = 320, camera_height: int = 240, num_objects: int = 15,
                 robot_uids: str = "panda", obs_mode: str = "rgb+segmentation"):
        """``robot_uids``: the robot the reachability filter judges for (docs/robots.md);
        ``obs_mode="none"`` when only ``reachable`` is asked (no renderer)."""
        import gymnasium as gym

        import fetchbench_ms  # noqa: F401  (registers the envs)

        extra = {} if robot_uids == "panda" else {"robot_uids": robot_uids}
        self.env = gym.make("FetchBench-v0", obs_mode=obs_mode, camera_width=camera_width,
                            camera_height=camera_height, num_objects=num_objects, **extra)
        self.min_pixels = int(round(VISIBLE_FRACTION * camera_width * camera_height))

    def close(self) -> None:
        self.env.close()

    # -------------------------------------------------------------- the filters
    def load(self, task):
        obs, _ = self.env.reset(options={"task": task})
        return obs

    def pixels(self, obs) -> np.ndarray:
        """(N, 2): pixels of each task object in the left and right camera."""
        u = self.env.unwrapped
        n = len(u.tasks[0].objects)
        ids = [int(u.object_slots[k].per_scene_id[0]) for k in range(n)]
        counts = np.zeros((n, 2), dtype=np.int64)
        for c, side in enumerate(("left", "right")):
            seg = obs["sensor_data"][f"{side}_camera"]["segmentation"][0, ..., 0].cpu().numpy()
            hist = np.bincount(seg.ravel().astype(np.int64), minlength=max(ids) + 1)
            counts[:, c] = hist[ids]
        return counts

    def reachable(self, targets, max_grasps: int = 32, n_seeds: int = 6, seed: int = 0) -> dict:
        """Object index -> whether a collision-free IK solution exists for one of its grasps."""
        from ..planning.checker import CollisionChecker
        from ..planning.ik import solve_ik
        from ..planning.robot import robot_for_env
        from ..grasp_labels.candidates import object_grasps, tcp_from_hand
        from ..planning.world_models import mesh_world, object_poses_base

        u = self.env.unwrapped
        task = u.tasks[0]
        robot = robot_for_env(self.env)
        world = mesh_world(self.env)
        poses = object_poses_base(self.env)
        q_start = u.start_arm_qpos(0)
        hand_from_tcp = np.linalg.inv(tcp_from_hand(np.eye(4)))
        out = {}
        for k in targets:
            group = "target" if k == task.target_index else f"object:{k}"
            checker = CollisionChecker(robot, world, exclude=(group,))
            T_object_hand = object_grasps(task.objects[k].object_id).T_object_hand
            T_tcp = tcp_from_hand(poses[k][None] @ T_object_hand)
            # The open hand alone must be free first (cheap); the closest-to-free grasps first.
            clearance = checker.hand_clearance(T_tcp @ hand_from_tcp)
            free = np.flatnonzero(clearance > 0)
            free = free[np.argsort(-clearance[free], kind="stable")][:max_grasps]
            if len(free) == 0:
                out[k] = False
                continue
            result = solve_ik(robot, T_tcp[free], checker=checker, q_seed=q_start, n_seeds=n_seeds,
                              rng=np.random.default_rng([seed, k]))
            out[k] = bool(result.found)
        return out

    def stability(self) -> tuple[float, float]:
        """(largest displacement m, largest speed m/s) of the objects after ``STABLE_SECONDS``."""
        u = self.env.unwrapped
        n = len(u.tasks[0].objects)
        bodies = [u.object_slots[k]._objs[0] for k in range(n)]
        start = np.array([b.pose.p for b in bodies], dtype=float)
        for _ in range(int(round(STABLE_SECONDS * u.sim_freq))):
            u.scene.step()
        end = np.array([b.pose.p for b in bodies], dtype=float)
        comps = [b.find_component_by_type(_rigid_dynamic()) for b in bodies]
        speed = max(float(np.linalg.norm(c.linear_velocity)) for c in comps)
        return float(np.linalg.norm(end - start, axis=1).max()), speed

    def check(self, task, targets=None, seed: int = 0) -> ArrangementCheck:
        """All three filters for ``task``'s arrangement. ``targets``: the objects whose
        reachability to test (default all); IK, the costly part, runs only for the visible
        ones among them and only when the arrangement is stable."""
        obs = self.load(task)
        pixels = self.pixels(obs)
        max_move, max_speed = self.stability()
        stable = max_move < STABLE_MAX_MOVE and max_speed < STABLE_MAX_SPEED
        if targets is None:
            targets = range(len(task.objects))
        targets = [k for k in targets if (pixels[k] > self.min_pixels).all()]
        reachable = {}
        if stable and targets:
            self.load(task)  # the same task again: back to the start poses, no rebuild
            reachable = self.reachable(targets, seed=seed)
        return ArrangementCheck(
            stable=stable, max_move=max_move, max_speed=max_speed, pixels=pixels, min_pixels=self.min_pixels,
            reachable=reachable,
        )


def _rigid_dynamic():
    import sapien

    return sapien.physx.PhysxRigidDynamicComponent

