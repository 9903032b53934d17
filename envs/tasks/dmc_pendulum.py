"""The DeepMind Control Suite's pendulum swing-up (dm_control/suite/pendulum.py), stepped by MJX:
`envs.make("dmc-pendulum-swingup")`. A pendulum with a weak motor (Euler, timestep 0.02, one physics
step per control step) must swing up and stay within 8 degrees of upright. The MJCF is dm_control's
`pendulum.xml`, read from the installed package.

- Action: Box(-1, 1, (1,)): the hinge's torque.
- Observation (3), dm_control's order: orientation = (pole xmat zz, xz), velocity = (hinge velocity).
- Reward: tolerance(pole xmat zz, (cos 8 deg, 1)): 1 within 8 degrees of upright, else 0.
- Reset: the hinge U(-pi, pi), at rest.
- Episode: 1,000 steps (20 s simulated), never terminated.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs.tasks.dm_control_suite import DmControlEnv, tolerance

COSINE_BOUND = float(np.cos(np.deg2rad(8)))  # dm_control's _COSINE_BOUND (_ANGLE_BOUND = 8 degrees)


class DmcPendulumSwingUp(DmControlEnv):
    domain, task = "pendulum", "swingup"
    observation_shapes = (("orientation", 2), ("velocity", 1))

    def initial_qpos_qvel(self, key):
        return jax.random.uniform(key, (1,), minval=-jnp.pi, maxval=jnp.pi), jnp.zeros(1)

    def observations(self, data):
        pole = self.body_xmat(data, "pole")
        return {"orientation": jnp.stack([pole[2, 2], pole[0, 2]]), "velocity": data.qvel}

    def reward(self, data, action, prev):
        return tolerance(self.body_xmat(data, "pole")[2, 2], (COSINE_BOUND, 1.0))
