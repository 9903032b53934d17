"""The DeepMind Control Suite's point mass, easy (dm_control/suite/point_mass.py), stepped by MJX:
`envs.make("dmc-point-mass-easy")`. A mass on two slides in a walled plane (Euler, timestep 0.02, one
physics step per control step), pushed through two tendons, must reach the target at the centre.
The MJCF is dm_control's `point_mass.xml`, read from the installed package.

- Action: Box(-1, 1, (2,)): the two tendon motors (x and y in "easy").
- Observation (4), dm_control's order: position = qpos, velocity = qvel.
- Reward: near_target * small_control, near_target = tolerance(|target - mass|, (0, r), margin r)
  with r the target's radius, small_control = (4 + mean tolerance(ctrl, margin 1,
  value_at_margin 0, quadratic)) / 5.
- Reset: both slides uniform in their ranges (dm_control's joint randomiser), at rest.
- Episode: 1,000 steps (20 s simulated), never terminated. "hard" (random actuation directions per episode,
  a per-episode model edit) is not offered.
"""

from __future__ import annotations

import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv, randomize_joints, tolerance


class DmcPointMassEasy(DmControlEnv):
    domain, task = "point_mass", "easy"
    observation_shapes = (("position", 2), ("velocity", 2))

    def initial_qpos_qvel(self, key):
        return randomize_joints(self.mj_model, jnp.asarray(self.mj_model.qpos0), key), jnp.zeros(2)

    def observations(self, data):
        return {"position": data.qpos, "velocity": data.qvel}

    def reward(self, data, action, prev):
        target, mass = self.mj_model.geom("target").id, self.mj_model.geom("pointmass").id
        size = float(self.mj_model.geom_size[target, 0])
        near_target = tolerance(jnp.linalg.norm(data.geom_xpos[target] - data.geom_xpos[mass]), (0.0, size),
                                margin=size)
        control = tolerance(data.ctrl, margin=1, value_at_margin=0, sigmoid="quadratic").mean()
        return near_target * (control + 4) / 5
