"""Contact-GraspNet as a grasp source: its predictions on the observed target, in the object
frame, as the ``GraspCandidates`` the annotated grasps come as (``grasp_labels.candidates``)."""
from __future__ import annotations

import numpy as np

from ..grasp_labels.candidates import GraspCandidates


def predicted_grasps(clouds, T_base_object: np.ndarray, model: str, max_grasps: int, rng: np.random.Generator,
                     first_index: int = 0) -> GraspCandidates:
    """The ``max_grasps`` best Contact-GraspNet grasps on the observed target (``clouds``:
    ``fetchbench_ms.envs.FetchClouds``), expressed in the object frame like the annotated
    ones (``T_base_object`` only changes the frame: the prediction sees the clouds alone).
    Ids count from ``first_index``."""
    import os

    import torch

    from .predict import predict_from_clouds

    # As the trajopt planner: the GPU when there is one (the network's inference dominates
    # a CGN method's compute time on CPU), overridable for timing comparisons.
    device = os.environ.get("FETCHBENCH_CGN_DEVICE") or ("cuda" if torch.cuda.is_available() else "cpu")
    predicted = predict_from_clouds(clouds, model, rng, device=device)
    T_object_hand = np.linalg.inv(T_base_object)[None] @ predicted.T_base_hand[:max_grasps]
    return GraspCandidates(T_object_hand, f"cgn-{model}", first_index + np.arange(len(T_object_hand)))
