"""Gymnasium's Swimmer-v5 stepped by MJX (gymnasium/envs/mujoco/swimmer_v5.py).

Three capsules joined by two motored hinges swim in a viscous fluid (MuJoCo's fluid forces from
the bodies' inertia boxes, density 4000, viscosity 0.1): qpos = (x, y, heading, hinge 1, hinge 2).
reward = forward_reward_weight * x_velocity - ctrl_cost_weight * |ctrl|^2; it never terminates
and Gymnasium truncates it at 1000 steps. The observation leaves out x and y (both, where the
other tasks leave out x alone). Reset: qpos0 + U(-s, s), velocities U(-s, s), s =
reset_noise_scale. RK4 at timestep 0.01, frame skip 4: dt = 0.04.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from envs.ranges import FINITE, FLAG, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class SwimmerParams:
    """Swimmer-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-4
    reset_noise_scale: float = 0.1
    # Changes the observation's size, so it is fixed at construction (not a pytree leaf).
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {
        "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "reset_noise_scale": NON_NEGATIVE,
        "exclude_current_positions_from_observation": FLAG}


class Swimmer(GymnasiumMujocoEnv):
    gymnasium_id = "Swimmer-v5"
    xml_file = "swimmer.xml"
    frame_skip = 4
    skipped_qpos = 2  # x and y

    def __init__(self, params: SwimmerParams = SwimmerParams(), xml: str | None = None):
        super().__init__(params, xml)

    def reward(self, data, action, prev):
        x_velocity, y_velocity = self.velocity(data, prev, 0), self.velocity(data, prev, 1)
        forward_reward = self.params.forward_reward_weight * x_velocity
        ctrl_cost = self.control_cost(data)
        terms = {"reward_forward": forward_reward, "reward_ctrl": -ctrl_cost,
                 "x_position": data.qpos[0], "y_position": data.qpos[1],
                 "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
                 "x_velocity": x_velocity, "y_velocity": y_velocity}
        return forward_reward - ctrl_cost, terms

    def terminated(self, data):
        return jnp.zeros((), bool)
