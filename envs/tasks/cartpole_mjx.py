"""CartPole-v1 as an MJCF model (assets/cartpole.xml) stepped by MJX.

Same observation, actions, reward, reset and termination as the analytic
`envs.tasks.cartpole`. MuJoCo's Euler integrator is semi-implicit, so the physics
matches the analytic CartPole with integrator="semi_implicit" (see docs/tasks.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.mjx_env import MjxEnv, mjx
from envs.tasks.cartpole import CartPoleRules


class CartPoleMjx(MjxEnv):
    xml = "cartpole.xml"
    observation_size = 4
    observation_names = ("x", "x_dot", "theta", "theta_dot")
    # The motor's gear turns ctrl +-1 into Gymnasium's +-10 N push.
    action_bins = {"push_left": (-1.0,), "push_right": (1.0,)}

    def __init__(self, rules: CartPoleRules = CartPoleRules(), xml: str | None = None):
        super().__init__(xml)
        self.rules = rules

    def initial_qpos_qvel(self, key):
        x, x_dot, theta, theta_dot = self.rules.initial_state(key)
        return jnp.stack([x, theta]), jnp.stack([x_dot, theta_dot])

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.stack([data.qpos[0], data.qvel[0], data.qpos[1], data.qvel[1]])

    def reward(self, data, action, prev):
        return jnp.ones(())

    def terminated(self, data):
        return self.rules.is_terminated(data.qpos[0], data.qpos[1])

    def __repr__(self) -> str:
        return f"CartPoleMjx(rules={self.rules})"
