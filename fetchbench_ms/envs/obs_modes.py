"""The env's observation modes: ManiSkill's own, and three of FetchBench's made on top of one
of ManiSkill's (``ObsModes``):

- ``compact_pointcloud``: ManiSkill's ``pointcloud`` underneath, compacted every observation
  (``pointcloud.compact_pointcloud_obs``);
- ``policy_pointcloud``: ManiSkill's position and segmentation textures underneath, made into
  the policies' points (no colour, no camera cloud), its cameras at ``POLICY_CAMERA_SIZE``;
- ``composed_pointcloud``: ManiSkill's ``state_dict`` underneath (no render a step); the cameras
  render once as an episode starts and every observation composes the points from the
  target's and the robot links' poses (``composed.ComposedCloud``).

Also here: the checks of an obs mode (``check_obs_mode``), the cameras' size for a mode, and
what every observation goes through (``own_arrays``).
"""
from __future__ import annotations

from typing import Optional

import numpy as np
import torch
from mani_skill.envs.utils.observations import ALL_VISUAL_TEXTURES
from mani_skill.utils import common
from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

from . import composed, pointcloud
from .composed import ComposedCloud

CAMERA_RESOLUTIONS = ((320, 240), (640, 480))
#: Observation modes that need no renderer (no camera data); every other mode renders.
NO_RENDER_OBS_MODES = ("state", "state_dict", "none")
#: ManiSkill's named obs modes; any "+"-joined combination of camera textures
#: (``ALL_VISUAL_TEXTURES``, optionally with "state" / "state_dict") is accepted too.
NAMED_OBS_MODES = NO_RENDER_OBS_MODES + ("sensor_data", "rgbd", "pointcloud", pointcloud.COMPACT_OBS_MODE,
                                         pointcloud.POLICY_OBS_MODE, pointcloud.COMPOSED_OBS_MODE)
#: What ``policy_pointcloud`` asks ManiSkill for: the two textures its points are made of (no colour).
POLICY_TEXTURES = "position+segmentation"
#: The obs modes ManiSkill's BaseEnv documents (all of them work here; tests sweep them).
MANISKILL_OBS_MODES = ("state", "state_dict", "none", "sensor_data", "rgb", "depth", "segmentation", "rgbd",
                       "rgb+depth", "rgb+depth+segmentation", "rgb+segmentation", "depth+segmentation",
                       "pointcloud")
#: FetchBench's obs modes -> the ManiSkill obs mode each runs on.
UNDERNEATH = {pointcloud.COMPACT_OBS_MODE: "pointcloud", pointcloud.POLICY_OBS_MODE: POLICY_TEXTURES,
              pointcloud.COMPOSED_OBS_MODE: "state_dict"}
#: Observation entries made fresh by every render (large): not copied by ``own_arrays``.
RENDERED_OBS_KEYS = ("sensor_data", "pointcloud")


def camera_size(obs_mode: Optional[str], width: Optional[int], height: Optional[int]) -> tuple[int, int]:
    """The cameras' (width, height): given, or 320x240; ``policy_pointcloud``'s own
    ``POLICY_CAMERA_SIZE`` (its observation is the policies' input, one resolution)."""
    if obs_mode == pointcloud.POLICY_OBS_MODE:
        size = pointcloud.POLICY_CAMERA_SIZE
        if (width, height) not in ((None, None), size):
            raise ValueError(f"obs_mode {obs_mode!r} renders its cameras at {size[0]}x{size[1]}; leave "
                             "camera_width / camera_height unset")
        return size
    width, height = 320 if width is None else width, 240 if height is None else height
    if (width, height) not in CAMERA_RESOLUTIONS:
        valid = ", ".join(f"{w}x{h}" for w, h in CAMERA_RESOLUTIONS)
        raise ValueError(f"camera resolution {width}x{height} is not supported; valid: {valid}")
    return width, height


def obs_mode_needs_renderer(obs_mode: Optional[str]) -> bool:
    """Whether ``obs_mode`` reads the cameras (None: ManiSkill's default, "state")."""
    return obs_mode is not None and obs_mode not in NO_RENDER_OBS_MODES


