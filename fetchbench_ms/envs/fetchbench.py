"""FetchBench-*-v0: fetch one object out of cluttered procedural furniture with a Franka arm
(or another robot of ``fetchbench_ms.robots``: ``robot_uids``, docs/robots.md)."""
from __future__ import annotations

import copy
import dataclasses
import gc
import math
from typing import Any, Optional

import gymnasium as gym
import numpy as np
import sapien
import torch
from mani_skill.agents.robots.panda.panda import Panda
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import common, sapien_utils
from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix
from mani_skill.utils.structs.pose import Pose
from mani_skill.utils.structs.types import GPUMemoryConfig

from ..objects.loading import check_object_source
from ..robots import ROBOT_UIDS, check_robot_uid, robot_setup
from ..robots import agents as _robot_agents  # noqa: F401  (registers the other robots' ManiSkill agents)
from ..scenes import SCENE_TYPES
from ..sim.bodies import default_sim_config
from ..tasks.camera_views import paper_camera_pair
from ..tasks.sampler import SamplerConfig, look_at_quat
from ..tasks.spec import CATEGORY_LABELS, CameraPose, TaskSpec, category_name
from ..utils.canonical import canonical_lengths, canonical_quat
from . import pointcloud, rewards
from .checks import (  # noqa: F401  (control_modes, check_num_envs: public here too)
    check_id_fixes, check_kwarg_names, check_maniskill_kwargs, check_num_envs, check_sim_config, control_modes)
from .contacts import FINGER_REACH, ContactQueries  # noqa: F401  (FINGER_REACH: public here too)
from .curriculum import resolve_curriculum
from .judging import HOLD_SECONDS, SUCCESS_CRITERIA, settle_and_hold, success_flags  # noqa: F401  (public here too)
from .obs_modes import (  # noqa: F401  (the obs modes' names and checks: public here too)
    CAMERA_RESOLUTIONS, MANISKILL_OBS_MODES, NAMED_OBS_MODES, NO_RENDER_OBS_MODES, RENDERED_OBS_KEYS, ObsModes,
    camera_size, check_obs_mode, homogeneous, obs_mode_needs_renderer)
from .options import DEFAULT_CAMERA_PLACEMENT, check_camera_placement, check_sim_freq
from .rewards import (  # noqa: F401  (public here too)
    CONTACT_FORCE, CONTACT_PENALTY, DENSE_REWARD_MAX, DISTURB_PENALTY, REWARD_WEIGHTS)
from .scene_builder import BuiltTasks, build_tasks, initialize_tasks
from .task_source import (  # noqa: F401  (DEFAULT_TASK_SUITE: docs/envs.md names it here too)
    DEFAULT_OBJECT_SPLIT, DEFAULT_TASK_SUITE, OBJECT_SPLITS, TASK_SOURCES, curriculum_category, resolve_task_source,
    sample_task_cached, scene_of, tasks_from_options)

FULL_GC_EVERY = 16  # CPU reconfigures between full garbage collections (see FetchBenchEnv._clear)


