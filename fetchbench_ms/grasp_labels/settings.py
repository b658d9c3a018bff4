"""The settings that decide the grasp labels (``LabelSettings``): recorded in every shard
and in the manifest, and compared on a re-run (``grasp_labels.build``); the Robotiq's labeller
extends them (``grasp_labels.robotiq``)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

from ..utils.io import canonical_json, sha256_bytes
from . import physics
from .sampler import SamplerConfig
from .store import GRASPS_VERSION


@dataclass(frozen=True)
class LabelSettings:
    """Everything that decides the labels; recorded in every shard and in the manifest."""

    seed: int = 0
    candidates_per_round: int = 32
    max_rounds: int = 6
    #: Stop drawing more rounds once an object has this many verified successes. 96, not
    #: the first build's 24: a target in a drawer or on a crowded shelf is reachable only
    #: through the few grasps whose hand clears the walls and its neighbours, and with 24
    #: most such targets had none (87% of sampled targets, the suite's main rejection).
    target_successes: int = 96
    slots: int = 16
    density: float = physics.DENSITY
    object_friction: float = physics.OBJECT_FRICTION
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    trial: physics.TrialConfig = field(default_factory=physics.TrialConfig)

    def as_dict(self) -> dict:
        d = asdict(self)
        d["sampler"]["depth_range"] = list(d["sampler"]["depth_range"])
        d["version"] = GRASPS_VERSION
        return d

    def digest(self) -> str:
        return sha256_bytes(canonical_json(self.as_dict()).encode())[:16]
