"""Planner parameters an ablation may set, each a ``SolveConfig`` field of the sense-plan-act
methods (``fetchbench eval --planner-option KEY=VALUE``, repeatable):

- ``mppi_goal_region``: rad >= 0, the region of MPPI's goal credit
  (``planning.mppi.MppiConfig.goal_region``, 0.5 by default; 0 switches the credit off);
- ``mppi_cost``: ``network`` or ``distance``, MPPI's scene-collision cost (by default the
  method's own);
- ``trajopt_counts``: ``SEEDSxITERSxSUBSTEPS``, the trajectory optimiser's seeds per problem,
  Adam iterations and collision points a segment (``planning.trajopt.COUNT_FIELDS``; by
  default ``TrajoptConfig``'s, 8x40x2), e.g. ``16x80x3`` (``trajopt.FULL_COUNTS``);
- ``trajopt_loop``: ``eager`` (the default), ``graph``, ``grid`` or ``cpu``, the trajectory
  optimiser's Adam loop and where it runs (``planning.trajopt.LOOPS``);
- ``trajopt_certify``: rad > 0, the trajectory optimiser's certified checks with that
  bisection floor (``planning.trajopt.TrajoptConfig.certify``), or ``off`` (the default).

A planner takes the options its row names (``method_spec.PlannerSpec.options``): the first
two are MPPI's, the last three the trajectory optimiser's (its methods and the hybrids'). This
module loads no torch (as ``envs.options``), so the command line answers a bad option before
torch and the planners load.
"""
from __future__ import annotations

import math
from typing import Iterable

from ..method_spec import MethodSpec, registry

#: ``planning.mppi.COSTS``, spelled out because that module loads torch
#: (tests/test_user_edges.py keeps them the same).
MPPI_COSTS = ("network", "distance")


def _finite(value, what: str) -> float:
    """``value`` (a number, or a string such as ``"0.25"``) as a finite float; a bool (an int:
    True would read as 1), a non-number or an infinity is a ValueError naming ``what``."""
    if isinstance(value, bool):
        raise ValueError(f"bad {what} {value!r}")
    number = float(value.strip() if isinstance(value, str) else value)  # not a number: ValueError
    if not math.isfinite(number):
        raise ValueError(f"bad {what} {value!r}")
    return number


def check_goal_region(value) -> float:
    """``value`` (a number, or a string such as ``"0.25"``) as a goal region in rad: finite and
    >= 0. A whole number comes back as an int, so that 0 reads ``0`` in records, labels and
    folder names, however it was typed."""
    region = _finite(value, "goal region")
    if region < 0:
        raise ValueError(f"bad goal region {value!r}")
    return int(region) if region.is_integer() else region


def check_mppi_cost(value) -> str:
    """``value`` as one of ``MPPI_COSTS``."""
    if not isinstance(value, str) or value.strip() not in MPPI_COSTS:
        raise ValueError(f"unknown MPPI cost {value!r}")
    return value.strip()


def check_trajopt_counts(value) -> str:
    """``value`` (``"16x80x3"``) as three whole counts >= 1 joined by ``x``, written plainly
    (``"016 x 80x3"`` reads ``16x80x3`` in records and folder names)."""
    parts = str(value).replace(" ", "").split("x")
    if isinstance(value, bool) or len(parts) != 3 or not all(p.isdigit() and int(p) >= 1 for p in parts):
        raise ValueError(f"bad trajopt counts {value!r}")
    return "x".join(str(int(p)) for p in parts)


#: ``planning.trajopt.LOOPS``, spelled out because that module loads torch
#: (tests/test_user_edges.py keeps them the same).
TRAJOPT_LOOPS = ("eager", "graph", "grid", "cpu")


def check_trajopt_loop(value) -> str:
    """``value`` as one of ``TRAJOPT_LOOPS``."""
    if not isinstance(value, str) or value.strip() not in TRAJOPT_LOOPS:
        raise ValueError(f"unknown trajopt loop {value!r}")
    return value.strip()


def check_trajopt_certify(value) -> float | str:
    """``value`` as a certified checks' floor in rad (finite, > 0, as a float: ``0.005``), or
    ``"off"``."""
    if isinstance(value, str) and value.strip() == "off":
        return "off"
    floor = _finite(value, "trajopt certify floor")
    if floor <= 0:
        raise ValueError(f"bad trajopt certify floor {value!r}")
    return floor


#: Option name (a ``SolveConfig`` field) -> (the function that checks and converts a value,
#: its valid values in words).
PLANNER_OPTIONS = {
    "mppi_goal_region": (check_goal_region, "RAD (>= 0; 0 switches the goal credit off)"),
    "mppi_cost": (check_mppi_cost, "|".join(MPPI_COSTS)),
    "trajopt_counts": (check_trajopt_counts, "SEEDSxITERSxSUBSTEPS (whole counts >= 1, e.g. 16x80x3)"),
    "trajopt_loop": (check_trajopt_loop, "|".join(TRAJOPT_LOOPS)),
    "trajopt_certify": (check_trajopt_certify, "RAD (> 0, the bisection floor)|off"),
}


def _valid_options() -> str:
    return "; ".join(f"{name}={values}" for name, (_, values) in PLANNER_OPTIONS.items())


def check_planner_options(method: MethodSpec, options: dict) -> dict:
    """``options`` (name -> value) checked and converted for ``method``: ``SolveConfig``
    kwargs. A ValueError of one line naming the valid options for an unknown name, a bad
    value, or an option its planner does not take (naming the methods it applies to)."""
    checked = {}
    for name, value in options.items():
        if name not in PLANNER_OPTIONS:
            raise ValueError(f"unknown planner option {name!r}; valid: {_valid_options()}")
        check, _ = PLANNER_OPTIONS[name]
        if method.planner is None or name not in method.planner.options:
            methods = [m.name for m in registry().values() if m.planner is not None and name in m.planner.options]
            raise ValueError(f"planner option {name!r} applies to {', '.join(methods)}, not {method.name}")
        try:
            checked[name] = check(value)
        except (TypeError, ValueError):
            raise ValueError(f"planner option {name}={value}: bad value; valid: {_valid_options()}") from None
    return checked


def parse_planner_options(options: Iterable[str]) -> dict:
    """``["mppi_goal_region=0"]`` -> ``{"mppi_goal_region": "0"}``, to be checked for a method
    by ``check_planner_options``; a ValueError of one line for a string without ``=`` and an
    option given twice."""
    values: dict = {}
    for option in options:
        name, sep, value = str(option).partition("=")
        name = name.strip()
        if not sep:
            raise ValueError(f"planner option {option!r}: not KEY=VALUE; valid: {_valid_options()}")
        if name in values:
            raise ValueError(f"planner option {name!r} is given twice; give each once (valid: {_valid_options()})")
        values[name] = value.strip()
    return values