class FetchBenchEnv(BaseEnv):
    """
    **Task Description:**
    Fetch a target object out of a cluttered procedural furniture scene (shelves, desks,
    cabinets, drawers, baskets; 13 scene types) with a Franka arm standing on a box robot
    table: grasp the target and carry it out of the furniture into free space in front of
    the robot, without knocking the other objects (about 15 per scene) around.

    **Randomizations:**
    - each episode is a task (``fetchbench_ms.tasks.TaskSpec``) sampled from the episode seed:
      scene type (fixed by the env id or drawn with the paper's scene mix), furniture
      parameters, the objects (catalog **train** split by default; ``object_split="test"``
      for evaluation on sampled tasks), their support label (weights basket .5,
      shelf .3, drawer .3, table .2), position on the eroded support polygon, stable pose and
      yaw; the target among the placed objects (on the env's category if it has one)
    - per object and task (as the paper lists): density U(100, 400) kg/m^3, friction
      U(0.6, 1.2) (static = dynamic), restitution U(0, 0.1); furniture friction 0.5
    - robot base position in the scene type's robot region; robot table size x U(0.4, 0.7) m,
      y U(0.6, 1.0) m; two cameras left and right (mirrored), aimed at the supports
      (``camera_placement``: ``"task"``, the task's pair, chosen by what it sees of the
      supports; ``"paper"``, the original's heuristic, drawn from the task's content)
    - ``curriculum`` (``fetchbench_ms.envs.curriculum``, for RL): fewer objects, targets on
      chosen supports, the robot closer, the arm starting at a pre-grasp configuration
    - ``reset(options={"task": task_dict})`` replays a given task instead (a task of a suite,
      e.g. ``task_suite="test"`` with ``options={"task_id": ...}``, keeps the suite's
      objects, test objects for the test suite); a changed task rebuilds the scene
      (reconfigure)

    **Success Conditions:**
    - the target's centre of mass in the robot-base frame has z > 0.30 m and x < 0.0 m
      (``success_criteria="release"``: z >= 0.28 m, x <= 0.15 m), and
    - every other object's centre of mass moved less than 0.10 m from its start.
    FetchBench judges after a 10 s settle-and-hold with the gripper closed
    (``fetchbench_ms.envs.settle_and_hold``).

    **Observations:** every ManiSkill obs mode (camera modes need a renderer: with
    ``render_backend="none"`` only state, state_dict and none; others raise ValueError).
    ``extra`` holds the TCP pose, the robot base pose and whether the target is grasped; in
    state modes also the target pose, its centre of mass in the base frame and every
    object's pose. In ``pointcloud`` mode the cloud also carries ``xyz_base`` and
    ``fetch_label`` (robot / target / object / furniture, cropped to 0.15-2.5 m depth), see
    ``fetchbench_ms.envs.pointcloud``.

    **Rates:** physics 120 Hz (``sim_freq=60``: the original's 60 Hz), control 20 Hz
    (see ``fetchbench_ms.sim.bodies`` and ``fetchbench_ms.envs.options``).
    """

    SUPPORTED_ROBOTS = list(ROBOT_UIDS)
    # gymnasium's render check wants a frame rate; videos play at the control rate.
    metadata = {**BaseEnv.metadata, "render_fps": default_sim_config().control_freq}
    SUPPORTED_REWARD_MODES = ("normalized_dense", "dense", "sparse", "none")
    agent: Panda

    def __init__(
        self,
        *args,
        robot_uids="panda",
        scene_type: Optional[str] = None,
        category: Optional[str] = None,
        camera_width: Optional[int] = None,
        camera_height: Optional[int] = None,
        success_criteria: str = "paper",
        num_objects: int = 15,
        object_split: str = DEFAULT_OBJECT_SPLIT,
        task_suite: Optional[str] = None,
        task_source: Optional[str] = None,
        robot_init_qpos_noise: float = 0.0,
        curriculum=None,
        sim_freq=None,
        camera_placement: str = DEFAULT_CAMERA_PLACEMENT,
        num_envs: int = 1,
        reconfiguration_freq: Optional[int] = None,
        id_fixes: Optional[dict] = None,
        **kwargs,
    ):
        check_kwarg_names(type(self), kwargs)
        category = category_name(category)  # either vocabulary: Shelf or on_shelf
        check_id_fixes(id_fixes, scene_type=scene_type, category=category)
        if scene_type is not None and scene_type not in SCENE_TYPES:
            raise ValueError(f"unknown scene type {scene_type!r}; valid: {', '.join(SCENE_TYPES)}")
        if success_criteria not in SUCCESS_CRITERIA:
            raise ValueError(f"unknown success_criteria {success_criteria!r}; valid: {', '.join(SUCCESS_CRITERIA)}")
        camera_width, camera_height = camera_size(kwargs.get("obs_mode"), camera_width, camera_height)
        self.robot_setup = robot_setup(check_robot_uid(robot_uids))
        if object_split not in OBJECT_SPLITS:
            raise ValueError(f"unknown object_split {object_split!r}; valid: {', '.join(OBJECT_SPLITS)}")
        if task_source is not None and task_source not in TASK_SOURCES:
            raise ValueError(f"unknown task_source {task_source!r}; valid: {', '.join(TASK_SOURCES)}")
        self.camera_placement = check_camera_placement(camera_placement)
        # None: 120 Hz, or the rate ManiSkill's ``sim_config`` sets (it overrides the defaults).
        self._sim_freq_kwarg = None if sim_freq is None else check_sim_freq(sim_freq)
        check_sim_config(self._sim_freq_kwarg, kwargs.get("sim_config"))
        check_maniskill_kwargs(type(self), kwargs)
        check_num_envs(num_envs, kwargs.get("sim_backend", "auto"))
        # FetchBench's obs modes run on one of ManiSkill's (envs/obs_modes.py).
        self.obs_modes = ObsModes(kwargs.get("obs_mode"))
        if self.obs_modes.asked != self.obs_modes.maniskill_obs_mode:
            kwargs["obs_mode"] = self.obs_modes.maniskill_obs_mode
        self.scene_type = scene_type
        self.category = category
        self.camera_size = (camera_width, camera_height)
        self.success_criteria = success_criteria
        self.curriculum = resolve_curriculum(curriculum)
        self.task_source_kwarg = task_source
        self._sample_category = curriculum_category(self.curriculum, category, task_source)
        self.sampler_config = SamplerConfig(num_objects=num_objects, object_split=object_split)
        self.task_source, self.task_suite, self._suite_pool = resolve_task_source(
            task_source, task_suite, object_split, scene_type, category, self.curriculum)
        self._task_ids: Optional[list[Optional[str]]] = None
        self.robot_init_qpos_noise = robot_init_qpos_noise
        self._tasks: Optional[list[TaskSpec]] = None
        self._pending_tasks: Optional[list[TaskSpec]] = None
        self._pending_ids: Optional[list[Optional[str]]] = None
        self.built: Optional[BuiltTasks] = None
        if reconfiguration_freq is None:
            # CPU: the content follows the task of each reset (a new task reconfigures).
            # GPU: new tasks only when asked (reconfigure=True) unless set here.
            reconfiguration_freq = 0
        super().__init__(*args, robot_uids=robot_uids, num_envs=num_envs,
                         reconfiguration_freq=reconfiguration_freq, **kwargs)

    # ------------------------------------------------------------------ configuration
    @property
    def _default_sim_config(self):
        config = default_sim_config()
        if self._sim_freq_kwarg is not None:  # control stays at 20 Hz: 6 or 3 physics steps an action
            config.sim_freq = self._sim_freq_kwarg
        # Many contacts per sub-scene (15 objects in furniture): room for them on GPU.
        config.gpu_memory_config = GPUMemoryConfig(
            max_rigid_contact_count=2**22, max_rigid_patch_count=2**20, found_lost_pairs_capacity=2**26
        )
        return config

    @property
    def tasks(self) -> list[TaskSpec]:
        """The task of each sub-scene in the current episode."""
        return list(self._tasks)

    @property
    def camera_poses(self) -> list[tuple[CameraPose, CameraPose]]:
        """The (left, right) camera of each sub-scene in the current episode: the task's
        (``camera_placement="task"``) or the original's heuristic drawn for the task
        (``"paper"``)."""
        return list(self._camera_poses)

    @property
    def task_ids(self) -> list[Optional[str]]:
        """The suite id of each sub-scene's task (None for a sampled or given task)."""
        return list(self._task_ids)

    @property
    def _default_sensor_configs(self):
        width, height = self.camera_size
        fov_x = self._tasks[0].camera_left.fov_x
        fov_y = 2 * math.atan(math.tan(fov_x / 2) * height / width)
        return [
            CameraConfig(f"{side}_camera", sapien.Pose(), width, height, fov_y, 0.01, 10.0,
                         mount=self.built.camera_mounts[side])
            for side in ("left", "right")
        ]

    @property
    def _default_human_render_camera_configs(self):
        task, spec = self._tasks[0], self._scene_specs[0]
        base = np.asarray(task.robot_base_position)
        target = np.asarray(spec.camera_target.center)
        eye = base + np.array([-0.9, 1.3, 0.9])
        pose = sapien_utils.look_at(eye=eye.tolist(), target=target.tolist())
        return CameraConfig("render_camera", pose, 512, 512, 1.0, 0.01, 20.0)

    # ------------------------------------------------------------------ episodes
    def reset(self, seed=None, options=None):
        """``seed`` samples a task per sub-scene; ``options`` may give ``task`` (a TaskSpec
        dict, for every sub-scene), ``tasks`` (one dict per sub-scene) or ``task_id`` (a
        task of the env's ``task_suite``). A task other than the loaded one reconfigures.
        On GPU (num_envs > 1) a seed samples new tasks only when reconfiguring
        (``reconfigure=True`` or ``reconfiguration_freq``); otherwise the loaded tasks restart."""
        if seed is not None:
            self._seed_np_random(seed)
        options = dict(options) if options else {}
        partial = "env_idx" in options and len(options["env_idx"]) != self.num_envs
        tasks = tasks_from_options(options, self.task_suite, self.num_envs)
        if tasks is not None and self.curriculum is not None:
            tasks = [self.curriculum.apply(t) for t in tasks]
        ids = [options["task_id"]] * self.num_envs if "task_id" in options else [None] * self.num_envs
        if tasks is not None and partial and tasks != [self._tasks[int(i)] for i in options["env_idx"]]:
            raise ValueError("a partial reset (env_idx) cannot load new tasks; reset all sub-scenes to change tasks")
        reconfiguring = (
            bool(options.get("reconfigure")) or self._tasks is None
            or (self._reconfig_counter == 0 and self.reconfiguration_freq != 0)
        )
        if tasks is None and not partial and (self.num_envs == 1 or reconfiguring):
            if seed is None:
                # Draw the episode seed here (from ManiSkill's main RNG) so the recorded
                # seed alone rebuilds the task.
                seed = [int(s) for s in np.atleast_1d(self._batched_main_rng.randint(2**31))]
            seeds = self._episode_seeds(seed)
            if self.task_source == "suite":
                ids = [self.suite_task_id(s) for s in seeds]
                tasks = [self.task_suite.get(i) for i in ids]
            else:
                tasks = [self._sample_task(s) for s in seeds]
            if self.curriculum is not None:
                tasks = [self.curriculum.apply(t) for t in tasks]
        if tasks is not None and not partial and tasks != self._tasks:
            for task in tasks:  # before anything is torn down: a refused task leaves the env as it was
                self._check_task(task)
            options["reconfigure"] = True
            self._pending_tasks, self._pending_ids = tasks, ids
        return super().reset(seed=seed, options=options)

    def _seed_np_random(self, seed) -> None:
        """Seed gymnasium's ``np_random`` from the reset seed, as ``gymnasium.Env.reset`` does.

        ManiSkill seeds its own main / episode RNGs and never calls ``gymnasium.Env.reset``,
        so ``env.np_random`` would otherwise be seeded from OS entropy on first use: code
        (wrappers, methods) drawing from it would not repeat, and gymnasium's checker
        rejects the env. The env itself draws nothing from it."""
        seeds = [int(s) for s in np.atleast_1d(np.asarray(seed, dtype=np.int64))]
        if len(seeds) == 1:
            gym.Env.reset(self, seed=seeds[0])
        else:  # one seed per sub-scene: one generator from all of them
            self._np_random = np.random.Generator(np.random.PCG64(np.random.SeedSequence(seeds)))
            self._np_random_seed = seeds[0]

    def _episode_seeds(self, seed) -> list[int]:
        """The per-sub-scene episode seeds ManiSkill derives from ``seed``."""
        seeds = [int(s) for s in np.atleast_1d(np.asarray(seed, dtype=np.int64))]
        if len(seeds) == 1 and self.num_envs > 1:
            seeds += np.random.RandomState(seeds[0]).randint(2**31, size=self.num_envs - 1).tolist()
        if len(seeds) != self.num_envs:
            raise ValueError(f"got {len(seeds)} seeds for {self.num_envs} sub-scenes; give 1 or {self.num_envs}")
        return seeds

    def suite_task_id(self, seed: int) -> str:
        """The id of the suite task a seed picks (``task_source="suite"``): uniform over the
        suite's tasks of this env's scene type / category, from the seed alone."""
        return self._suite_pool[int(np.random.default_rng(seed).integers(len(self._suite_pool)))]

    def _sample_task(self, seed: int) -> TaskSpec:
        # A copy: a TaskSpec's dict fields (scene_params, extra) could be changed by a caller.
        return copy.deepcopy(sample_task_cached(seed, self.scene_type, self._sample_category, self.sampler_config))

    def _check_task(self, task: TaskSpec) -> None:
        check_object_source(task.object_source)
        if self.scene_type is not None and task.scene_type != self.scene_type:
            raise ValueError(f"task is in a {task.scene_type} scene but this env is for {self.scene_type} scenes")
        if self.category is not None and task.target_label != CATEGORY_LABELS[self.category]:
            raise ValueError(f"task's target is {task.target_label} but this env is for {self.category} targets "
                             f"({CATEGORY_LABELS[self.category]})")

    def _clear(self):
        """ManiSkill's ``_clear``, without its full garbage collection on every CPU
        reconfigure: with the catalog and suites loaded a full collection takes ~0.3 s, the
        larger part of loading a new task. A young-generation collection runs every time
        and a full one every ``FULL_GC_EVERY`` rebuilds (and on close and on GPU, where it
        frees GPU memory), so old scenes are freed all the same."""
        self._rebuilds = getattr(self, "_rebuilds", 0) + 1
        if getattr(self, "scene", None) is None or self.gpu_sim_enabled or self._rebuilds % FULL_GC_EVERY == 0:
            return super()._clear()
        self._close_viewer()
        self.agent = None
        self._sensors = dict()
        self._human_render_cameras = dict()
        self.scene = None
        self._hidden_objects = []
        gc.collect(1)

    def close(self):
        BaseEnv._clear(self)  # with the full collection

    def set_state_dict(self, state: dict, env_idx: torch.Tensor = None):
        """ManiSkill's, plus what its state leaves out: whether an object was asleep. PhysX
        reports exactly zero velocity for a sleeping body (an awake one at rest jitters at
        ~1e-3 m/s), and setting a pose wakes a body up, so without this a replayed resting
        object would start to jitter (and a precarious one to slide) where the recording
        had it still. On CPU an object whose recorded velocities are all zero goes back to
        sleep; the next contact wakes it as in the recording. (Not at an episode's first
        step: after a reset the objects are awake at zero velocity, and so they stay.)"""
        super().set_state_dict(state, env_idx)
        if self.gpu_sim_enabled or int(self.elapsed_steps.max()) == 0:
            return
        actors = state.get("actors", {})
        for slot in self.object_slots:
            values = actors.get(slot.name)
            if values is None:
                continue
            velocities = common.to_numpy(values).reshape(-1, 13)[0, 7:13]
            if not np.any(velocities):
                slot._objs[0].find_component_by_type(sapien.physx.PhysxRigidDynamicComponent).put_to_sleep()

    def _load_agent(self, options: dict):
        base = torch.tensor([list(t.robot_base_position) + list(t.robot_base_quat_wxyz) for t in self._pending_tasks])
        super()._load_agent(options, Pose.create(base))

    def _load_scene(self, options: dict):
        self._tasks = self._pending_tasks
        self._task_ids = self._pending_ids
        self._task_filtered = torch.tensor([i is not None for i in self._task_ids], device=self.device)
        self._scene_specs = [scene_of(t) for t in self._tasks]
        # Render meshes only where something can show them: a camera obs mode or a render
        # mode (with state obs and no render_mode, skipping them saves ~0.1 s a new task).
        with_visual = obs_mode_needs_renderer(self.obs_mode) or self.render_mode is not None
        if self.camera_placement == "paper":
            width, height = self.camera_size
            self._camera_poses = [paper_camera_poses(t, spec, width / height)
                                  for t, spec in zip(self._tasks, self._scene_specs)]
            # Built from copies with those cameras: ``self._tasks`` stay the tasks given.
            built_tasks = [dataclasses.replace(t, camera_left=left, camera_right=right)
                           for t, (left, right) in zip(self._tasks, self._camera_poses)]
        else:
            self._camera_poses = [(t.camera_left, t.camera_right) for t in self._tasks]
            built_tasks = self._tasks
        self.built = build_tasks(self, built_tasks, self._scene_specs, min_slots=self.sampler_config.num_objects,
                                 with_visual=with_visual)
        self.object_slots = self.built.slots
        self.target = self.built.target

    def _after_reconfigure(self, options: dict):
        b = self.built
        robot_ids = [link.per_scene_id for link in self.agent.robot.links]
        object_ids = torch.stack([slot.per_scene_id for slot in b.slots], dim=1).to(self.device)
        object_ids = torch.where(b.valid, object_ids, torch.full_like(object_ids, -1))
        furniture_ids = [torch.stack([a.per_scene_id[0] for a in b.furniture]),
                         torch.stack([a.per_scene_id[0] for a in b.robot_tables])]
        furniture_ids += [a.per_scene_id for name, a in self.scene.actors.items() if name == "ground"]
        max_id = 1 + max(int(i.max()) for i in robot_ids + furniture_ids + [object_ids])
        self.segmentation_lut = pointcloud.segmentation_lut(
            max_id, robot_ids, self.target.per_scene_id, object_ids, furniture_ids, self.num_envs, self.device
        )
        # Displacements are measured from the task's (settled) start poses.
        self._initial_com_world = self._com_world(b.initial_pose)
        # The base is the articulation's fixed root, placed by the task: its frame is constant.
        self._world_base = (b.base_pose[:, :3], quaternion_to_matrix(b.base_pose[:, 3:]))
        self.contact_queries = ContactQueries(self)
        self.obs_modes.after_reconfigure(self)

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            b = self.built
            initialize_tasks(b, env_idx)
            if self.robot_setup.uid == "panda":
                qpos = torch.tensor([list(self._tasks[int(i)].robot_init_qpos) for i in env_idx], dtype=torch.float32)
            else:  # the robot's own start configuration (its TCP where the Panda's starts)
                rest = self.agent.keyframes["rest"].qpos
                qpos = torch.tensor(np.tile(rest, (len(env_idx), 1)), dtype=torch.float32)
            if self.robot_init_qpos_noise > 0:
                noise = self._batched_episode_rng[common.to_numpy(env_idx)].normal(0, self.robot_init_qpos_noise, 7)
                qpos[:, :7] += torch.tensor(noise, dtype=torch.float32).reshape(len(env_idx), 7)
            self.agent.reset(qpos)
            self.agent.robot.set_root_pose(Pose.create(b.base_pose[env_idx]))
            self.obs_modes.episodes_start(env_idx)  # (composed points: these episodes' first observation renders)

    def start_arm_qpos(self, env_idx: int = 0) -> np.ndarray:
        """The arm's start configuration of sub-scene ``env_idx`` (7,): the task's on the
        Panda, the robot's own start (``RobotSetup.q_home``) on the others."""
        if self.robot_setup.uid == "panda":
            return np.asarray(self._tasks[env_idx].robot_init_qpos[:7], dtype=float)
        return np.asarray(self.robot_setup.q_home, dtype=float)

    # ------------------------------------------------------------------ evaluation
    def _com_world(self, raw_pose: torch.Tensor) -> torch.Tensor:
        """[B, S, 3] centres of mass of the object slots from their raw poses [B, S, 7]."""
        R = quaternion_to_matrix(raw_pose[..., 3:])  # [B, S, 3, 3]
        return raw_pose[..., :3] + (R @ self.built.com_local[..., None])[..., 0]

    def _objects_raw_pose(self) -> torch.Tensor:
        """[B, S, 7] poses of the object slots."""
        if self.gpu_sim_enabled:
            return torch.stack([slot.pose.raw_pose for slot in self.object_slots], dim=1)
        # CPU (one sub-scene): read the bodies directly; building a ManiSkill Pose per
        # slot costs more than the whole physics step.
        poses = [slot._objs[0].pose for slot in self.object_slots]
        raw = np.array([np.concatenate([p.p, p.q]) for p in poses], dtype=np.float32)
        return torch.from_numpy(raw)[None]

    def _links_raw_pose(self) -> torch.Tensor:
        """[B, L, 7] poses of the robot's links (``self.agent.robot.links`` order)."""
        if self.gpu_sim_enabled:
            return torch.stack([link.pose.raw_pose for link in self.agent.robot.links], dim=1)
        # CPU: the bodies' poses directly, as _objects_raw_pose (a Pose per link costs ~10x more).
        poses = [link._objs[0].entity_pose for link in self.agent.robot.links]
        return torch.from_numpy(np.array([np.concatenate([p.p, p.q]) for p in poses], dtype=np.float32))[None]

    def _contact_forces_cpu(self, furniture: bool = True) -> dict:
        """One pass over the CPU contact list (``ContactQueries.forces_cpu``)."""
        return self.contact_queries.forces_cpu(self, furniture)

    def evaluate(self):
        b = self.built
        raw_pose = self._objects_raw_pose()
        com_world = self._com_world(raw_pose)
        rows = torch.arange(self.num_envs, device=self.device)
        target_com_world = com_world[rows, b.target_index]
        target_com_base = pointcloud.world_to_frame(target_com_world[:, None], *self._world_base)[:, 0]
        moved = torch.linalg.norm(com_world - self._initial_com_world, dim=-1)
        others = b.valid.clone()
        others[rows, b.target_index] = False
        max_others_moved = torch.where(others, moved, torch.zeros_like(moved)).max(dim=1).values
        flags = success_flags(self.success_criteria, target_com_base, max_others_moved)
        extra = {}
        contacts = None
        if self.reward_mode in ("dense", "normalized_dense"):
            # The reward's furniture contacts, from the same pass as the grasp test on CPU.
            if self.gpu_sim_enabled:
                extra["robot_furniture_force"] = self.contact_queries.robot_furniture_force_gpu(self)
            else:
                contacts = self.contact_queries.forces_cpu(self)
                extra["robot_furniture_force"] = contacts["robot_furniture_force"]
        if self.reward_mode != "none" or self.obs_mode != "none":
            # The grasp test walks the contact list at every step once the hand is near the
            # target (on CPU about as long as the rest of evaluate); the rewards and the
            # observations read it, so an env with neither (the demo generator's) leaves it out.
            extra["is_grasped"] = self.contact_queries.is_grasping(self, target_com_world, contacts)
        return dict(
            objects_pose=raw_pose,
            success=flags["success"],
            target_com_base=target_com_base,
            target_height=target_com_base[:, 2],
            target_lift=target_com_world[:, 2] - self._initial_com_world[rows, b.target_index, 2],
            target_moved=moved[rows, b.target_index],
            max_others_moved=max_others_moved,
            # The target's centre of mass above the success height (not "lifted from its
            # start": a target on a high shelf starts above it; ``target_lift`` is the rise).
            is_above_height=flags["is_above_height"],
            is_retrieved=flags["is_retrieved"],
            others_undisturbed=flags["others_undisturbed"],
            task_filtered=self._task_filtered.clone(),
            **extra,
        )

    # ------------------------------------------------------------------ observations
    def _get_obs_extra(self, info: dict):
        obs = dict(
            tcp_pose=self.agent.tcp.pose.raw_pose,
            base_pose=self.built.base_pose,
            is_grasped=info["is_grasped"],
        )
        if self.obs_mode_struct.state or self.obs_mode in ("state", "state_dict"):
            raw = info["objects_pose"]
            obs.update(
                target_pose=self.target.pose.raw_pose,
                target_com_base=info["target_com_base"],
                tcp_to_target=self.target.pose.p - self.agent.tcp.pose.p,
                objects_pose=raw.reshape(self.num_envs, -1),
                objects_valid=self.built.valid.float(),
            )
        # (composed_pointcloud reads no camera a step: its points are in the base frame already)
        if self.obs_mode not in ("state", "state_dict", "none", pointcloud.COMPOSED_OBS_MODE):
            obs["target_segmentation_id"] = self.target.per_scene_id.to(self.device)
            base_inv = self.agent.robot.pose.inv().to_transformation_matrix()  # [B, 4, 4]
            for side in ("left", "right"):
                params = self.scene.sensors[f"{side}_camera"].get_params()
                cam2world = torch.linalg.inv(homogeneous(params["extrinsic_cv"].to(self.device)))
                obs[f"cam_pose_base_{side}"] = (base_inv @ cam2world).reshape(self.num_envs, 16)
                obs[f"cam_intrinsic_{side}"] = params["intrinsic_cv"].to(self.device).reshape(self.num_envs, 9)
        return obs

    def get_obs(self, info: Optional[dict] = None, unflattened: bool = False):
        obs = self.obs_modes.observation(self, super().get_obs(info, unflattened=True))
        return obs if unflattened else self._flatten_raw_obs(obs)

    def composed_pointcloud_obs(self) -> dict:
        """``obs["pointcloud"]`` of ``composed_pointcloud``: the episode-start render of the
        sub-scenes that start an episode (the cameras' position and segmentation textures),
        then every sub-scene's points placed by the target's and the links' current poses.

        Also callable in the other camera modes (a hybrid method whose policy reads these
        points while the env renders full clouds for its grasp network): the first call after
        a reset takes the episode's start, so call it before anything moves."""
        return self.obs_modes.composed_points(self)

    @property
    def obs_mode(self) -> str:
        """The obs mode asked for (``compact_pointcloud`` is ManiSkill's ``pointcloud`` underneath,
        ``policy_pointcloud`` its position and segmentation textures, ``composed_pointcloud``
        ManiSkill's ``state_dict`` with a render as an episode starts: ``envs/obs_modes.py``)."""
        return self.obs_modes.name(super().obs_mode)

    # ------------------------------------------------------------------ rewards (envs/rewards.py)
    def target_surface_distance(self) -> torch.Tensor:
        """[B] distance from the TCP to the nearest of the target's surface points."""
        return rewards.target_surface_distance(self)

    def reward_terms(self, info: dict) -> dict[str, torch.Tensor]:
        """The dense reward's parts, each [B] in [0, 1] (``rewards.reward_terms``, docs/rl.md)."""
        return rewards.reward_terms(self, info)

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """The weighted stages times the penalty factor, in [0, 6]; 6 on success (``rewards.dense_reward``)."""
        return rewards.dense_reward(self, info)

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        """The dense reward over its maximum: in [0, 1]."""
        return self.compute_dense_reward(obs=obs, action=action, info=info) / DENSE_REWARD_MAX

#: Mixed into the seed of ``paper_camera_poses``, so its draws are its own.
PAPER_CAMERA_SALT = 0x70617065  # "pape"


def paper_camera_poses(task: TaskSpec, scene, aspect: float = 4.0 / 3.0) -> tuple[CameraPose, CameraPose]:
    """The (left, right) cameras of the original's heuristic for ``task``
    (``camera_views.paper_camera_pair``) in the furniture ``scene`` (``task.scene()``),
    with the task's horizontal FOV. Drawn from a generator seeded by the task's content
    hash, so the same task always gets the same pair."""
    fov_x = task.camera_left.fov_x
    rng = np.random.default_rng([PAPER_CAMERA_SALT, int(task.content_hash()[:16], 16)])
    pair, _ = paper_camera_pair(rng, scene, fov_x, aspect)
    left, right = (CameraPose(canonical_lengths(eye), canonical_quat(look_at_quat(eye, target)), fov_x)
                   for eye, target in pair)
    return left, right
