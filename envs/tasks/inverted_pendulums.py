"""Gymnasium's InvertedPendulum-v5 and InvertedDoublePendulum-v5, stepped by MJX.

Both read their MJCF from the installed gymnasium package (`gymnasium_asset`) and follow
`gymnasium/envs/mujoco/inverted_pendulum_v5.py` and `inverted_double_pendulum_v5.py`:

- InvertedPendulum: frame skip 2 (dt 0.04 s), observation (qpos, qvel), reward 1 while
  |pole angle| <= 0.2 and 0 on the step that ends the episode (angle > 0.2 or a non-finite
  observation), reset qpos, qvel = init + U(-reset_noise_scale, reset_noise_scale).
- InvertedDoublePendulum: frame skip 5 (dt 0.05 s), observation (cart x, sin and cos of the
  two hinge angles, qvel clipped to +-10, the cart's constraint force clipped to +-10),
  reward healthy_reward (0 on the terminating step) - 0.01 x_tip^2 - (y_tip - 2)^2
  - 1e-3 w1^2 - 5e-3 w2^2, terminated when the tip's height y_tip <= 1; reset qpos = init +
  U(-reset_noise_scale, reset_noise_scale), qvel = init + reset_noise_scale * N(0, 1).

Both integrate with RK4 (the MJCF's option): after a step MuJoCo's derived quantities
(`site_xpos`, `qfrc_constraint`) are those of RK4's last stage, in C MuJoCo (what Gymnasium
reads) and in MJX alike. Actions: ours in [-1, 1] scaled to the actuator's ctrlrange, which is
[-3, 3] (InvertedPendulum) and [-1, 1] (InvertedDoublePendulum) in Gymnasium's action units.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from envs.mjx_env import mjx
from envs.ranges import FINITE, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class InvertedPendulumParams:
    """InvertedPendulum-v5's constructor arguments (same names and defaults)."""

    reset_noise_scale: float = 0.01  # qpos, qvel = init + U(-scale, scale)

    RANGES: ClassVar[dict[str, Valid]] = {"reset_noise_scale": NON_NEGATIVE}


@struct.dataclass
class InvertedDoublePendulumParams:
    """InvertedDoublePendulum-v5's constructor arguments (same names and defaults)."""

    healthy_reward: float = 10.0  # paid on every step that does not terminate
    reset_noise_scale: float = 0.1  # qpos = init + U(-scale, scale), qvel = init + scale * N(0, 1)

    RANGES: ClassVar[dict[str, Valid]] = {"healthy_reward": FINITE, "reset_noise_scale": NON_NEGATIVE}


class InvertedPendulum(GymnasiumMujocoEnv):
    """Gymnasium's InvertedPendulum-v5: balance a pole on a cart (see the module docs)."""

    gymnasium_id = "InvertedPendulum-v5"
    xml_file = "inverted_pendulum.xml"
    frame_skip = 2
    observation_size = 4  # qpos and qvel, nothing left out
    observation_names = ("cart_x", "pole_angle", "cart_velocity", "pole_angular_velocity")
    max_pole_angle = 0.2  # rad; Gymnasium terminates past it

    def __init__(self, params: InvertedPendulumParams = InvertedPendulumParams(), xml: str | None = None):
        super().__init__(params, xml)

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos, data.qvel])

    def terminated(self, data: mjx.Data) -> jax.Array:
        return ~jnp.isfinite(self.observation(data)).all() | (jnp.abs(data.qpos[1]) > self.max_pole_angle)

    def reward(self, data, action, prev):
        survive = jnp.where(self.terminated(data), 0.0, 1.0)
        return survive, {"reward_survive": survive}


class InvertedDoublePendulum(GymnasiumMujocoEnv):
    """Gymnasium's InvertedDoublePendulum-v5: balance two stacked poles on a cart."""

    gymnasium_id = "InvertedDoublePendulum-v5"
    xml_file = "inverted_double_pendulum.xml"
    frame_skip = 5
    observation_size = 9
    observation_names = ("cart_x", "sin_hinge1", "sin_hinge2", "cos_hinge1", "cos_hinge2",
                         "cart_velocity", "hinge1_velocity", "hinge2_velocity", "cart_constraint_force")
    # The observation reads the tip site and the cart's constraint force, which mjx.forward
    # computes at reset as Gymnasium's set_state (mj_forward) does.
    forward_on_reset = True
    min_tip_height = 1.0  # m; Gymnasium terminates when the tip is at or below it
    observation_clip = 10.0  # Gymnasium clips qvel and the constraint force to +-10 in the observation

    def __init__(self, params: InvertedDoublePendulumParams = InvertedDoublePendulumParams(), xml: str | None = None):
        super().__init__(params, xml)

    def initial_qvel_noise(self, key: jax.Array) -> jax.Array:
        return self.params.reset_noise_scale * jax.random.normal(key, self.init_qvel.shape)

    def observation(self, data: mjx.Data) -> jax.Array:
        clip = self.observation_clip
        return jnp.concatenate([
            data.qpos[:1],
            jnp.sin(data.qpos[1:]),
            jnp.cos(data.qpos[1:]),
            jnp.clip(data.qvel, -clip, clip),
            jnp.clip(data.qfrc_constraint, -clip, clip)[:1],
        ])

    def terminated(self, data: mjx.Data) -> jax.Array:
        return data.site_xpos[0, 2] <= self.min_tip_height

    def reward(self, data, action, prev):
        x, _, y = data.site_xpos[0]
        w1, w2 = data.qvel[1], data.qvel[2]
        distance_penalty = 0.01 * x**2 + (y - 2) ** 2
        velocity_penalty = 1e-3 * w1**2 + 5e-3 * w2**2
        survive = jnp.where(self.terminated(data), 0.0, self.params.healthy_reward)
        terms = {"reward_survive": survive, "distance_penalty": -distance_penalty, "velocity_penalty": -velocity_penalty}
        return survive - distance_penalty - velocity_penalty, terms
