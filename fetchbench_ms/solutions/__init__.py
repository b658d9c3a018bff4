"""Sense-plan-act baselines (FetchBench's GA-Mesh / GA-Ptd and CGN / CGN-Mesh with RRTConnect) as
ManiSkill-style ``solve(env, seed)`` functions. Running them over many tasks is
``fetchbench_ms.evaluation`` (``fetchbench eval``)."""
from .sense_plan_act import FAILURE_CLASSES, METHODS, PHASES, SolveConfig, solve

__all__ = ["FAILURE_CLASSES", "METHODS", "PHASES", "SolveConfig", "solve"]
