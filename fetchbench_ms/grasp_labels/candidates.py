"""Grasp candidates for the target: the annotated (physics-verified) grasps of the
object from the grasp store, or, for an object without labels there, antipodal
candidates computed from its convex parts as a stand-in (unverified; the episode
records which source it used). Contact-GraspNet's predictions on the observed clouds
come as the same ``GraspCandidates`` (``grasp_prediction.candidates.predicted_grasps``).

Both the annotated grasps and the stand-in are per-object assets computed ahead of time
(the stand-in once per object and process, from a seed derived from the object id), so an
episode's grasp "inference" is a lookup, as it is for FetchBench's annotated-grasp baselines.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..utils.io import sha256_bytes
from .hand import TCP_OFFSET

STANDIN_CANDIDATES = 128


@dataclass(frozen=True)
class GraspCandidates:
    T_object_hand: np.ndarray  # (N, 4, 4) panda_hand poses in the object frame
    source: str  # "annotated", "antipodal-standin" or "cgn-<model>" (grasp_prediction.candidates)
    index: np.ndarray | None = None  # (N,) positions in the object's full grasp list


@functools.lru_cache(maxsize=256)
def object_grasps(object_id: str, directory: str | None = None) -> GraspCandidates:
    """All grasps of an object (cached per process); ``directory``: another grasp store
    than the shipped Franka-hand labels (e.g. the Robotiq's, docs/robots.md)."""
    from .store import load_grasps

    try:
        return GraspCandidates(load_grasps(object_id, directory).successful.T_object_hand, "annotated")
    except (KeyError, FileNotFoundError):  # no store, or no labels for this object (stale/corrupt stores raise)
        from ..objects.loading import load_object
        from .sampler import sample_candidates

        seed = int(sha256_bytes(object_id.encode())[:8], 16)
        candidates = sample_candidates(load_object(object_id), STANDIN_CANDIDATES, np.random.default_rng(seed))
        return GraspCandidates(candidates.T_object_hand, "antipodal-standin")


def choose_grasps(grasps: GraspCandidates, rng: np.random.Generator, max_grasps: int) -> GraspCandidates:
    """A seeded random order (no grasp is better than another among verified ones), at most ``max_grasps``."""
    order = rng.permutation(len(grasps.T_object_hand))[:max_grasps]
    return GraspCandidates(grasps.T_object_hand[order], grasps.source, order)


def tcp_from_hand(T_hand: np.ndarray) -> np.ndarray:
    """TCP pose(s) of hand pose(s) ((4, 4) or (N, 4, 4))."""
    offset = np.eye(4)
    offset[2, 3] = TCP_OFFSET
    return T_hand @ offset


def retreat(T_tcp: np.ndarray, distance: float) -> np.ndarray:
    """The pose(s) ``distance`` back along the hand's approach axis (its z); (4, 4) or (N, 4, 4)."""
    back = np.eye(4)
    back[2, 3] = -distance
    return T_tcp @ back
