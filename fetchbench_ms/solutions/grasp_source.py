"""Grasp candidates for the target: the annotated (physics-verified) grasps of the
object, or, for an object without labels in the grasp store, antipodal candidates
computed from its convex parts as a stand-in (unverified, marked in the result)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..grasps.hand import TCP_OFFSET


@dataclass(frozen=True)
class GraspCandidates:
    T_object_hand: np.ndarray  # (N, 4, 4) panda_hand poses in the object frame, best first
    source: str  # "annotated" or "antipodal-standin"


def annotated_grasps(asset, rng: np.random.Generator, max_grasps: int = 64) -> GraspCandidates:
    from ..grasps import load_grasps

    try:
        labelled = load_grasps(asset.object_id).successful
        T, source = labelled.T_object_hand, "annotated"
    except (KeyError, FileNotFoundError):  # no store, or no labels for this object (stale/corrupt stores raise)
        from ..grasps.sampler import sample_candidates

        T, source = sample_candidates(asset, max_grasps, rng).T_object_hand, "antipodal-standin"
    if len(T) > max_grasps:
        T = T[np.sort(rng.choice(len(T), max_grasps, replace=False))]
    # Best first has no meaning among verified grasps: a seeded shuffle avoids a bias to
    # whatever order the labeller produced.
    return GraspCandidates(T[rng.permutation(len(T))], source)


def tcp_from_hand(T_hand: np.ndarray) -> np.ndarray:
    offset = np.eye(4)
    offset[2, 3] = TCP_OFFSET
    return T_hand @ offset


def retreat(T_tcp: np.ndarray, distance: float) -> np.ndarray:
    """The pose ``distance`` back along the hand's approach axis (its z)."""
    back = np.eye(4)
    back[2, 3] = -distance
    return T_tcp @ back
