"""How a run's method is resolved, and how one task is run in a worker.

``resolve_run`` turns a method's name and the run's options into a ``method_spec.RunSpec``,
once, at the edge (``fetchbench eval``, ``evaluate``), and checks everything that can be
checked before a task runs (options that do not apply, missing weights or checkpoints, a
robot the method was not trained for). Workers receive that spec (``TaskRunner``) and run
``run(env, seed) -> dict`` on an env already reset to the task: the sense-plan-act
pipeline, a policy, a hybrid, ``idle`` (the arm holds its start configuration through the
episode and the env judges: a lower bound, and a cheap deterministic method for testing the
runner), or any importable ``module:function`` with that signature (its ``obs_mode``
attribute, default ``"none"``), so a new solution is evaluated without touching this file.
"""
from __future__ import annotations

import hashlib
import json
import re
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from ..method_spec import IMPROVEMENTS, PANDA_ONLY, MethodSpec, RunSpec, load, method_spec, registry
from .worker_caches import release_between_tasks

#: Objects of the tasks an env id samples from seeds (``--env ID --episodes N``): those
#: runs are evaluations, so test objects, as the suites use. The envs' own default is the
#: train split (safe for learning); suite tasks carry their objects and ignore this.
SAMPLED_TASK_SPLIT = "test"
ERROR_FAILURE = "error"  # the failure class of a task that crashed or timed out
#: s a worker may take to make and reset a task's env (before the method runs) when the task
#: time limit is shorter: the limit counts the method's run, from its start in the worker, so
#: a machine's load (a slow env build) does not turn a task's outcome into a timeout.
ENV_BUILD_LIMIT = 300.0


def setup_limit(task_timeout: float) -> float:
    """s a task may spend before its method starts (making and resetting its env)."""
    return max(task_timeout, ENV_BUILD_LIMIT)


def timeout_message(method_started: bool, task_timeout: float) -> str:
    """The message of a timeout record: the method's limit, or the env build's before it."""
    if method_started:
        return f"ran past the task time limit of {task_timeout:g} s"
    return f"took longer than {setup_limit(task_timeout):g} s to make and reset its env"


@dataclass(frozen=True)
class WorkItem:
    """One task to run: a suite task (``task`` is its TaskSpec dict) or a seed of an env id."""

    task_id: str
    seed: int
    env_id: str = "FetchBench-v0"
    task: Optional[dict] = None

    def describe(self) -> dict:
        """Scene type and category, known before the task runs (for error records)."""
        if self.task is None:
            return {}
        from ..tasks.spec import TaskSpec

        task = TaskSpec.from_dict(self.task)
        return {"scene_type": task.scene_type, "category": task.target_label, "target_object": task.target.object_id}


def task_seed(task_id: str) -> int:
    """The method's seed for a suite task: fixed by the id, whatever the selection or order."""
    return int(hashlib.sha256(task_id.encode()).hexdigest()[:8], 16) % 2**31


@dataclass(frozen=True)
class Method:
    name: str
    obs_mode: str
    run: Callable  # run(env, seed) -> record dict


def resolve_method(name: str) -> MethodSpec:
    """The method a name stands for: a built-in one (``method_spec.registry()``), or an
    importable ``module:function`` (Panda only; the env of its ``obs_mode`` attribute)."""
    if ":" not in name:
        return method_spec(name)
    try:
        fn = load(name)
    except (ImportError, AttributeError, ValueError) as error:
        module, _, attr = name.partition(":")
        raise ValueError(f"method {name!r}: cannot import {attr!r} from {module!r} ({error})") from error
    return MethodSpec(name, robots=PANDA_ONLY, obs_mode=getattr(fn, "obs_mode", "none"), entry=name)


