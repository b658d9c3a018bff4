"""Grasp-quality figures of predicted grasps against an object's annotated (physics-verified) grasps."""
from __future__ import annotations

import numpy as np


def grasp_coverage(T_object_predicted: np.ndarray, T_object_annotated: np.ndarray, max_distance: float = 0.02,
                   max_angle_deg: float = 30.0) -> float:
    """Fraction of the annotated grasps ((M, 4, 4) panda_hand poses, object frame) that some
    predicted grasp ((N, 4, 4), same frame) covers: its TCP within ``max_distance`` m and its
    approach axis (hand z) within ``max_angle_deg`` (the two fingers are interchangeable, so
    the closing direction is not compared). NaN when nothing is annotated."""
    from ..grasp_labels.candidates import tcp_from_hand

    if len(T_object_annotated) == 0:
        return float("nan")
    if len(T_object_predicted) == 0:
        return 0.0
    tcp_annotated, tcp_predicted = tcp_from_hand(T_object_annotated), tcp_from_hand(T_object_predicted)
    near = np.linalg.norm(tcp_annotated[:, None, :3, 3] - tcp_predicted[None, :, :3, 3], axis=-1) <= max_distance
    aligned = tcp_annotated[:, :3, 2] @ tcp_predicted[:, :3, 2].T >= np.cos(np.radians(max_angle_deg))
    return float(np.mean(np.any(near & aligned, axis=1)))
