"""Methods as data: what a fetching method is made of, and what one run of it is.

A method is a composition: grasp source (``oracle``: the annotated grasps | ``cgn``:
Contact-GraspNet) x world model (``mesh`` | ``pointcloud``) x planner (a ``PLANNERS`` row) x
retrieval (by the planner | by a learned policy, a ``POLICY_KINDS`` row). Its name is what
users type (``ga-mesh-rrt``, ``cgn-imit-mlp``); ``MethodSpec`` is what the code reads.
Every method lives in one registry, built from the small tables below:

- each planner gives ``{ga,cgn}-{mesh,ptd}-<planner>`` (its ``compositions``);
- each policy kind gives ``e2e-<kind>`` (the policy fetches, re-grasping), ``twostage-<kind>``
  (without re-grasping) and ``cgn-imit-<kind>`` (CGN grasps and the ``HYBRID_PLANNER``
  approach, then the policy retrieves);
- ``idle`` holds the start configuration (a lower bound, a cheap method for tests).

``RunSpec`` is a method with its run's options (tries, weight set, checkpoint, policy stride,
pipeline improvements, env and planner options, robot): ``fetchbench eval`` resolves and
checks it once (``evaluation.methods.resolve_run``), records it in ``run.json`` and hands it
to every worker, whose runners (``solutions.sense_plan_act.solve``, ``policies.deploy``)
read it and look no name up. This module imports nothing heavy: the command line reads it
before torch loads. Planners, networks and configs are named as ``module:attribute``
(``load``), imported where they run.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from typing import Optional


def load(path: str):
    """The object a ``module:attribute`` string names."""
    module, _, attr = path.partition(":")
    return getattr(importlib.import_module(module), attr)


# ----------------------------------------------------------------------------- pipelines
#: Our additions to the original's step list, each switched on by name in
#: ``SolveConfig.improvements`` (``--pipeline ours [--without NAME,...]``):
#: - ``retreat``: after the lift, back the held object out along the reverse approach (the
#:   first of ``retreat_distances`` whose straight line is free) before planning the retrieval
#:   (the grasp pose sits millimetres from the furniture, and a planner often fails to leave
#:   such a pocket within its budget);
#: - ``extra_lifts``: if the carried object still touches its support after the 2 cm lift
#:   (its balls bulge past its faces, or it slipped), lift more (the first of ``extra_lifts``
#:   that frees it);
#: - ``start_escape``: a plan start the conservative spheres call in collision, up to
#:   ``start_tolerance`` deep, is escaped first (``planning.rrt.escape_start``, MoveIt's start
#:   repair), instead of failing the plan as ``start_invalid``;
#: - ``cgn_filter``: CGN predictions whose open hand collides are dropped before the top
#:   ``cgn_grasps`` go to IK (the original takes the top 10 by score, unfiltered).
IMPROVEMENTS = ("retreat", "extra_lifts", "start_escape", "cgn_filter")
#: ``paper``: the original's step list (pre-grasp, approach, close, lift 2 cm, retrieval plan);
#: ``ours``: with every improvement.
PIPELINES = {"paper": (), "ours": IMPROVEMENTS}


def pipeline_improvements(pipeline: str = "paper", without=()) -> tuple[str, ...]:
    """The improvements of a named pipeline, less ``without`` (names of ``IMPROVEMENTS``)."""
    if pipeline not in PIPELINES:
        raise ValueError(f"unknown pipeline {pipeline!r}; valid: {', '.join(PIPELINES)}")
    without = tuple(without)
    unknown = [w for w in without if w not in IMPROVEMENTS]
    if unknown:
        raise ValueError(f"unknown improvement {unknown[0]!r}; valid: {', '.join(IMPROVEMENTS)}")
    if without and pipeline != "ours":
        raise ValueError(f"--without switches off improvements of the 'ours' pipeline; '{pipeline}' has none")
    return tuple(i for i in PIPELINES[pipeline] if i not in without)


def pipeline_label(improvements) -> str:
    """``paper``, ``ours`` or ``ours-minus-retreat+start_escape``: the variant's name in records."""
    improvements = tuple(improvements)
    for name, on in PIPELINES.items():
        if set(improvements) == set(on):
            return name
    return "ours-minus-" + "+".join(i for i in IMPROVEMENTS if i not in improvements)


