"""Grasp prediction: Contact-GraspNet in plain PyTorch (docs/grasping.md).

- ``network.ContactGraspNet``: the network (batched, CPU or CUDA, no compiled extension; its
  point operations are ``fetchbench_ms.geometry.pointops``);
- ``predict``: weight sets (``pretrained`` from the ``cgn-pytorch`` package, ``ours``),
  pre-processing of a FetchBench observation and grasps in the project's hand frame.
"""
import importlib

_NAMES = {"ContactGraspNet": "network", "GRASP_MODELS": "predict", "PredictedGrasps": "predict",
          "load_model": "predict", "predict_from_clouds": "predict", "predict_target_grasps": "predict"}


def __getattr__(name: str):
    # torch loads on first use, not when a command's flags are read.
    if name in _NAMES:
        return getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["GRASP_MODELS", "ContactGraspNet", "PredictedGrasps", "load_model", "predict_from_clouds",
           "predict_target_grasps"]
