"""Statistics of the scene library: per type, what its generator produces over seeds."""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from .checks import reachable_fractions
from .registry import generate, get_scene_type
from .spec import SUPPORT_LABELS


@dataclass(frozen=True)
class TypeStats:
    scene_type: str
    n_params: int  # independent parameters the generator draws
    n_seeds: int
    parts_mean: float
    surfaces_mean: dict[str, float]  # label -> mean number of surfaces per scene
    area_mean: dict[str, float]  # label -> mean total area per scene (m^2)
    height_range: tuple[float, float]  # lowest and highest surface over all seeds (m)
    reach_min: float  # smallest reachable share of any surface over all seeds (checks.py)

    def to_dict(self) -> dict:
        return asdict(self)


def type_stats(scene_type: str, seeds=range(8)) -> TypeStats:
    seeds = list(seeds)
    if not seeds:
        raise ValueError(f"statistics of {scene_type} need at least one seed, got none")
    st = get_scene_type(scene_type)
    specs = [generate(scene_type, s) for s in seeds]
    counts = {lab: [len(spec.surfaces(lab)) for spec in specs] for lab in SUPPORT_LABELS}
    areas = {lab: [sum(s.area for s in spec.surfaces(lab)) for spec in specs] for lab in SUPPORT_LABELS}
    heights = [s.height for spec in specs for s in spec.support_surfaces] or [float("nan")]
    return TypeStats(
        scene_type=scene_type,
        n_params=len(st.params),
        n_seeds=len(seeds),
        parts_mean=float(np.mean([len(spec.parts) for spec in specs])),
        surfaces_mean={lab: float(np.mean(v)) for lab, v in counts.items()},
        area_mean={lab: float(np.mean(v)) for lab, v in areas.items()},
        height_range=(float(min(heights)), float(max(heights))),
        reach_min=min((min(reachable_fractions(spec).values(), default=0.0) for spec in specs)),
    )


def stats_table(stats: list[TypeStats]) -> str:
    """A fixed-width text table of ``stats`` (one row per type, a total row at the end)."""
    head = f"{'scene type':<24}{'params':>7}{'parts':>7}"
    head += "".join(f"{lab:>11}" for lab in SUPPORT_LABELS) + f"{'area m2':>9}{'heights m':>13}{'reach':>7}"
    lines = [head, "-" * len(head)]
    for s in stats:
        row = f"{s.scene_type:<24}{s.n_params:>7}{s.parts_mean:>7.1f}"
        row += "".join(f"{s.surfaces_mean[lab]:>11.1f}" for lab in SUPPORT_LABELS)
        row += f"{sum(s.area_mean.values()):>9.2f}{s.height_range[0]:>8.2f}-{s.height_range[1]:.2f}{s.reach_min:>7.0%}"
        lines.append(row)
    lines.append("-" * len(head))
    lines.append(f"{'total (' + str(len(stats)) + ' types)':<24}{sum(s.n_params for s in stats):>7}")
    lines.append("(parts, surfaces per label and area: means per scene over the seeds; reach: the smallest")
    lines.append(" reachable share of any surface, averaged over base positions in the robot region)")
    return "\n".join(lines)
