"""Physics-verified Franka grasps for every catalog object.

Frames and conventions (shared with the env's Panda and every grasp consumer):

* A grasp is a pose ``T_object_hand`` (4x4, object frame) of ManiSkill's ``panda_hand``
  link. The fingers close along the hand's **y** axis, the hand approaches along **+z**,
  and the tool centre point ``panda_hand_tcp`` is ``TCP_OFFSET = 0.1034`` m along +z from
  the hand origin: ``T_object_tcp = T_object_hand @ translate(0, 0, 0.1034)``.
* ``width`` is the gap between the fingers measured in simulation after closing (m);
  the hand opens at most 0.08 m.
* Labels come from a SAPIEN test with the env Panda's gripper (see ``physics``):
  close with object gravity off, then gravity on and a 1 s shake; success = the object
  is still held between both fingers near the TCP.

Modules: ``hand`` (geometry from ManiSkill's URDF), ``sampler`` (antipodal candidates),
``physics`` (the SAPIEN labeller), ``store`` (files, hashes, ``load_grasps``,
``objects_with_grasps``), ``build`` (resumable parallel builder), ``show`` (pictures).
"""
import importlib

# Loaded on first use (trimesh, scipy): a command's flags are read without them. Loading
# ``store`` registers the grasp counts with ``fetchbench objects stats`` (catalog.stats()).
_NAMES = {"Grasps": "store", "load_grasps": "store", "objects_with_grasps": "store", "add_grasp_stats": "store",
          "TCP_OFFSET": "hand", "MAX_OPENING": "hand"}


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(importlib.import_module(f".{_NAMES[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["Grasps", "load_grasps", "objects_with_grasps", "TCP_OFFSET", "MAX_OPENING"]
