"""Canonical forms of generated floats, so stored and hashed bytes do not depend on the machine.

NumPy and OpenBLAS choose SIMD kernels from the CPU at run time and libm differs between
systems, so the same computation can end in different last bits on two machines. What is
stored or hashed, and what is fed to the physics engine (whose contact dynamics amplify a
last-bit difference into a different resting yaw), is first snapped to a declared grid:

- lengths and positions: ``LENGTH_DECIMALS`` (1 um), far below what physics or
  grasping resolves, far above last-bit noise (1e-16 m), so two machines round the same
  way unless a value lies within ~1e-16 of a rounding boundary (odds ~1e-10 per value);
- unit quaternions: ``QUAT_DECIMALS`` with one sign (the first non-zero component
  positive), so q and -q (the same rotation) store alike;
- probabilities and other unit-free fractions: ``FRACTION_DECIMALS``.

Python's ``round`` is correctly rounded (it works on the exact binary value), so it gives
the same result everywhere; ``+ 0.0`` turns -0.0 into 0.0.
"""
from __future__ import annotations

import math

import numpy as np

LENGTH_DECIMALS = 6
QUAT_DECIMALS = 7
FRACTION_DECIMALS = 6


def canonical_length(value: float) -> float:
    return round(float(value), LENGTH_DECIMALS) + 0.0


def canonical_lengths(values) -> tuple[float, ...]:
    return tuple(canonical_length(v) for v in values)


def canonical_lengths_array(values) -> np.ndarray:
    """An array snapped to the length grid (NumPy's ``round`` scales by 10**d and rounds
    half to even: exact IEEE operations, identical everywhere)."""
    return np.round(np.asarray(values, dtype=np.float64), LENGTH_DECIMALS) + 0.0


def canonical_fraction(value: float) -> float:
    return round(float(value), FRACTION_DECIMALS) + 0.0


def canonical_quat(q) -> tuple[float, float, float, float]:
    """Unit quaternion (any order of components) normalised, rounded, one sign."""
    q = [float(v) for v in q]
    norm = math.sqrt(sum(v * v for v in q))
    rounded = [round(v / norm, QUAT_DECIMALS) + 0.0 for v in q]
    first = next((v for v in rounded if v != 0.0), 1.0)
    if first < 0:
        rounded = [-v + 0.0 for v in rounded]
    return tuple(rounded)
