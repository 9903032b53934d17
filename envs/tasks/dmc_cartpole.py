"""The DeepMind Control Suite's cart-pole (dm_control/suite/cartpole.py), stepped by MJX:
`envs.make("dmc-cartpole-balance")`, `-balance-sparse`, `-swingup`, `-swingup-sparse`. A pole hinged
on a cart that slides on a rail (limited to +-1.8 m, RK4, timestep 0.01, one physics step per control
step): keep the pole up (balance) or swing it up from hanging down and keep it there (swingup).
The MJCF is dm_control's `cartpole.xml`, read from the installed package.

- Action: Box(-1, 1, (1,)): the cart's motor (gear 10).
- Observation (5), dm_control's order: position = (cart position, pole xmat zz, pole xmat xz), velocity
  = (cart velocity, pole angular velocity).
- Reward, smooth: upright * centered * small_control * small_velocity with upright = (cos + 1) / 2,
  centered = (1 + tolerance(cart, margin 2)) / 2, small_control = (4 + tolerance(ctrl, margin 1,
  value_at_margin 0, quadratic)) / 5, small_velocity = (1 + tolerance(pole velocity, margin 5)) / 2.
  Sparse: tolerance(cart, (-0.25, 0.25)) * tolerance(cos, (0.995, 1)), 0 or 1.
- Reset: swingup: cart 0.01 N(0, 1), pole pi + 0.01 N(0, 1); balance: cart U(-0.1, 0.1), pole
  U(-0.034, 0.034); both: velocities 0.01 N(0, 1).
- Episode: 1,000 steps (10 s simulated), never terminated.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv, tolerance

CART_RANGE = (-0.25, 0.25)  # dm_control's Balance._CART_RANGE (sparse reward)
ANGLE_COSINE_RANGE = (0.995, 1.0)  # Balance._ANGLE_COSINE_RANGE


class DmcCartPole(DmControlEnv):
    """dm_control's `cartpole.Balance(swing_up, sparse)`; the four tasks below fix the two."""

    domain = "cartpole"
    observation_shapes = (("position", 3), ("velocity", 2))
    swing_up: bool
    sparse: bool

    def initial_qpos_qvel(self, key):
        cart_key, pole_key, velocity_key = jax.random.split(key, 3)
        if self.swing_up:
            qpos = jnp.stack([0.01 * jax.random.normal(cart_key), jnp.pi + 0.01 * jax.random.normal(pole_key)])
        else:
            qpos = jnp.stack([jax.random.uniform(cart_key, minval=-0.1, maxval=0.1),
                              jax.random.uniform(pole_key, minval=-0.034, maxval=0.034)])
        return qpos, 0.01 * jax.random.normal(velocity_key, (self.mj_model.nv,))

    def _pole_cosine(self, data):
        return self.body_xmat(data, "pole_1")[2, 2]

    def observations(self, data):
        pole = self.body_xmat(data, "pole_1")
        return {"position": jnp.stack([data.qpos[0], pole[2, 2], pole[0, 2]]), "velocity": data.qvel}

    def reward(self, data, action, prev):
        cart, cosine = data.qpos[0], self._pole_cosine(data)
        if self.sparse:
            return tolerance(cart, CART_RANGE) * tolerance(cosine, ANGLE_COSINE_RANGE)
        upright = (cosine + 1) / 2
        centered = (1 + tolerance(cart, margin=2)) / 2
        small_control = (4 + tolerance(data.ctrl[0], margin=1, value_at_margin=0, sigmoid="quadratic")) / 5
        small_velocity = (1 + tolerance(data.qvel[1:], margin=5).min()) / 2
        return upright * small_control * small_velocity * centered


class DmcCartPoleBalance(DmcCartPole):
    task, swing_up, sparse = "balance", False, False


class DmcCartPoleBalanceSparse(DmcCartPole):
    task, swing_up, sparse = "balance_sparse", False, True


class DmcCartPoleSwingUp(DmcCartPole):
    task, swing_up, sparse = "swingup", True, False


class DmcCartPoleSwingUpSparse(DmcCartPole):
    task, swing_up, sparse = "swingup_sparse", True, True
