"""Sense-plan-act baselines (FetchBench's GA-Mesh / GA-Ptd and CGN / CGN-Mesh with RRTConnect) as
ManiSkill-style ``solve(env, seed)`` functions. Running them over many tasks is
``fetchbench_ms.evaluation`` (``fetchbench eval``)."""
_NAMES = ("FAILURE_CLASSES", "PHASES", "SolveConfig", "solve")


def __getattr__(name: str):
    # torch and the planners load on first use, not when a command's flags are read.
    if name in _NAMES:
        from . import sense_plan_act

        return getattr(sense_plan_act, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["FAILURE_CLASSES", "PHASES", "SolveConfig", "solve"]
