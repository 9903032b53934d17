"""Gymnasium's planar walkers stepped by MJX: Hopper-v5 and Walker2d-v5
(gymnasium/envs/mujoco/hopper_v5.py and walker2d_v5.py).

Both move in the x-z plane on three root joints (rootx, rootz, rooty: the torso's x, height
and pitch) and are rewarded for moving forward while healthy:
reward = forward_reward_weight * x_velocity + healthy_reward * healthy - ctrl_cost_weight * |ctrl|^2,
where healthy means the torso's height and pitch lie inside open intervals (and for the Hopper
every other coordinate of qpos and qvel too). An unhealthy state ends the episode unless
`terminate_when_unhealthy=False`; Gymnasium truncates at 1000 steps. The observation clips the
velocities to +-10 (the state itself is not clipped). Reset: qpos0 + U(-s, s), velocities U(-s, s),
s = reset_noise_scale. RK4 at timestep 0.002, frame skip 4: dt = 0.008.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from envs.mjx_env import mjx
from envs.ranges import FINITE, FLAG, INTERVAL, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv

# The options both walkers take, checked by envs.make before anything compiles.
WALKER_RANGES: dict[str, Valid] = {
    "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "healthy_reward": FINITE,
    "terminate_when_unhealthy": FLAG, "healthy_z_range": INTERVAL, "healthy_angle_range": INTERVAL,
    "reset_noise_scale": NON_NEGATIVE, "exclude_current_positions_from_observation": FLAG}


@struct.dataclass
class HopperParams:
    """Hopper-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-3
    healthy_reward: float = 1.0
    terminate_when_unhealthy: bool = struct.field(pytree_node=False, default=True)
    healthy_state_range: tuple[float, float] = (-100.0, 100.0)  # every qpos[2:] and qvel
    healthy_z_range: tuple[float, float] = (0.7, math.inf)
    healthy_angle_range: tuple[float, float] = (-0.2, 0.2)
    reset_noise_scale: float = 5e-3
    # Changes the observation's size, so it is fixed at construction (not a pytree leaf).
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {**WALKER_RANGES, "healthy_state_range": INTERVAL}


@struct.dataclass
class Walker2dParams:
    """Walker2d-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-3
    healthy_reward: float = 1.0
    terminate_when_unhealthy: bool = struct.field(pytree_node=False, default=True)
    healthy_z_range: tuple[float, float] = (0.8, 2.0)
    healthy_angle_range: tuple[float, float] = (-1.0, 1.0)
    reset_noise_scale: float = 5e-3
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = WALKER_RANGES


def inside(value: jnp.ndarray, interval: tuple[float, float]) -> jnp.ndarray:
    """low < value < high (Gymnasium's strict comparisons), for every element."""
    low, high = interval
    return jnp.all((low < value) & (value < high))


class PlanarWalker(GymnasiumMujocoEnv):
    """What Hopper-v5 and Walker2d-v5 share: everything but the model and the Hopper's state check."""

    frame_skip = 4
    velocity_clip = 10.0

    def is_healthy(self, data: mjx.Data) -> jnp.ndarray:
        z, angle = data.qpos[1], data.qpos[2]
        return inside(z, self.params.healthy_z_range) & inside(angle, self.params.healthy_angle_range)

    def reward(self, data, action, prev):
        p = self.params
        x_velocity = self.velocity(data, prev)
        forward_reward = p.forward_reward_weight * x_velocity
        # v5 pays the healthy reward only in a healthy state, whether or not that ends the episode.
        healthy_reward = jnp.where(self.is_healthy(data), p.healthy_reward, 0.0)
        ctrl_cost = self.control_cost(data)
        terms = {"reward_forward": forward_reward, "reward_ctrl": -ctrl_cost, "reward_survive": healthy_reward,
                 "x_position": data.qpos[0], "z_distance_from_origin": data.qpos[1] - self.init_qpos[1],
                 "x_velocity": x_velocity}
        return forward_reward + healthy_reward - ctrl_cost, terms

    def terminated(self, data):
        return ~self.is_healthy(data) & self.params.terminate_when_unhealthy


class Hopper(PlanarWalker):
    gymnasium_id = "Hopper-v5"
    xml_file = "hopper.xml"

    def __init__(self, params: HopperParams = HopperParams(), xml: str | None = None):
        super().__init__(params, xml)

    def is_healthy(self, data):
        # Gymnasium's state_vector()[2:]: every coordinate but x and z, velocities included.
        state = jnp.concatenate([data.qpos[2:], data.qvel])
        return super().is_healthy(data) & inside(state, self.params.healthy_state_range)


class Walker2d(PlanarWalker):
    gymnasium_id = "Walker2d-v5"
    xml_file = "walker2d_v5.xml"

    def __init__(self, params: Walker2dParams = Walker2dParams(), xml: str | None = None):
        super().__init__(params, xml)
