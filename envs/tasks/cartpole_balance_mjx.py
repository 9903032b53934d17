"""Cart-pole balance, after the DeepMind Control Suite's `cartpole.balance`.

The swing-up's cart-pole (`envs.tasks.cartpole_swingup_mjx`: the same model, observation, action
and reward) with dm_control's balance start: the pole starts nearly upright and must be kept
there, with the cart near the centre, little force and a slow pole. Episodes are 1000 steps
(10 s simulated) and never terminate; each step's reward lies in [0, 1], so returns lie in
[0, 1000] (a policy that holds the pole still scores close to 1000).

Observation (5): cart position, cos and sin of the pole angle (angle 0 = upright),
cart velocity, pole angular velocity. Action (1): force in [-1, 1] (x 10 N).

Reset, as dm_control's balance: cart position uniform in [-cart_start, cart_start] m, pole angle
uniform in [-pole_start, pole_start] rad, both velocities Gaussian with std `reset_noise`.

Reward: the swing-up's (dm_control's smooth reward).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import jax
import jax.numpy as jnp

from envs.ranges import NON_NEGATIVE, Range
from envs.tasks.cartpole_swingup_mjx import CartPoleSwingUpMjx, SwingUpRules


@dataclasses.dataclass(frozen=True)
class BalanceRules(SwingUpRules):
    """The swing-up's rules with dm_control's balance start; `reset_noise` is here the std of
    the velocities' noise only (the positions are drawn uniformly)."""

    cart_start: float = 0.1  # m: the cart starts uniformly within this distance of the centre
    pole_start: float = 0.034  # rad: the pole starts uniformly within this angle of upright

    RANGES: ClassVar[dict[str, Range]] = {**SwingUpRules.RANGES, "cart_start": NON_NEGATIVE,
                                          "pole_start": NON_NEGATIVE}


class CartPoleBalanceMjx(CartPoleSwingUpMjx):
    def __init__(self, rules: BalanceRules = BalanceRules(), xml: str | None = None):
        super().__init__(rules, xml)

    def initial_qpos_qvel(self, key):
        key_cart, key_pole, key_vel = jax.random.split(key, 3)
        rules = self.rules
        qpos = jnp.stack([jax.random.uniform(key_cart, minval=-rules.cart_start, maxval=rules.cart_start),
                          jax.random.uniform(key_pole, minval=-rules.pole_start, maxval=rules.pole_start)])
        qvel = rules.reset_noise * jax.random.normal(key_vel, (2,))
        return qpos, qvel

    def __repr__(self) -> str:
        return f"CartPoleBalanceMjx(rules={self.rules})"