def check_obs_mode(obs_mode: Optional[str], render_backend: Optional[str] = "gpu") -> None:
    """ValueError naming the valid choices for an obs mode ManiSkill would reject (it
    asserts deep in its parser) or one that cannot work with ``render_backend``: without
    a renderer the cameras are never built and the first observation fails on a missing
    camera (a KeyError), so it is refused here, before anything is built."""
    valid = (f"{', '.join(NAMED_OBS_MODES)}, or camera textures joined by '+' "
             f"({', '.join(ALL_VISUAL_TEXTURES)}; e.g. rgb+depth, optionally with +state or +state_dict)")
    if obs_mode is not None and obs_mode not in NAMED_OBS_MODES:
        parts = obs_mode.split("+")
        textures = [p for p in parts if p in ALL_VISUAL_TEXTURES]
        unknown = [p for p in parts if p not in ALL_VISUAL_TEXTURES and p not in ("state", "state_dict")]
        if unknown or not textures or len(set(parts)) != len(parts):
            raise ValueError(f"unknown obs_mode {obs_mode!r}; valid: {valid}")
    if render_backend in (None, "none") and obs_mode_needs_renderer(obs_mode):
        raise ValueError(f"obs_mode {obs_mode!r} reads the cameras, which need a renderer, but render_backend="
                         f"{render_backend!r}; without a renderer valid obs modes: {', '.join(NO_RENDER_OBS_MODES)} "
                         "(or leave render_backend at its default)")


def own_arrays(obs):
    """``obs`` with every tensor its own copy, but the freshly rendered camera data:
    ManiSkill hands out some buffers as they are (the base pose, camera parameters, on
    CPU the robot's state), so a kept observation would change under its owner's feet
    (gymnasium's data-not-reused check). Small tensors: ~2 us each."""
    if isinstance(obs, torch.Tensor):
        return obs.clone()
    if isinstance(obs, dict):
        return {k: v if k in RENDERED_OBS_KEYS else own_arrays(v) for k, v in obs.items()}
    return obs


def homogeneous(extrinsic: torch.Tensor) -> torch.Tensor:
    """[B, 3, 4] -> [B, 4, 4]."""
    bottom = torch.zeros((extrinsic.shape[0], 1, 4), dtype=extrinsic.dtype, device=extrinsic.device)
    bottom[:, 0, 3] = 1
    return torch.cat([extrinsic, bottom], dim=1)


def T_base_world(env) -> torch.Tensor:
    """[B, 4, 4] world -> robot base of ``env`` (the base is fixed: from the task's base pose)."""
    p_world_base, R_world_base = env._world_base
    T = torch.zeros((env.num_envs, 4, 4), device=p_world_base.device)
    T[:, :3, :3] = R_world_base.transpose(1, 2)
    T[:, :3, 3] = -(R_world_base.transpose(1, 2) @ p_world_base[..., None])[..., 0]
    T[:, 3, 3] = 1
    return T


