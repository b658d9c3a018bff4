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
from ..objects import catalog as _catalog
from .hand import MAX_OPENING, TCP_OFFSET
from .store import Grasps, add_grasp_stats, load_grasps, objects_with_grasps

# `fetchbench objects stats` (and catalog.stats()) report grasp counts once this package is loaded.
_catalog.register_stats_extension(add_grasp_stats)

__all__ = ["Grasps", "load_grasps", "objects_with_grasps", "TCP_OFFSET", "MAX_OPENING"]
