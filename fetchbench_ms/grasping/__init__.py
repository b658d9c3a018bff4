"""Grasp prediction: Contact-GraspNet in plain PyTorch (docs/grasping.md).

- ``network.ContactGraspNet``: the network (batched, CPU or CUDA, no compiled extension);
- ``pointops``: farthest-point sampling, ball query, kNN interpolation in torch;
- ``predict``: weight sets (``pretrained`` from the ``cgn-pytorch`` package, ``ours``),
  pre-processing of a FetchBench observation and grasps in the project's hand frame.
"""
from .network import ContactGraspNet
from .predict import GRASP_MODELS, PredictedGrasps, load_model, predict_from_clouds, predict_target_grasps

__all__ = ["GRASP_MODELS", "ContactGraspNet", "PredictedGrasps", "load_model", "predict_from_clouds",
           "predict_target_grasps"]
