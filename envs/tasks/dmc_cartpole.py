"""The DeepMind Control Suite's cart-pole (dm_control/suite/cartpole.py), stepped by MJX:
`envs.make("dmc-cartpole-balance")`, `-balance-sparse`, `-swingup`, `-swingup-sparse`, and the EXTRA
`-two-poles` and `-three-poles`. A pole (or a chain of n poles, each hinged on the top of the one
below) hinged on a cart that slides on a rail (limited to +-1.8 m, RK4, timestep 0.01, one physics
step per control step): keep the poles up (balance) or swing them up and keep them there (swingup,
two and three poles). The MJCF is dm_control's `cartpole.xml`, read from the installed package;
for n poles the chain, the floor and the cameras are edited as dm_control's `_make_model(n)` edits
its XML (here on MuJoCo's `MjSpec`; the test proves the compiled models equal to dm_control's).

- Action: Box(-1, 1, (1,)): the cart's motor (gear 10).
- Observation (2 + 3 n: 5, 8 for two poles, 11 for three), dm_control's order: position = (cart
  position, then each pole's xmat zz and xz, in the world frame), velocity = (cart velocity, each
  hinge's angular velocity).
- Reward, smooth: upright * centered * small_control * small_velocity with upright = the poles' mean
  of (cos + 1) / 2 (cos: the pole's world zz), centered = (1 + tolerance(cart, margin 2)) / 2,
  small_control = (4 + tolerance(ctrl, margin 1, value_at_margin 0, quadratic)) / 5, small_velocity
  = (1 + min over the hinges of tolerance(angular velocity, margin 5)) / 2. Sparse: tolerance(cart,
  (-0.25, 0.25)) * the product over the poles of tolerance(cos, (0.995, 1)), 0 or 1.
- Reset: swingup (two and three poles too): cart 0.01 N(0, 1), first hinge pi + 0.01 N(0, 1), the
  other hinges 0.1 N(0, 1) (relative to the pole below); balance: cart U(-0.1, 0.1), hinge
  U(-0.034, 0.034); both: velocities 0.01 N(0, 1).
- Episode: 1,000 steps (10 s simulated), never terminated.
"""

from __future__ import annotations

import os
from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco

from envs.tasks.dm_control_suite import DmControlEnv, tolerance

CART_RANGE = (-0.25, 0.25)  # dm_control's Balance._CART_RANGE (sparse reward)
ANGLE_COSINE_RANGE = (0.995, 1.0)  # Balance._ANGLE_COSINE_RANGE
FIRST_POLE_BODY = 2  # dm_control reads the poles as xmat[2:]: every body past the world and the cart


def cartpole_spec(path: os.PathLike, n_poles: int) -> mujoco.MjSpec:
    """dm_control's `cartpole._make_model(n_poles)` on `cartpole.xml`: poles 2..n, each a body
    `pole_i` 1 m up its parent pole (class "pole") with hinge `hinge_i` and capsule `pole_i`; the
    floor moved down to 1 - n - 0.05 and the two cameras back, as its XML edits place them."""
    spec = mujoco.MjSpec.from_file(str(path))
    if n_poles == 1:
        return spec
    pole, parent = spec.find_default("pole"), spec.body("pole_1")
    for index in range(2, n_poles + 1):
        child = parent.add_body(default=pole, name=f"pole_{index}", pos=[0.0, 0.0, 1.0])
        child.childclass = "pole"
        child.add_joint(default=pole, name=f"hinge_{index}")
        child.add_geom(default=pole, name=f"pole_{index}")
        parent = child
    spec.geom("floor").pos = [0.0, 0.0, 1 - n_poles - 0.05]
    spec.camera("fixed").pos = [0.0, -1 - 2 * n_poles, 1.0]
    spec.camera("lookatcart").pos = [0.0, -2 * n_poles, 2.0]
    return spec


class DmcCartPole(DmControlEnv):
    """dm_control's `cartpole.Balance(swing_up, sparse)` on `_make_model(n_poles)`; the tasks below
    fix the three."""

    domain = "cartpole"
    observation_shapes = (("position", 3), ("velocity", 2))
    swing_up: bool
    sparse: bool
    n_poles: ClassVar[int] = 1

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        # One pole: dm_control's XML as it is, loaded as before the chains existed.
        if self.n_poles == 1:
            return super().load_mj_model(path)
        return cartpole_spec(path, self.n_poles).compile()

    def initial_qpos_qvel(self, key):
        cart_key, pole_key, velocity_key = jax.random.split(key, 3)
        others_key = jax.random.fold_in(key, 1)  # beside the split: one pole's draws stay what they were
        nv = self.mj_model.nv
        if self.swing_up:
            qpos = jnp.concatenate([jnp.stack([0.01 * jax.random.normal(cart_key),
                                               jnp.pi + 0.01 * jax.random.normal(pole_key)]),
                                    0.1 * jax.random.normal(others_key, (nv - 2,))])
        else:
            qpos = jnp.concatenate([jax.random.uniform(cart_key, (1,), minval=-0.1, maxval=0.1),
                                    jax.random.uniform(pole_key, (nv - 1,), minval=-0.034, maxval=0.034)])
        return qpos, 0.01 * jax.random.normal(velocity_key, (nv,))

    def _pole_cosines(self, data):
        return data.xmat[FIRST_POLE_BODY:, 2, 2]

    def observations(self, data):
        poles = data.xmat[FIRST_POLE_BODY:]
        position = jnp.concatenate([data.qpos[:1], jnp.stack([poles[:, 2, 2], poles[:, 0, 2]], axis=1).ravel()])
        return {"position": position, "velocity": data.qvel}

    def reward(self, data, action, prev):
        cart, cosines = data.qpos[0], self._pole_cosines(data)
        if self.sparse:
            return tolerance(cart, CART_RANGE) * tolerance(cosines, ANGLE_COSINE_RANGE).prod()
        upright = ((cosines + 1) / 2).mean()
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


class DmcCartPoleTwoPoles(DmcCartPole):
    task, swing_up, sparse, n_poles = "two_poles", True, False, 2
    observation_shapes = (("position", 5), ("velocity", 3))


class DmcCartPoleThreePoles(DmcCartPole):
    task, swing_up, sparse, n_poles = "three_poles", True, False, 3
    observation_shapes = (("position", 7), ("velocity", 4))
