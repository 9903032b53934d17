"""Gymnasium's HalfCheetah-v5 stepped by MJX (gymnasium/envs/mujoco/half_cheetah_v5.py).

A planar cheetah (9 joints, 6 motors with ctrlrange [-1, 1]) rewarded for running forward:
reward = forward_reward_weight * x_velocity - ctrl_cost_weight * |ctrl|^2. It never
terminates; Gymnasium truncates it at 1000 steps. Reset: qpos0 + U(-s, s) and velocities
s * N(0, 1), s = reset_noise_scale. Frame skip 5 at timestep 0.01: dt = 0.05.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from envs.ranges import FINITE, FLAG, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class HalfCheetahParams:
    """HalfCheetah-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 0.1
    reset_noise_scale: float = 0.1
    # Changes the observation's size, so it is fixed at construction (not a pytree leaf).
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {
        "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "reset_noise_scale": NON_NEGATIVE,
        "exclude_current_positions_from_observation": FLAG}


class HalfCheetah(GymnasiumMujocoEnv):
    gymnasium_id = "HalfCheetah-v5"
    xml_file = "half_cheetah.xml"
    frame_skip = 5

    def __init__(self, params: HalfCheetahParams = HalfCheetahParams(), xml: str | None = None):
        super().__init__(params, xml)

    def initial_qvel_noise(self, key):
        # HalfCheetah alone draws its velocities from a normal distribution.
        return self.params.reset_noise_scale * jax.random.normal(key, self.init_qvel.shape)

    def reward(self, data, action, prev):
        x_velocity = self.velocity(data, prev)
        forward_reward = self.params.forward_reward_weight * x_velocity
        ctrl_cost = self.control_cost(data)
        terms = {"reward_forward": forward_reward, "reward_ctrl": -ctrl_cost,
                 "x_position": data.qpos[0], "x_velocity": x_velocity}
        return forward_reward - ctrl_cost, terms

    def terminated(self, data):
        return jnp.zeros((), bool)