# ----------------------------------------------------------------------------- the tables
@dataclass(frozen=True)
class PlannerSpec:
    """A planner of the sense-plan-act pipeline. ``entry`` names ``plan(PlanRequest) ->
    PlanResult`` (``planning.rrt``); its methods are ``<grasps>-<world>-<name>`` for each of
    ``compositions``."""

    name: str
    entry: str
    paper_name: str = ""  # the paper's name for it (its rows: GA-Mesh-<paper_name>)
    compositions: tuple = ("ga-mesh", "ga-ptd", "cgn-ptd", "cgn-mesh")
    #: world model -> the collision model it plans against (``spheres``: the robot's sphere
    #: model on the world's boxes, convexes or points, ``planning.checker``).
    collision: tuple = (("mesh", "spheres"), ("pointcloud", "spheres"))
    budgeted: bool = True  # draws on the episode's collision-check budget (``plan_checks_total``)
    executes: bool = False  # moves the robot while it plans (``PlanRequest.execute``)
    options: tuple = ()  # the ``--planner-option`` names it reads (``solutions.planner_options``)


@dataclass(frozen=True)
class PolicyKind:
    """A learned policy's network: its checkpoints' ``kind``, the network and config classes
    (``module:Class``; the config has an ``encoder`` field, ``policies.networks``) and the
    script that trains it (named when a checkpoint is missing)."""

    name: str
    network: str
    config: str
    trainer: str


@dataclass(frozen=True)
class PaperRow:
    """The paper's figures for a method: its name there, success rate, the ablation table's
    funnel (approach plan, approach execution, retrieval plan; None where not given) and the
    "Other Manipulators" table's success by robot uid."""

    name: str
    success: float
    funnel: Optional[tuple] = None
    robots: tuple = ()  # (robot uid, success) pairs

    def on_robot(self, robot: str) -> Optional[float]:
        return self.success if robot == "panda" else dict(self.robots).get(robot)


_NETWORKS = "fetchbench_ms.policies.networks"
PLANNERS: dict[str, PlannerSpec] = {p.name: p for p in (
    PlannerSpec("rrt", "fetchbench_ms.planning.rrt:plan", "RRTConnect"),
    PlannerSpec("trajopt", "fetchbench_ms.planning.trajopt:plan", "CuRobo",
                options=("trajopt_counts", "trajopt_loop", "trajopt_certify")),
    # MPPI executes while it plans and is bounded by its replans, not by collision checks; its
    # collision cost is the learned scene-collision network on the observed cloud, or (the
    # mesh oracle) the meshes' distance fields.
    PlannerSpec("mppi", "fetchbench_ms.planning.mppi:plan", "Cabinet", compositions=("cgn-ptd", "ga-ptd", "ga-mesh"),
                collision=(("pointcloud", "network"), ("mesh", "distance")), budgeted=False, executes=True,
                options=("mppi_goal_region", "mppi_cost")),
)}
POLICY_KINDS: dict[str, PolicyKind] = {k.name: k for k in (
    PolicyKind(kind, f"{_NETWORKS}:{network}Policy", f"{_NETWORKS}:{network}Config",
               f"baselines/imitation/train_{kind}.py")
    for kind, network in (("mlp", "MLP"), ("transformer", "Transformer"), ("diffusion", "Diffusion"), ("act", "ACT")))}
#: The hybrids' approach: CGN grasps in the point-cloud world with this planner (the paper's CuRobo).
HYBRID_PLANNER = "trajopt"
#: The paper's rows (FetchBench, main table, ablation table, the appendix's imitation and
#: "Other Manipulators" tables), by our method name.
PAPER_ROWS: dict[str, PaperRow] = {
    "ga-mesh-trajopt": PaperRow("GA-Mesh-CuRobo", 0.671, (0.865, 0.861, 0.776),
                                (("kinova_gen3_panda_hand", 0.629), ("kinova_gen3_robotiq", 0.471))),
    "ga-mesh-rrt": PaperRow("GA-Mesh-RRTConnect", 0.529, (0.947, 0.903, 0.681)),
    "ga-ptd-trajopt": PaperRow("GA-Ptd-CuRobo", 0.190, (0.792, 0.705, 0.321),
                               (("kinova_gen3_panda_hand", 0.173), ("kinova_gen3_robotiq", 0.108))),
    "ga-ptd-rrt": PaperRow("GA-Ptd-RRTConnect", 0.306, (0.949, 0.678, 0.502)),
    "cgn-mesh-trajopt": PaperRow("CGN-Mesh-CuRobo", 0.336, (0.611, 0.602, 0.546)),
    "cgn-mesh-rrt": PaperRow("CGN-Mesh-RRTConnect", 0.275, (0.607, None, 0.478)),
    "cgn-ptd-trajopt": PaperRow("CGN-CuRobo", 0.094, None,
                                (("kinova_gen3_panda_hand", 0.088), ("kinova_gen3_robotiq", 0.017))),
    "cgn-ptd-rrt": PaperRow("CGN-RRTConnect", 0.131),
    "cgn-ptd-mppi": PaperRow("CGN-Cabinet", 0.121),
    "cgn-imit-mlp": PaperRow("CGN-CuRobo-Imit-MLP", 0.200),
    "cgn-imit-transformer": PaperRow("CGN-CuRobo-Imit-Transformer", 0.203),
    "e2e-mlp": PaperRow("E2EImit-MLP", 0.082),
    "e2e-transformer": PaperRow("E2EImit-Transformer", 0.099),
    # appendix, "different models and more training data", 1x data
    "e2e-act": PaperRow("E2EImit-ACT", 0.093),
}
GRASP_SOURCES = {"ga": "annotated", "cgn": "cgn"}  # name prefix -> grasp source (ga: the annotated grasps)
WORLDS = {"mesh": "mesh", "ptd": "pointcloud"}  # name part -> world model
IDLE = "idle"
PANDA_ONLY = ("panda",)  # what the learned networks were trained on


