"""Planning stack: Panda sphere model + batched FK, collision worlds (primitives, point
clouds), collision-aware IK, OMPL RRTConnect and time parametrisation."""
