"""The DeepMind Control Suite's acrobot (dm_control/suite/acrobot.py), stepped by MJX:
`envs.make("dmc-acrobot-swingup")` and `-swingup-sparse`. A two-link pendulum driven at the elbow
only (RK4, timestep 0.01, one physics step per control step) must bring its tip to a target above the
shoulder. The MJCF is dm_control's `acrobot.xml`, read from the installed package.

- Action: Box(-1, 1, (1,)): the elbow's torque.
- Observation (6), dm_control's order: orientations = (upper_arm xmat xz, lower_arm xz, upper_arm
  zz, lower_arm zz), velocity = (shoulder, elbow velocities).
- Reward: tolerance(|tip - target|, (0, target radius), margin 1); sparse: margin 0 (0 or 1).
- Reset: shoulder and elbow U(-pi, pi), at rest.
- Episode: 1,000 steps (10 s simulated), never terminated.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv, tolerance


class DmcAcrobot(DmControlEnv):
    """dm_control's `acrobot.Balance(sparse)`; the two tasks below fix it."""

    domain = "acrobot"
    observation_shapes = (("orientations", 4), ("velocity", 2))
    sparse: bool

    def initial_qpos_qvel(self, key):
        return jax.random.uniform(key, (2,), minval=-jnp.pi, maxval=jnp.pi), jnp.zeros(2)

    def observations(self, data):
        upper, lower = self.body_xmat(data, "upper_arm"), self.body_xmat(data, "lower_arm")
        return {"orientations": jnp.stack([upper[0, 2], lower[0, 2], upper[2, 2], lower[2, 2]]),
                "velocity": data.qvel}

    def reward(self, data, action, prev):
        target, tip = self.mj_model.site("target").id, self.mj_model.site("tip").id
        distance = jnp.linalg.norm(data.site_xpos[target] - data.site_xpos[tip])
        radius = float(self.mj_model.site_size[target, 0])
        return tolerance(distance, (0.0, radius), margin=0.0 if self.sparse else 1.0)


class DmcAcrobotSwingUp(DmcAcrobot):
    task, sparse = "swingup", False


class DmcAcrobotSwingUpSparse(DmcAcrobot):
    task, sparse = "swingup_sparse", True