# ----------------------------------------------------------------------------- specs
@dataclass(frozen=True)
class MethodSpec:
    """One method, resolved from its name: its parts, the robots it runs on, the env obs mode
    it reads (None: its checkpoint's) and the paper's row (None: the paper has none).
    ``entry``: an importable ``module:function`` method's function (``run(env, seed)``)."""

    name: str
    grasps: Optional[str] = None  # annotated | cgn
    world: Optional[str] = None  # mesh | pointcloud
    planner: Optional[PlannerSpec] = None
    collision: Optional[str] = None  # the planner's collision model (PlannerSpec.collision)
    retrieval: Optional[str] = None  # planner | policy
    policy: Optional[PolicyKind] = None
    regrasp: bool = False  # an end-to-end policy re-grasps after a failed grasp (e2e, not twostage)
    robots: Optional[tuple] = None  # robot uids; None: every robot
    obs_mode: Optional[str] = "none"
    paper: Optional[PaperRow] = None
    entry: Optional[str] = None

    @property
    def family(self) -> str:
        """``sense_plan_act``, ``hybrid`` (planned approach, policy retrieval), ``policy``
        (end to end), ``idle`` or ``custom``."""
        if self.entry is not None:
            return "custom"
        if self.planner is not None:
            return "hybrid" if self.policy is not None else "sense_plan_act"
        return "policy" if self.policy is not None else IDLE

    @property
    def has_pipeline(self) -> bool:
        """Whether it runs the sense-plan-act pipeline (whole, or its approach: the hybrids),
        so ``--pipeline`` and its improvements apply to it."""
        return self.planner is not None

    @property
    def reads_clouds(self) -> bool:
        """Whether its pipeline reads the cameras (the env must give ``pointcloud``)."""
        return self.world == "pointcloud" or self.grasps == "cgn"

    @property
    def approach_method(self) -> str:
        """The sense-plan-act method its pipeline runs (a hybrid's approach)."""
        prefix = {v: k for k, v in GRASP_SOURCES.items()}[self.grasps]
        world = {v: k for k, v in WORLDS.items()}[self.world]
        return f"{prefix}-{world}-{self.planner.name}"

    def to_json(self) -> dict:
        """Its parts, as ``run.json`` records them."""
        parts = {"grasps": self.grasps, "world": self.world, "planner": self.planner and self.planner.name,
                 "collision": self.collision, "retrieval": self.retrieval, "policy": self.policy and self.policy.name,
                 "entry": self.entry}
        return {"family": self.family, **{k: v for k, v in parts.items() if v is not None}}


@dataclass(frozen=True)
class RunSpec:
    """A method with its run's options, checked once (``evaluation.methods.resolve_run``):
    what ``run.json`` records and what every worker receives. ``obs_mode``: the env's (a
    policy's is its checkpoint's); ``planner_options`` and ``env_options`` are sorted (name,
    value) pairs; ``video_dir``: where GIFs of failed tasks go (None: none recorded)."""

    method: MethodSpec
    obs_mode: str = "none"
    retries: int = 1
    grasp_model: str = "pretrained"  # the CGN weight set
    policy_checkpoint: Optional[str] = None  # None: the policy kind's shipped checkpoint
    policy_stride: int = 1
    improvements: tuple = ()
    grasp_labels: Optional[str] = None  # the annotated grasps' store (None: the shipped labels)
    planner_options: tuple = ()
    env_options: tuple = ()
    robot: str = "panda"
    video_dir: Optional[str] = None

    @property
    def name(self) -> str:
        return self.method.name

    def pipeline_fields(self) -> dict:
        """``{"pipeline": "paper" | "ours" | "ours-minus-...", "improvements": [...]}`` for a
        method with the pipeline; ``{"pipeline": "none"}`` for the others (records without
        the key predate the count-budgeted evaluation)."""
        if not self.method.has_pipeline:
            return {"pipeline": "none"}
        return {"pipeline": pipeline_label(self.improvements),
                "improvements": [i for i in IMPROVEMENTS if i in self.improvements]}

    def method_options(self) -> dict:
        """``run.json``'s ``method_options`` (what resuming compares): an option at its
        default is left out where earlier stores had no key for it."""
        options: dict = {"retries": self.retries}
        if self.method.grasps == "cgn":
            options["grasp_model"] = self.grasp_model
        if self.policy_checkpoint is not None:
            options["policy_checkpoint"] = self.policy_checkpoint
        if self.policy_stride != 1:
            options["policy_stride"] = self.policy_stride
        return {**options, **self.pipeline_fields(), **self.record_options()}

    def record_options(self) -> dict:
        """The options every record names besides its pipeline (none at their defaults)."""
        options: dict = {}
        if self.env_options:
            options["env_options"] = dict(self.env_options)
        if self.planner_options:
            options["planner_options"] = dict(self.planner_options)
        if self.robot != "panda":
            options["robot"] = self.robot
        if self.grasp_labels is not None:
            options["grasp_labels"] = self.grasp_labels
        return options


