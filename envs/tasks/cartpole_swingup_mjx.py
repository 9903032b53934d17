"""Cart-pole swing-up, after the DeepMind Control Suite's `cartpole.swingup`.

The pole starts hanging down (plus a little noise); a continuous force on the
cart must swing it up and balance it there, with the cart near the centre,
little force and a slow pole. Model: assets/cartpole_swingup.xml (dm_control's
cart-pole: dt = 0.01, RK4, the slider limited to +-1.8 m). Episodes are 1000 steps
(10 s simulated) and never terminate; each step's reward lies in [0, 1], so returns lie in
[0, 1000].

Observation (5): cart position, cos and sin of the pole angle (angle 0 = upright),
cart velocity, pole angular velocity. Action (1): force in [-1, 1] (x 10 N).

Reward, as dm_control's smooth reward:
    upright        = (cos(angle) + 1) / 2
    centered       = (1 + gaussian(cart position, margin 2)) / 2
    small_control  = (4 + quadratic(force, margin 1)) / 5
    small_velocity = (1 + gaussian(pole angular velocity, margin 5)) / 2
    reward = upright * centered * small_control * small_velocity
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from envs.mjx_env import MjxEnv, mjx
from envs.ranges import NON_NEGATIVE, POSITIVE, Range


def gaussian_tolerance(x: jax.Array, margin: float, value_at_margin: float = 0.1) -> jax.Array:
    """1 at x = 0, `value_at_margin` at |x| = margin, a Gaussian bell in between and beyond
    (dm_control's `rewards.tolerance(x, margin=margin)` with its default sigmoid)."""
    return value_at_margin ** ((x / margin) ** 2)


def quadratic_tolerance(x: jax.Array, margin: float) -> jax.Array:
    """1 at x = 0, falling as 1 - (x / margin)^2 to 0 at |x| = margin and 0 beyond
    (dm_control's `rewards.tolerance(x, margin=margin, value_at_margin=0, sigmoid="quadratic")`)."""
    return jnp.maximum(1.0 - (x / margin) ** 2, 0.0)


@dataclasses.dataclass(frozen=True)
class SwingUpRules:
    """The task around the physics: reset noise and the reward's margins (dm_control's values)."""

    reset_noise: float = 0.01  # std of the Gaussian noise on every coordinate at reset
    cart_margin: float = 2.0  # m from the centre where `centered` has dropped to (1 + 0.1) / 2
    control_margin: float = 1.0  # |action| where `small_control` has dropped to 4 / 5
    velocity_margin: float = 5.0  # rad/s where `small_velocity` has dropped to (1 + 0.1) / 2

    # What `envs.make` accepts as overrides.
    RANGES: ClassVar[dict[str, Range]] = {"reset_noise": NON_NEGATIVE, "cart_margin": POSITIVE,
                                          "control_margin": POSITIVE, "velocity_margin": POSITIVE}


class CartPoleSwingUpMjx(MjxEnv):
    xml = "cartpole_swingup.xml"
    observation_size = 5
    observation_names = ("x", "cos_theta", "sin_theta", "x_dot", "theta_dot")
    # No action_bins: the force is continuous, action in [-1, 1] scaled to ctrlrange.

    def __init__(self, rules: SwingUpRules = SwingUpRules(), xml: str | None = None):
        super().__init__(xml)
        self.rules = rules

    def initial_qpos_qvel(self, key):
        key_pos, key_vel = jax.random.split(key)
        noise = self.rules.reset_noise
        hanging_down = jnp.array([0.0, jnp.pi])
        qpos = hanging_down + noise * jax.random.normal(key_pos, (2,))
        qvel = noise * jax.random.normal(key_vel, (2,))
        return qpos, qvel

    def observation(self, data: mjx.Data) -> jax.Array:
        x, theta = data.qpos
        x_dot, theta_dot = data.qvel
        return jnp.stack([x, jnp.cos(theta), jnp.sin(theta), x_dot, theta_dot])

    def reward(self, data, action, prev):
        rules = self.rules
        x, theta = data.qpos
        force = data.ctrl[0]  # the action as applied (already clipped to [-1, 1])
        upright = (jnp.cos(theta) + 1.0) / 2.0
        centered = (1.0 + gaussian_tolerance(x, rules.cart_margin)) / 2.0
        small_control = (4.0 + quadratic_tolerance(force, rules.control_margin)) / 5.0
        small_velocity = (1.0 + gaussian_tolerance(data.qvel[1], rules.velocity_margin)) / 2.0
        return upright * centered * small_control * small_velocity

    def terminated(self, data):
        return jnp.zeros((), bool)  # the swing-up never ends early; the time limit truncates it

    def __repr__(self) -> str:
        return f"CartPoleSwingUpMjx(rules={self.rules})"
