"""The DeepMind Control Suite's ball-in-cup catch (dm_control/suite/ball_in_cup.py), stepped by MJX:
`envs.make("dmc-ball-in-cup-catch")`. A planar cup, moved by two slides, swings a ball tied to it by
a string (a limited spatial tendon) into itself (Euler, timestep 0.002, 10 physics steps per
control step: dt 0.02). The MJCF is dm_control's `ball_in_cup.xml`, read from the installed package.

- Action: Box(-1, 1, (2,)): the cup's x and z motors.
- Observation (8), dm_control's order: position = qpos (cup x, z, ball x, z), velocity = qvel.
- Reward: 1 when the ball's centre lies inside the cup's target box shrunk by the ball's radius
  (|target - ball| in x and z below target half-size - ball radius), else 0.
- Reset: the cup at qpos0; the ball x U(-0.2, 0.2), z U(0.2, 0.5), drawn again until nothing touches
  (dm_control's loop on `ncon > 0` after a forward pass; here a `lax.while_loop` on MJX's contact
  slots closer than their margin), at rest.
- Episode: 1,000 steps (20 s simulated), never terminated.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv


class DmcBallInCupCatch(DmControlEnv):
    costly_reset = True
    domain, task = "ball_in_cup", "catch"
    control_timestep = 0.02  # dm_control's _CONTROL_TIMESTEP
    observation_shapes = (("position", 4), ("velocity", 4))

    def _draw(self, key):
        x_key, z_key = jax.random.split(key)
        qpos = jnp.asarray(self.mj_model.qpos0, self._initial_data.qpos.dtype)
        ball_x, ball_z = self.mj_model.joint("ball_x").qposadr[0], self.mj_model.joint("ball_z").qposadr[0]
        qpos = qpos.at[ball_x].set(jax.random.uniform(x_key, minval=-0.2, maxval=0.2))
        return qpos.at[ball_z].set(jax.random.uniform(z_key, minval=0.2, maxval=0.5))

    def initial_qpos_qvel(self, key):
        return self.drawn_until_apart(key, self._draw), jnp.zeros(self.mj_model.nv)

    def observations(self, data):
        return {"position": data.qpos, "velocity": data.qvel}

    def reward(self, data, action, prev):
        target, ball = self.mj_model.site("target").id, self.mj_model.body("ball").id
        ball_to_target = jnp.abs(data.site_xpos[target, jnp.array([0, 2])] - data.xpos[ball, jnp.array([0, 2])])
        inner = self.mj_model.site_size[target, [0, 2]] - self.mj_model.geom_size[self.mj_model.geom("ball").id, 0]
        return jnp.all(ball_to_target < inner).astype(data.qpos.dtype)