# ----------------------------------------------------------------------------- the registry
def _planner_methods(planner: PlannerSpec):
    for composition in planner.compositions:
        prefix, world_part = composition.split("-")
        world = WORLDS[world_part]
        name = f"{composition}-{planner.name}"
        collision = dict(planner.collision)[world]
        yield MethodSpec(name, GRASP_SOURCES[prefix], world, planner, collision, "planner",
                         robots=PANDA_ONLY if collision == "network" else None,
                         obs_mode="pointcloud" if world == "pointcloud" or prefix == "cgn" else "none",
                         paper=PAPER_ROWS.get(name))


def _policy_method(kind: PolicyKind, family: str) -> MethodSpec:
    """``e2e-<kind>`` (the policy fetches, re-grasping), ``twostage-<kind>`` (without
    re-grasping) or ``cgn-imit-<kind>`` (the hybrid: CGN grasps and the planned approach,
    then the policy retrieves)."""
    name = f"{family}-{kind.name}"
    if family != "cgn-imit":
        return MethodSpec(name, retrieval="policy", policy=kind, regrasp=family == "e2e", robots=PANDA_ONLY,
                          obs_mode=None, paper=PAPER_ROWS.get(name))
    planner = PLANNERS[HYBRID_PLANNER]
    return MethodSpec(name, "cgn", "pointcloud", planner, dict(planner.collision)["pointcloud"], "policy", kind,
                      robots=PANDA_ONLY, obs_mode="pointcloud", paper=PAPER_ROWS.get(name))


def registry() -> dict[str, MethodSpec]:
    """Every built-in method by name, in the order ``fetchbench eval`` lists them: the
    planners' methods, the policies' end-to-end, two-stage and hybrid methods, ``idle``."""
    specs = [m for planner in PLANNERS.values() for m in _planner_methods(planner)]
    specs += [_policy_method(kind, family) for family in ("e2e", "twostage", "cgn-imit")
              for kind in POLICY_KINDS.values()]
    specs.append(MethodSpec(IDLE))
    return {m.name: m for m in specs}


def method_spec(name: str) -> MethodSpec:
    """The built-in method ``name``; ValueError naming the valid ones otherwise."""
    methods = registry()
    if name not in methods:
        raise ValueError(f"unknown method {name!r}; valid: {', '.join(methods)} or an importable module:function")
    return methods[name]


def policy_kind(name: str) -> PolicyKind:
    if name not in POLICY_KINDS:
        raise ValueError(f"unknown policy kind {name!r}; valid: {', '.join(POLICY_KINDS)}")
    return POLICY_KINDS[name]


def _add(table: dict, row, what: str) -> None:
    if row.name in table:
        raise ValueError(f"a {what} named {row.name!r} is registered already")
    table[row.name] = row


def register_planner(planner: PlannerSpec) -> None:
    """Add a planner (and so its methods) to the registry of this process."""
    _add(PLANNERS, planner, "planner")


def register_policy_kind(kind: PolicyKind) -> None:
    """Add a policy kind (and so its e2e-, twostage- and cgn-imit- methods) to the registry."""
    _add(POLICY_KINDS, kind, "policy kind")


def unregister_planner(name: str) -> None:
    PLANNERS.pop(name)


def unregister_policy_kind(name: str) -> None:
    POLICY_KINDS.pop(name)


__all__ = ["IMPROVEMENTS", "PIPELINES", "PLANNERS", "POLICY_KINDS", "PAPER_ROWS", "MethodSpec", "PaperRow",
           "PlannerSpec", "PolicyKind", "RunSpec", "method_spec", "policy_kind", "register_planner",
           "register_policy_kind", "registry", "unregister_planner", "unregister_policy_kind", "load",
           "pipeline_improvements", "pipeline_label"]
