"""Declared, range-checked generator parameters.

Every number a scene generator draws is declared as a ``ParamSpec`` (name, range,
unit, meaning). Sampling is uniform within the range (integers inclusive), from an
explicit ``numpy.random.Generator`` in declaration order, so the same seed always
gives the same values. Overrides replace sampled values after validation; unknown
names and out-of-range values are errors that name what is valid.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Literal, Mapping

import numpy as np

ParamKind = Literal["float", "int"]


@dataclass(frozen=True)
class ParamSpec:
    name: str
    low: float
    high: float
    unit: str  # "m", "rad", "count", "1" (dimensionless: colour channels, fractions)
    doc: str
    kind: ParamKind = "float"

    def __post_init__(self):
        if self.kind not in ("float", "int"):
            raise ValueError(f"parameter {self.name!r}: kind must be 'float' or 'int', got {self.kind!r}")
        if self.high < self.low:
            raise ValueError(f"parameter {self.name!r}: high {self.high} < low {self.low}")

    def sample(self, rng: np.random.Generator) -> float:
        if self.kind == "int":
            return int(rng.integers(int(self.low), int(self.high) + 1))
        return float(rng.uniform(self.low, self.high))

    def validate(self, value) -> float:
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"parameter {self.name!r}: {value!r} is not a number") from None
        if self.kind == "int":
            if number != int(number):
                raise ValueError(f"parameter {self.name!r} is an integer count; got {value!r}")
            number = int(number)
        if not (self.low <= number <= self.high):
            raise ValueError(
                f"parameter {self.name!r} = {value!r} is out of range [{self.low}, {self.high}] {self.unit}"
            )
        return number


def prefixed(prefix: str, specs: Iterable[ParamSpec]) -> tuple[ParamSpec, ...]:
    """The same parameters under ``prefix.name`` (composite types combine pieces this way)."""
    return tuple(
        ParamSpec(f"{prefix}.{s.name}", s.low, s.high, s.unit, s.doc, s.kind) for s in specs
    )


def sub_params(values: Mapping[str, float], prefix: str) -> dict[str, float]:
    """The values under ``prefix.`` with the prefix removed."""
    head = prefix + "."
    return {k[len(head):]: v for k, v in values.items() if k.startswith(head)}


def sample_params(
    specs: tuple[ParamSpec, ...],
    rng: np.random.Generator,
    overrides: Mapping[str, float] | None = None,
    owner: str = "scene",
) -> dict[str, float]:
    """Draw every parameter in declaration order, then apply validated overrides.

    All parameters are always drawn (even overridden ones) so that an override changes
    only that parameter and leaves every other value as the seed gave it.
    """
    names = [s.name for s in specs]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise ValueError(f"{owner}: duplicate parameter names {dup}")
    values = {s.name: s.sample(rng) for s in specs}
    by_name = {s.name: s for s in specs}
    for name, value in (overrides or {}).items():
        if name not in by_name:
            raise ValueError(f"{owner} has no parameter {name!r}; valid: {', '.join(sorted(by_name))}")
        values[name] = by_name[name].validate(value)
    return values
