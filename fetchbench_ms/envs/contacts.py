"""What the env reads of the contacts: the grasp test (both fingers push on the target) and
the force between the robot and the furniture that the dense reward's contact term reads.

On the GPU these are ManiSkill's own (``agent.is_grasping``) and one pairwise impulse query.
On the CPU one pass over the scene's contact list serves both, as a Python walk of it per
finger would cost more than the physics step: this reads the SAPIEN bodies behind ManiSkill's
links and actors (``_bodies``), which ManiSkill has no public accessor for.
"""
from __future__ import annotations

from typing import Optional

import numpy as np
import torch
from mani_skill.utils import common

# Farthest a finger pad can be from the TCP (the pads span ~2 cm along the hand axis
# around the TCP; 4 cm of opening across), with a margin: beyond the target's radius plus
# this, the fingers cannot touch it.
FINGER_REACH = 0.08  # m


class ContactQueries:
    """The contact look-ups of one built scene (made again with every reconfiguration)."""

    def __init__(self, env):
        """What the reward's contact terms look up: the robot links that count for
        robot-furniture contact (all but the base, which stands on the robot table) and the
        static furniture and robot table of each sub-scene. On the GPU one pairwise impulse
        query holds every (link, furniture / robot table) pair of every sub-scene; on the
        CPU the contact list is walked once a step (``forces_cpu``)."""
        b = env.built
        links = [link for link in env.agent.robot.links if link.name != env.robot_setup.base_link]
        if env.gpu_sim_enabled:
            # Made on first use (as ManiSkill's own pairwise queries), after the GPU system is set up.
            self._furniture_query = None
            self._furniture_pairs = [(link._bodies[i], statics[i]._bodies[0]) for link in links
                                     for statics in (b.furniture, b.robot_tables) for i in range(env.num_envs)]
            self._furniture_query_shape = (len(links) * 2, env.num_envs, 3)
            return
        # The physics components themselves: SAPIEN hands out the same Python object for a
        # body every time, so a contact's bodies are found by identity (4x faster than
        # comparing entity ids, with ~150 resting contacts a step).
        self._robot_bodies = frozenset(link._bodies[0] for link in links)
        self._furniture_bodies = frozenset(a._bodies[0] for a in b.furniture + b.robot_tables)
        self._finger_bodies = (env.agent.finger1_link._bodies[0], env.agent.finger2_link._bodies[0])

    def is_grasping(self, env, target_com_world: torch.Tensor, contacts: Optional[dict] = None) -> torch.Tensor:
        """The Panda's grasp test: both fingers push on the target (>= 0.5 N, within 85 deg
        of their closing direction), as ``Panda.is_grasping``.

        On CPU that test walks the scene's contact list in Python twice (once per finger),
        which with ~15 resting objects costs more than the physics step. Here the fingers'
        forces come from one pass that also serves the reward's furniture contacts
        (``contacts``, from ``forces_cpu``), and without it the test is skipped
        while the TCP is too far for the fingers to touch the target."""
        if env.gpu_sim_enabled:
            return env.agent.is_grasping(env.target)
        not_grasping = torch.zeros(env.num_envs, dtype=torch.bool, device=env.device)
        reach = env.built.target_radius + FINGER_REACH
        if not bool((torch.linalg.norm(env.agent.tcp.pose.p - target_com_world, dim=1) < reach).any()):
            return not_grasping
        if contacts is None:
            contacts = env._contact_forces_cpu(furniture=False)
        l_force, r_force = contacts["finger_forces"]
        if not (bool(l_force.any()) and bool(r_force.any())):
            return not_grasping
        agent = env.agent
        l_sign, r_sign = env.robot_setup.finger_open_signs
        l_open = l_sign * agent.finger1_link.pose.to_transformation_matrix()[..., :3, 1]  # direction that opens the finger
        r_open = r_sign * agent.finger2_link.pose.to_transformation_matrix()[..., :3, 1]
        flags = []
        for force, direction in ((l_force, l_open), (r_force, r_open)):
            angle = common.compute_angle_between(direction, force)
            flags.append((torch.linalg.norm(force, dim=1) >= 0.5) & (torch.rad2deg(angle) <= 85))
        return flags[0] & flags[1]

    def forces_cpu(self, env, furniture: bool = True) -> dict:
        """One pass over the CPU contact list: ``finger_forces``, the target's contact force
        [1, 3] on each finger, and (``furniture``) ``robot_furniture_force`` [1], the
        total force between robot links (not the base) and the furniture / robot table."""
        fingers, target = self._finger_bodies, env.target._bodies[0]
        robot, statics = self._robot_bodies, self._furniture_bodies
        finger_impulse = np.zeros((2, 3))
        furniture_impulse = 0.0
        for contact in env.scene.px.get_contacts():
            b0, b1 = contact.bodies
            if b1 is target or b0 is target:
                # Impulses act on the first body.
                finger, sign = (b0, 1.0) if b1 is target else (b1, -1.0)
                for k in (0, 1):
                    if finger is fingers[k]:
                        finger_impulse[k] += sign * np.sum([point.impulse for point in contact.points], axis=0)
            elif furniture and ((b0 in robot and b1 in statics) or (b1 in robot and b0 in statics)):
                furniture_impulse += float(np.linalg.norm(np.sum([p.impulse for p in contact.points], axis=0)))
        dt = env.scene.px.timestep
        forces = torch.tensor(finger_impulse / dt, dtype=torch.float32, device=env.device)
        return dict(finger_forces=(forces[0:1], forces[1:2]),
                    robot_furniture_force=torch.tensor([furniture_impulse / dt], dtype=torch.float32, device=env.device))

    def robot_furniture_force_gpu(self, env) -> torch.Tensor:
        """[B] total force between robot links and furniture / robot table (GPU sim)."""
        if self._furniture_query is None:
            self._furniture_query = env.scene.px.gpu_create_contact_pair_impulse_query(self._furniture_pairs)
        env.scene.px.gpu_query_contact_pair_impulses(self._furniture_query)
        impulses = self._furniture_query.cuda_impulses.torch().reshape(self._furniture_query_shape)
        return torch.linalg.norm(impulses, dim=-1).sum(dim=0) / env.scene.px.timestep