def check_robot(method: MethodSpec, robot: str) -> str:
    """``robot`` (a ``fetchbench_ms.robots`` uid) if ``method`` runs on it; ValueError
    otherwise. Every sense-plan-act method plans for any robot; the learned policies and the
    learned scene-collision network were trained on the Panda only."""
    from ..robots import check_robot_uid

    robot = check_robot_uid(robot)
    if method.robots is None or robot in method.robots:
        return robot
    why = ("other robots run the sense-plan-act methods only" if method.family == "custom"
           else "its network was trained on the Panda")
    valid = [m.name for m in registry().values() if m.family == "sense_plan_act" and m.robots is None]
    raise ValueError(f"{method.name} runs on the Panda only ({why}); on robot {robot!r} valid methods: "
                     f"{', '.join(valid)}")


def resolve_run(method: MethodSpec | str, retries: int = 1, grasp_model: str = "pretrained",
                policy_checkpoint: Optional[str] = None, policy_stride: int = 1, improvements=(),
                grasp_labels: Optional[str] = None, planner_options: Optional[dict] = None,
                env_options: Optional[dict] = None, robot: str = "panda",
                video_dir: Optional[str] = None) -> RunSpec:
    """The run of ``method`` (its spec, or a name for ``resolve_method``) with these options,
    checked: ``grasp_model``: the Contact-GraspNet weight set of the ``cgn-*`` methods;
    ``policy_checkpoint``: the imitation methods' checkpoint (default: the shipped one);
    ``policy_stride``: their control steps per observation (``ImitationPolicy``);
    ``improvements``: the sense-plan-act pipeline's (``method_spec.IMPROVEMENTS``; none: the
    paper's pipeline); ``grasp_labels``: the annotated grasps' store (None: the shipped
    labels); ``planner_options``: planner parameters of the ablation
    (``solutions.planner_options``); ``env_options``: env kwargs of the ablation
    (``fetchbench_ms.envs.parse_env_options``); ``robot``: the hardware setup. Options that
    do not apply, unknown values, missing weights or checkpoints: a clear error here, before
    any task runs (the cheap checks first: no torch loads for a bad option)."""
    from ..solutions.planner_options import check_planner_options

    spec = method if isinstance(method, MethodSpec) else resolve_method(method)
    improvements = tuple(improvements)
    unknown = [i for i in improvements if i not in IMPROVEMENTS]
    if unknown:
        raise ValueError(f"unknown improvement {unknown[0]!r}; valid: {', '.join(IMPROVEMENTS)}")
    if improvements and not spec.has_pipeline:
        pipelines = [m.name for m in registry().values() if m.family == "sense_plan_act"]
        raise ValueError(f"{spec.name} runs no sense-plan-act pipeline: --pipeline ours applies to "
                         f"{', '.join(pipelines)} and the cgn-imit-* hybrids")
    planner_options = check_planner_options(spec, planner_options or {})
    robot = check_robot(spec, robot)
    if grasp_labels is not None:
        if spec.family != "sense_plan_act" or spec.grasps != "annotated":
            annotated = [m.name for m in registry().values() if m.family == "sense_plan_act" and m.grasps == "annotated"]
            raise ValueError(f"--grasp-labels applies to the annotated-grasp methods ({', '.join(annotated)}), "
                             f"not {spec.name}")
        from ..grasp_labels.store import GraspStore

        grasp_labels = str(Path(grasp_labels).resolve())
        GraspStore(grasp_labels)  # no manifest there: a clear error before any task runs
    if spec.grasps == "cgn":
        from ..grasp_prediction import load_model

        load_model(grasp_model)  # unknown or missing weights: a clear error before any task runs
    if (planner_options.get("mppi_cost") or spec.collision) == "network":
        if spec.world != "pointcloud":
            raise ValueError(f"{spec.name} plans in the meshes, and the network cost reads an observed point "
                             f"cloud: valid mppi_cost there: distance")
        from ..planning.collision_net import load_collision_net

        load_collision_net()  # no trained scene-collision network: a clear error before any task runs
    obs_mode = spec.obs_mode
    if spec.policy is not None:
        from ..policies import deploy
        from ..policies.agent import check_stride

        # missing: the error says how to train one; unreadable or of another kind: a usage
        # error here, before any task runs (not one error record per task)
        deploy.check_checkpoint(spec, policy_checkpoint)
        check_stride(policy_stride)
        obs_mode = deploy.policy_obs_mode(spec, policy_checkpoint)
    return RunSpec(spec, obs_mode, retries, grasp_model,
                   str(Path(policy_checkpoint).resolve()) if policy_checkpoint is not None else None,
                   policy_stride, improvements, grasp_labels, tuple(sorted(planner_options.items())),
                   tuple(sorted((env_options or {}).items())), robot, video_dir)


