"""Env options that change one factor toward the original FetchBench, for ablations.

Both default to this env's behaviour:

- ``sim_freq``: physics rate in Hz, 120 (default) or 60 (the original's). Control stays
  at 20 Hz, so an action runs 6 or 3 physics steps; ``settle_and_hold``'s 10 s hold runs
  1,200 or 600 physics steps.
- ``camera_placement``: ``"task"`` (default), the task's two cameras as stored (the best
  of 32 mirrored pairs by how much of the supports they see past furniture and robot,
  ``tasks.camera_views.sample_camera_pair``); ``"paper"``, the original's heuristic
  (``tasks.camera_views.paper_camera_pair``): a mirrored pair looking at the support
  region's centre plus an offset, the first of up to 20 draws whose vertical field of
  view spans the supports' heights, without occlusion scoring; drawn from the task's
  content, so the same task always gets the same pair.

Give them to ``gym.make`` as kwargs (``gym.make("FetchBench-v0", sim_freq=60,
camera_placement="paper")``), or turn ``NAME=VALUE`` strings (a command line's) into those
kwargs with ``parse_env_options``.
"""
from __future__ import annotations

from typing import Iterable

from ..sim.bodies import SIM_FREQ

#: Physics rates the env runs at (Hz); the first is the default (``bodies.SIM_FREQ``).
SIM_FREQS = (SIM_FREQ, 60)
DEFAULT_SIM_FREQ = SIM_FREQ
#: Where the two cameras go; the first is the default.
CAMERA_PLACEMENTS = ("task", "paper")
DEFAULT_CAMERA_PLACEMENT = "task"


def check_sim_freq(value) -> int:
    """``value`` (an int, or a string such as ``"60"``) as a valid physics rate; a
    ValueError naming the valid ones otherwise."""
    valid = ", ".join(map(str, SIM_FREQS))
    if isinstance(value, bool):  # bool is an int: True would read as 1
        raise ValueError(f"unknown sim_freq {value!r}; valid: {valid} (Hz)")
    try:
        freq = int(str(value).strip()) if isinstance(value, str) else int(value)
    except (TypeError, ValueError):
        raise ValueError(f"unknown sim_freq {value!r}; valid: {valid} (Hz)") from None
    if freq not in SIM_FREQS or (not isinstance(value, str) and freq != value):
        raise ValueError(f"unknown sim_freq {value!r}; valid: {valid} (Hz)")
    return freq


def check_camera_placement(value) -> str:
    """``value`` as a valid camera placement; a ValueError naming the valid ones otherwise."""
    if not isinstance(value, str) or value.strip() not in CAMERA_PLACEMENTS:
        raise ValueError(f"unknown camera_placement {value!r}; valid: {', '.join(CAMERA_PLACEMENTS)}")
    return value.strip()


#: Option name -> (the function that checks and converts a value, the valid values).
ENV_OPTIONS = {
    "sim_freq": (check_sim_freq, SIM_FREQS),
    "camera_placement": (check_camera_placement, CAMERA_PLACEMENTS),
}


def _valid_options() -> str:
    return "; ".join(f"{name}={'|'.join(map(str, values))}" for name, (_, values) in ENV_OPTIONS.items())


def parse_env_options(options: Iterable[str]) -> dict:
    """``["sim_freq=60", "camera_placement=paper"]`` -> ``{"sim_freq": 60,
    "camera_placement": "paper"}``: env kwargs for ``gym.make``. A ValueError of one line
    naming the valid options and values for an unknown name, a bad value, a string
    without ``=`` or an option given twice."""
    if isinstance(options, str):
        options = [options]
    kwargs: dict = {}
    for option in options:
        name, sep, value = str(option).partition("=")
        name = name.strip()
        if not sep or name not in ENV_OPTIONS:
            what = "not NAME=VALUE" if not sep else f"unknown env option {name!r}"
            raise ValueError(f"env option {option!r}: {what}; valid: {_valid_options()}")
        if name in kwargs:
            raise ValueError(f"env option {name!r} is given twice; give each once (valid: {_valid_options()})")
        check, _ = ENV_OPTIONS[name]
        try:
            kwargs[name] = check(value.strip())
        except ValueError:
            raise ValueError(f"env option {option!r}: bad value {value.strip()!r}; valid: {_valid_options()}") from None
    return kwargs
