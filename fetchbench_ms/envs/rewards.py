"""The dense reward of the FetchBench envs (docs/rl.md): the stages of a fetch (reach, grasp,
lift, carry, hold), each in [0, 1], weighted, times penalties for disturbing the other objects
and pushing the furniture; the maximum on success. Read from the env's ``evaluate()`` info
and the TCP's and target's poses (``FetchBenchEnv.reward_terms``, ``compute_dense_reward``)."""
from __future__ import annotations

import torch
from mani_skill.utils.geometry.rotation_conversions import quaternion_to_matrix

from .judging import SUCCESS_CRITERIA

#: The dense reward (``FetchBenchEnv.reward_terms``, docs/rl.md): the stages of a fetch,
#: each in [0, 1], times these weights. A later stage counts only once the earlier ones
#: hold (grasp, lift, carry and hold need the grasp), so a state of a later stage earns
#: more than any state of an earlier one; success earns the maximum.
REWARD_WEIGHTS = {"reach": 1.0, "grasp": 1.0, "lift": 1.0, "carry": 2.0, "hold": 1.0}
DENSE_REWARD_MAX = sum(REWARD_WEIGHTS.values())  # 6
REACH_TOLERANCE = 0.02  # m of TCP-to-surface distance that count as reached (the TCP sits between the pads)
REACH_SCALE = 5.0  # 1/m: reach = 1 - tanh(5 * distance beyond the tolerance)
LIFT_HEIGHT = 0.05  # m above its start at which the target is off its support
CARRY_MARGIN = 0.05  # m past the success thresholds the carry term aims at
CARRY_SCALE = 3.0  # 1/m
HOLD_SPEED_SCALE = 5.0  # s/m: hold = 1 - tanh(5 * target speed) once in the success region
#: Penalties, as fractions of the stage reward taken away: others' largest displacement
#: (at the success threshold, 0.10 m, and beyond) and robot-furniture contact.
DISTURB_PENALTY = 0.5
CONTACT_PENALTY = 0.25
CONTACT_FORCE = 1.0  # N: a robot link pushing furniture or the robot table harder than this is in contact


def target_surface_distance(env) -> torch.Tensor:
    """[B] distance from the TCP to the nearest of the target's surface points (the TCP
    taken into the target's frame: one point turned instead of 512)."""
    pose = env.target.pose
    R = quaternion_to_matrix(pose.q)  # [B, 3, 3]
    tcp_local = ((env.agent.tcp.pose.p - pose.p)[:, None] @ R)[:, 0]  # R^T (tcp - p), as a row
    return torch.linalg.norm(env.built.target_surface - tcp_local[:, None], dim=-1).min(dim=1).values


def reward_terms(env, info: dict) -> dict[str, torch.Tensor]:
    """The dense reward's parts, each [B] in [0, 1]:

    - ``reach``: 1 - tanh(5 x the TCP's distance to the target's surface beyond 2 cm); 1 once grasped;
    - ``grasp``: both fingers push on the target (``is_grasped``);
    - ``lift``: grasped, and the target's rise above its start over 5 cm (1 in the success region);
    - ``carry``: grasped, and 1 - tanh(3 x the target's distance to 5 cm inside the
      success region, in the base frame): out of the furniture toward the free space;
    - ``hold``: grasped inside the success region (lifted and retrieved), and still:
      1 - tanh(5 x the target's speed);
    - ``disturb``: the other objects' largest move over the success threshold (0.10 m), clipped to 1;
    - ``contact``: a robot link (not the base) pushes furniture or the robot table > 1 N.
    """
    c = SUCCESS_CRITERIA[env.success_criteria]
    grasped = info["is_grasped"].float()
    reach = torch.maximum(1 - torch.tanh(REACH_SCALE * torch.relu(env.target_surface_distance() - REACH_TOLERANCE)),
                          grasped)
    in_region = (info["is_above_height"] & info["is_retrieved"]).float()
    # Out in the success region counts as off the support, also where the carry went
    # down from a high shelf to below the target's start height.
    lift = grasped * torch.maximum(torch.clamp(info["target_lift"] / LIFT_HEIGHT, 0.0, 1.0), in_region)
    com = info["target_com_base"]
    shortfall = torch.stack([torch.relu(com[:, 0] - (c["max_x"] - CARRY_MARGIN)),
                             torch.relu((c["min_height"] + CARRY_MARGIN) - com[:, 2])], dim=1)
    carry = grasped * (1 - torch.tanh(CARRY_SCALE * torch.linalg.norm(shortfall, dim=1)))
    speed = torch.linalg.norm(env.target.linear_velocity, dim=1)
    hold = grasped * in_region * (1 - torch.tanh(HOLD_SPEED_SCALE * speed))
    disturb = torch.clamp(info["max_others_moved"] / c["max_others_moved"], 0.0, 1.0)
    force = info.get("robot_furniture_force")
    contact = (force > CONTACT_FORCE).float() if force is not None else torch.zeros_like(grasped)
    return dict(reach=reach, grasp=grasped, lift=lift, carry=carry, hold=hold, disturb=disturb, contact=contact)


def dense_reward(env, info: dict) -> torch.Tensor:
    """The weighted stages (``REWARD_WEIGHTS``, at most 6) of ``env.reward_terms`` times the
    penalty factor (1 - 0.5 disturb)(1 - 0.25 contact), in [0, 6]; 6 on success."""
    terms = env.reward_terms(info)
    stages = sum(weight * terms[name] for name, weight in REWARD_WEIGHTS.items())
    factor = (1 - DISTURB_PENALTY * terms["disturb"]) * (1 - CONTACT_PENALTY * terms["contact"])
    reward = stages * factor
    return torch.where(info["success"], torch.full_like(reward, DENSE_REWARD_MAX), reward)
