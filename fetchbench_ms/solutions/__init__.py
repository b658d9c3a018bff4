"""Sense-plan-act baselines (FetchBench's GA-Mesh / GA-Ptd with RRTConnect) as
ManiSkill-style ``solve(env, seed)`` functions, and an episode runner."""
from .runner import run_episodes, summarize
from .sense_plan_act import FAILURE_CLASSES, METHODS, PHASES, SolveConfig, solve

__all__ = ["FAILURE_CLASSES", "METHODS", "PHASES", "SolveConfig", "run_episodes", "solve", "summarize"]