def method_runner(run: RunSpec) -> Callable:
    """``run(env, seed) -> record`` of a resolved run: what its spec says runs, no look-up."""
    family = run.method.family
    if family == "sense_plan_act":
        from ..solutions import sense_plan_act

        config = sense_plan_act.SolveConfig.for_run(run)
        return lambda env, seed: sense_plan_act.solve(env, seed=seed, method=run.method, retries=run.retries,
                                                      reset=False, config=config)
    if family in ("policy", "hybrid"):
        from ..policies import deploy

        if family == "hybrid":
            return lambda env, seed: deploy.run_hybrid(env, seed, run)
        return lambda env, seed: deploy.run_e2e(env, seed, run)
    if family == "custom":
        return load(run.method.entry)
    return run_idle


def run_idle(env, seed) -> dict:
    """Hold the start configuration with the gripper open, then FetchBench's judge (a failed
    episode is ``not_attempted``)."""
    from ..envs.judging import judge

    return {**judge(env, "not_attempted").record_fields(), "computation_time": 0.0, "cspace_length": 0.0,
            "phases": {}}


VIDEO_EVERY = 8  # control steps between video frames (0.4 s at 20 Hz)
VIDEO_SIZE = 256  # px, square


class TaskRunner:
    """Runs work items of one method in this process, keeping one env per (env id, obs mode)."""

    def __init__(self, run: RunSpec):
        self.run = run
        self.method = Method(run.name, run.obs_mode, method_runner(run))
        self.video_dir = run.video_dir
        self.robot = run.robot
        self.env_options = dict(run.env_options)
        self.envs: dict = {}
        # time.monotonic() when the current task's method started (its env made and reset),
        # None between methods; ``on_method_start(item)`` is told at that moment. The task
        # time limit counts from there (the backends' deadlines).
        self.method_started: Optional[float] = None
        self.current_item: Optional[WorkItem] = None  # the task being run, None between tasks
        self.on_method_start: Optional[Callable[[WorkItem], None]] = None

    def method_elapsed(self) -> Optional[float]:
        """s since the current task's method started; None while none runs."""
        started = self.method_started
        return None if started is None else time.monotonic() - started

    def env(self, env_id: str):
        from ..envs import make

        key = (env_id, self.method.obs_mode)
        if key not in self.envs:
            extra = {"render_mode": "rgb_array"} if self.video_dir else {}
            if self.robot != "panda":  # (the Panda's envs are made as they always were)
                extra["robot_uids"] = self.robot
            self.envs[key] = make(env_id, obs_mode=self.method.obs_mode, control_mode="pd_joint_pos",
                                  object_split=SAMPLED_TASK_SPLIT, **self.env_options, **extra)
        return self.envs[key]

    def close(self) -> None:
        for env in self.envs.values():
            try:
                env.close()
            except Exception:  # noqa: BLE001 - a broken env is dropped whatever it says
                pass
        self.envs.clear()

    def __call__(self, item: WorkItem) -> dict:
        t = time.perf_counter()
        self.current_item = item
        try:
            env = self.current_env = self.env(item.env_id)  # (the worker's progress reports read its steps)
            options = {"task": item.task} if item.task is not None else None
            env.reset(seed=item.seed, options=options)
            self.method_started = time.monotonic()
            if self.on_method_start is not None:
                self.on_method_start(item)
            if self.video_dir:
                with VideoRecorder(env) as video:
                    record = dict(self.method.run(env, item.seed))
                if not record.get("success"):
                    video.save(Path(self.video_dir) / f"{file_slug(item.task_id)}.gif")
            else:
                record = dict(self.method.run(env, item.seed))
            # The parent writes it as one canonical JSON line: make sure it is JSON here,
            # where a failure is this task's error and not the run's.
            record = json.loads(json.dumps(record, default=_json_default, allow_nan=False))
            if not isinstance(record.get("success"), (bool, int)):
                raise TypeError(f"method {self.method.name} returned no boolean 'success' (keys: {sorted(record)})")
            record["success"] = bool(record["success"])
            task = env.unwrapped.tasks[0]
            record.setdefault("scene_type", task.scene_type)
            record.setdefault("category", task.target_label)
            record.setdefault("target_object", task.target.object_id)
        except Exception as error:  # noqa: BLE001 - any failure of one task is that task's record
            # The env may be half-way through a reconfigure: start the next task on a fresh one.
            self.close()
            record = error_record(item, "exception", f"{type(error).__name__}: {error}", traceback.format_exc())
        self.method_started = self.current_item = None
        release_between_tasks()  # the torch planners' per-task blocks: see worker_caches
        record.update(task_id=item.task_id, seed=item.seed, env_id=item.env_id, method=self.method.name,
                      wall_time=round(time.perf_counter() - t, 2))
        # Every record names the run's pipeline variant and options (error records too).
        for key, value in self.run.pipeline_fields().items():
            record.setdefault(key, value)
        record.update(self.run.record_options())
        return record


