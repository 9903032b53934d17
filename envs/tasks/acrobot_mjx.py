"""Acrobot-v1 as an MJCF model (assets/acrobot.xml) stepped by MJX.

Same observation, actions, reward, reset and termination as the analytic
`envs.tasks.acrobot`. MuJoCo's RK4 integrator with ctrl held over the step is
Gymnasium's rk4; the velocity clip and angle wrap Gymnasium applies after each
step happen in `post_step`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.mjx_env import MjxEnv, mjx
from envs.tasks.acrobot import AcrobotRules, observation, wrap_angle


class AcrobotMjx(MjxEnv):
    xml = "acrobot.xml"
    observation_size = 6
    observation_names = ("cos_theta1", "sin_theta1", "cos_theta2", "sin_theta2", "dtheta1", "dtheta2")
    # The elbow motor has gear 1, so ctrl is Gymnasium's torque itself.
    action_bins = {"torque_-1": (-1.0,), "torque_0": (0.0,), "torque_+1": (1.0,)}

    def __init__(self, rules: AcrobotRules = AcrobotRules(), xml: str | None = None):
        super().__init__(xml)
        self.rules = rules

    def initial_qpos_qvel(self, key):
        theta1, theta2, dtheta1, dtheta2 = self.rules.initial_state(key)
        return jnp.stack([theta1, theta2]), jnp.stack([dtheta1, dtheta2])

    def post_step(self, prev: mjx.Data, data: mjx.Data) -> mjx.Data:
        # Wrapping changes no physics (it is a whole number of turns) but keeps float32
        # angles small, as Gymnasium's state is; the clip is part of Gymnasium's step.
        dtheta1, dtheta2 = self.rules.clip_velocities(data.qvel[0], data.qvel[1])
        return data.replace(qpos=wrap_angle(data.qpos), qvel=jnp.stack([dtheta1, dtheta2]))

    def observation(self, data: mjx.Data) -> jax.Array:
        return observation(jnp.concatenate([data.qpos, data.qvel]))

    def reward(self, data, action, prev):
        return jnp.where(self.terminated(data), 0.0, -1.0)

    def terminated(self, data):
        return self.rules.is_terminated(data.qpos[0], data.qpos[1])

    def __repr__(self) -> str:
        return f"AcrobotMjx(rules={self.rules})"
