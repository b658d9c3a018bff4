"""Planning stack, all in the robot base frame:

- ``robot``: a robot setup's model (the Panda from ManiSkill's URDF by default, the others of
  ``fetchbench_ms.robots`` from their generated URDFs), batched FK, fitted collision
  spheres, self pairs;
- ``world``: collision worlds answering batched signed distances (exact primitives, convex
  parts as half-spaces, point clouds as a 5 mm distance field), in named groups;
- ``checker``: configuration validity (limits, self, world, a carried object);
- ``ik``: batched multi-seed collision-aware damped-least-squares IK;
- ``rrt``: OMPL RRTConnect with batched edge checks, simplification, dense re-check;
- ``timing``: trapezoidal time parametrisation to joint-position targets;
- ``exact``: python-fcl checks on the real link meshes, to validate plans;
- ``distance``: the worlds and the robot's spheres as differentiable torch distances,
  batched over problems, on any device;
- ``trajopt``: the cuRobo-style trajectory optimiser (seeds, MPPI, Adam), returning the
  same ``PlanResult`` as ``rrt`` (docs/planning.md);
- ``collision_net``: the learned scene-collision network (observed cloud + query spheres ->
  collision probability), CabiNet-style;
- ``mppi``: receding-horizon MPPI in joint space, scored by the network or by ``distance``.
"""
from .checker import Attachment, CollisionChecker
from .ik import IKResult, solve_ik
from .robot import Q_DEFAULT, PandaModel, RobotModel, panda, robot_for_env, robot_model
from .rrt import PlanResult, plan_rrtconnect
from .timing import time_parametrize
from .trajopt import TrajoptConfig, plan_trajopt, plan_trajopt_batch, plan_trajopt_to_pose
from .world import CollisionWorld, PointCloudField

__all__ = ["Attachment", "CollisionChecker", "CollisionWorld", "IKResult", "PandaModel", "PlanResult",
           "PointCloudField", "Q_DEFAULT", "RobotModel", "TrajoptConfig", "panda", "plan_rrtconnect", "plan_trajopt",
           "plan_trajopt_batch", "plan_trajopt_to_pose", "robot_for_env", "robot_model", "solve_ik",
           "time_parametrize"]