def _json_default(value):
    if hasattr(value, "tolist"):  # numpy / torch scalars and arrays
        return value.tolist()
    raise TypeError(f"a record value of type {type(value).__name__} is not JSON")


def error_record(item: WorkItem, kind: str, message: str, trace: str = "") -> dict:
    """A task that raised (``exception``), ran past its limit (``timeout``) or took its worker
    down (``crash``): a failed task with the reason, not a lost one."""
    return {
        **item.describe(),
        "task_id": item.task_id,
        "seed": item.seed,
        "env_id": item.env_id,
        "success": False,
        # A task stopped by the wall-clock limit is a ``timeout`` (reported apart from errors).
        "failure": "timeout" if kind == "timeout" else ERROR_FAILURE,
        "error": {"kind": kind, "message": message, "traceback": trace},
    }


def file_slug(text: str) -> str:
    """A file-name-safe form of a task id or label ("test/0042" -> "test_0042")."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_")


class VideoRecorder:
    """Frames of the env's overview camera every few control steps while a method runs.

    Methods step the simulation through ``BaseEnv._step_action`` (``env.step`` would also
    render the sensors), so the recorder wraps that on the env instance for the duration
    of the ``with`` block: no method needs to know about recording.
    """

    def __init__(self, env, every: int = VIDEO_EVERY):
        self.u, self.every, self.frames, self.steps = env.unwrapped, every, [], 0

    def _frame(self) -> None:
        from PIL import Image

        image = self.u.render()[0].cpu().numpy()
        self.frames.append(Image.fromarray(image).resize((VIDEO_SIZE, VIDEO_SIZE)))

    def __enter__(self):
        step_action = self.u._step_action

        def recording_step(action):
            out = step_action(action)
            self.steps += 1
            if self.steps % self.every == 0:
                self._frame()
            return out

        self._frame()
        self.u._step_action = recording_step
        return self

    def __exit__(self, *exc):
        del self.u._step_action  # back to the class's method
        self._frame()  # the end of the episode (after the hold)
        return False

    def save(self, path: Path) -> None:
        import io

        from ..utils.io import atomic_write_bytes

        buffer = io.BytesIO()
        self.frames[0].save(buffer, format="GIF", save_all=True, append_images=self.frames[1:],
                            duration=int(1000 * self.every / self.u.control_freq), loop=0)
        atomic_write_bytes(path, buffer.getvalue())
