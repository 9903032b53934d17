"""Gymnasium's Pendulum-v1 as an MJCF model (assets/pendulum.xml) stepped by MJX.

The model holds the physics (g = 10, m = l = 1, dt = 0.05, torque limit 2 N m);
this task adds what Gymnasium does around it: the speed clip between the velocity
and the angle update, the reward on the state *before* the step, the observation
(cos theta, sin theta, theta_dot) and the reset distribution. It never terminates;
the registry truncates it at 200 steps, as Gymnasium's TimeLimit does.

Actions: continuous in [-1, 1] (scaled to the torque range [-2, 2] by MjxEnv), or,
with `action_bins=n`, n evenly spaced torques from -2 to 2 for DQN.
"""

from __future__ import annotations

import functools
import math
from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from envs.mjx_env import ActionBins, MjxEnv, mjx
from envs.ranges import NON_NEGATIVE, POSITIVE, Range

# Torque bins of `pendulum-mjx-discrete`: -2, -1.5, ..., 2 N m. An odd count keeps
# zero torque (to hold the pendulum still once upright) and the full +-2 N m (to swing
# it up). DQN learned as fast with 5 bins as with 9 (docs/tasks.md); 9 give finer balancing.
DISCRETE_TORQUE_BINS = 9


@struct.dataclass
class PendulumParams:
    """The constants the task uses in JAX (the rest is in the MJCF model). A pytree of floats."""

    max_speed: float = 8.0  # rad/s; Gymnasium clips the new speed before it advances the angle
    reset_angle: float = math.pi  # theta ~ U(-reset_angle, reset_angle) at reset
    reset_speed: float = 1.0  # theta_dot ~ U(-reset_speed, reset_speed) at reset
    speed_cost: float = 0.1  # reward = -(theta^2 + speed_cost theta_dot^2 + torque_cost u^2)
    torque_cost: float = 0.001

    # What `envs.make` accepts as overrides (a vmapped pytree of values is not checked).
    RANGES: ClassVar[dict[str, Range]] = {"max_speed": POSITIVE, "reset_angle": NON_NEGATIVE,
                                          "reset_speed": NON_NEGATIVE, "speed_cost": NON_NEGATIVE,
                                          "torque_cost": NON_NEGATIVE}


def angle_normalize(theta: jax.Array) -> jax.Array:
    """theta wrapped to [-pi, pi), as Gymnasium's `angle_normalize`."""
    return (theta + jnp.pi) % (2 * jnp.pi) - jnp.pi


class PendulumMjx(MjxEnv):
    xml = "pendulum.xml"
    observation_size = 3
    observation_names = ("cos_theta", "sin_theta", "theta_dot")

    def __init__(
        self,
        params: PendulumParams = PendulumParams(),
        action_bins: ActionBins | int | None = None,
        xml: str | None = None,
    ):
        super().__init__(xml, action_bins)
        self.params = params

    def initial_qpos_qvel(self, key):
        angle_key, speed_key = jax.random.split(key)
        p = self.params
        theta = jax.random.uniform(angle_key, (1,), minval=-p.reset_angle, maxval=p.reset_angle)
        theta_dot = jax.random.uniform(speed_key, (1,), minval=-p.reset_speed, maxval=p.reset_speed)
        return theta, theta_dot

    def post_step(self, prev: mjx.Data, data: mjx.Data) -> mjx.Data:
        # mjx.step advanced the angle with the unclipped speed; Gymnasium clips the speed
        # first and advances the angle with the clipped one, so redo that last update.
        theta_dot = jnp.clip(data.qvel, -self.params.max_speed, self.params.max_speed)
        theta = prev.qpos + theta_dot * self.dt
        return data.replace(qpos=theta, qvel=theta_dot)

    def observation(self, data: mjx.Data) -> jax.Array:
        theta, theta_dot = data.qpos[0], data.qvel[0]
        return jnp.stack([jnp.cos(theta), jnp.sin(theta), theta_dot])

    def reward(self, data, action, prev):
        # Gymnasium charges the state the action was taken in, not the one it led to.
        theta, theta_dot = prev.qpos[0], prev.qvel[0]
        torque = data.qfrc_actuator[0]  # N m on the hinge, after the ctrlrange clip and gear
        p = self.params
        return -(angle_normalize(theta) ** 2 + p.speed_cost * theta_dot**2 + p.torque_cost * torque**2)

    def terminated(self, data):
        return jnp.zeros((), bool)

    def __repr__(self) -> str:
        bins = "" if self.action_bins is None else f", action_bins={len(self.action_bins)}"
        return f"PendulumMjx(params={self.params}{bins})"


# `pendulum-mjx-discrete`: envs/__init__.py registers it as "module:attr", imported on first use.
PendulumMjxDiscrete = functools.partial(PendulumMjx, action_bins=DISCRETE_TORQUE_BINS)