class ObsModes:
    """The obs mode an env was asked for, the ManiSkill mode it runs on, and what turns
    ManiSkill's observation into the asked mode's (``observation``).

    An object the env holds rather than a mixin: the composed points' state (the store of an
    episode's start, the robot's link points) lives here and not among the env's attributes,
    and the env calls it at three named points only (``__init__``: ``maniskill_obs_mode``;
    a new scene and a new episode: ``after_reconfigure``, ``episodes_start``; ``get_obs``:
    ``observation``), so the layer is read and tested on its own."""

    def __init__(self, asked: Optional[str]):
        self.asked = asked
        #: The ManiSkill obs mode underneath (the asked one when it is ManiSkill's).
        self.maniskill_obs_mode = UNDERNEATH.get(asked, asked)
        self.compact = asked == pointcloud.COMPACT_OBS_MODE
        self.policy = asked == pointcloud.POLICY_OBS_MODE
        self.composed_mode = asked == pointcloud.COMPOSED_OBS_MODE
        #: The composed points' store: ``composed_pointcloud``'s from a new scene on; another camera
        #: mode's from its first ``composed_points`` call (a new scene's: made again).
        self.composed: Optional[ComposedCloud] = None
        self._robot_points: Optional[composed.RobotPoints] = None

    def name(self, maniskill_obs_mode: str) -> str:
        """The env's ``obs_mode``: the asked mode where it is FetchBench's, else ManiSkill's."""
        return self.asked if self.asked in UNDERNEATH else maniskill_obs_mode

    # ------------------------------------------------------------------ the env's hooks
    def after_reconfigure(self, env) -> None:
        """A new scene: ``composed_pointcloud`` keeps a new store; another mode none until asked."""
        self.composed = self._composed_cloud(env) if self.composed_mode else None

    def episodes_start(self, env_idx: torch.Tensor) -> None:
        """These sub-scenes start an episode: their next composed points render."""
        if self.composed is not None:
            self.composed.stale[env_idx.to(self.composed.device)] = True

    def observation(self, env, obs: dict) -> dict:
        """ManiSkill's observation ``obs`` (unflattened) as the asked mode's: the fetch cloud's
        extra fields in ``pointcloud`` (and ``compact_pointcloud``), then compacted, made into
        the policies' points, or composed; every small tensor its own copy."""
        if self.maniskill_obs_mode == "pointcloud":
            pixels = {uid: s.config.width * s.config.height for uid, s in env.scene.sensors.items()}
            pointcloud.add_fetch_pointcloud(obs, env.segmentation_lut, *env._world_base, pixels)
        if self.compact or self.policy:
            steps = common.to_numpy(env.elapsed_steps).reshape(-1)
            seeds = [pointcloud.compact_seed(int(e), int(t)) for e, t in zip(np.atleast_1d(env._episode_seed), steps)]
        if self.compact:
            obs = pointcloud.compact_pointcloud_obs(obs, seeds)
        if self.policy:
            obs = self._policy_pointcloud_obs(env, obs, seeds)
        if self.composed_mode:
            obs["pointcloud"] = self.composed_points(env)
        return own_arrays(obs)

    # ------------------------------------------------------------------ the modes
    def _policy_pointcloud_obs(self, env, obs: dict, seeds: list[int]) -> dict:
        """``obs`` with the cameras' textures replaced by ``obs["pointcloud"]``: the policies'
        points (``points`` [B, N, 3] float16, base frame) and labels (``point_label`` [B, N]
        uint8), made on the render device and moved to the env's."""
        points_base, labels = pointcloud.camera_points_base(obs, env.segmentation_lut, T_base_world(env))
        points, point_label = pointcloud.policy_cloud(points_base, labels, torch.tensor(seeds, dtype=torch.int64))
        out = {k: v for k, v in obs.items() if k != "sensor_data"}
        out["pointcloud"] = {"points": points.to(env.device), "point_label": point_label.to(env.device)}
        return out

    def _composed_cloud(self, env) -> ComposedCloud:
        """The composed clouds' store, with points fixed on this robot's links (its visual
        meshes in the link frames, from the first sub-scene: every sub-scene has the same
        robot; drawn once per env, as the robot stays the same through reconfigurations)."""
        if self._robot_points is None:
            meshes = [(link.generate_mesh(lambda link, shape: True, "fetch_composed_points") or [None])[0]
                      for link in env.agent.robot.links]
            self._robot_points = composed.robot_link_points(meshes, pointcloud.POLICY_CLOUD_SIZES["robot"])
        return ComposedCloud(env.num_envs, self._robot_points, env.device)

    def composed_points(self, env) -> dict:
        """``obs["pointcloud"]`` of ``composed_pointcloud`` (``FetchBenchEnv.composed_pointcloud_obs``):
        the episode-start render of the sub-scenes that start an episode (the cameras' position
        and segmentation textures), then every sub-scene's points placed by the target's and
        the links' current poses."""
        if self.composed is None:
            if not env.scene.can_render():
                raise RuntimeError("composed points render the cameras as an episode starts: this env has no renderer")
            self.composed = self._composed_cloud(env)
        T_base = T_base_world(env)
        T_base_target = T_base @ env.target.pose.to_transformation_matrix()
        stale = torch.nonzero(self.composed.stale).reshape(-1)
        if len(stale):
            # The cameras' pictures now, as ManiSkill's own sensor observation takes them.
            for obj in env._hidden_objects:
                obj.hide_visual()
            env.scene.update_render(update_sensors=True, update_human_render_cameras=False)
            textures = {"sensor_data": {}, "sensor_param": {}}
            for uid, sensor in env.scene.sensors.items():
                sensor.capture()
                textures["sensor_data"][uid] = sensor.get_obs(rgb=False, depth=False, position=True, segmentation=True)
                textures["sensor_param"][uid] = sensor.get_params()
            points_base, labels = pointcloud.camera_points_base(textures, env.segmentation_lut, T_base)
            seeds = torch.tensor([pointcloud.compact_seed(int(e), 0) for e in np.atleast_1d(env._episode_seed)],
                                 dtype=torch.int64)
            rows = stale.to(points_base.device)
            self.composed.start(stale, points_base[rows], labels[rows], seeds[stale.cpu()], T_base_target[stale])
        raw = env._links_raw_pose()
        T_world_links = torch.zeros((*raw.shape[:2], 4, 4), device=raw.device)
        T_world_links[..., :3, :3] = quaternion_to_matrix(raw[..., 3:])
        T_world_links[..., :3, 3] = raw[..., :3]
        T_world_links[..., 3, 3] = 1
        points, point_label = self.composed.compose(T_base_target, T_base[:, None] @ T_world_links)
        return {"points": points.to(env.device), "point_label": point_label.to(env.device)}
