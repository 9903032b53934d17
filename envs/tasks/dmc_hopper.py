"""The DeepMind Control Suite's hopper (dm_control/suite/hopper.py), stepped by MJX:
`envs.make("dmc-hopper-stand")` and `-hop`. A planar one-legged hopper (7 joints, 4 motors; Euler,
timestep 0.005, 4 physics steps per control step: dt 0.02) stands up, or hops forward at 2 m/s.
The MJCF is dm_control's `hopper.xml`, read from the installed package.

- Action: Box(-1, 1, (4,)): waist, hip, knee, ankle.
- Observation (15), dm_control's order: position = qpos[1:] (rootx left out), velocity = qvel,
  touch = log1p of the toe's and the heel's touch sensors. Touch is an acceleration-stage sensor:
  as in dm_control's legacy step, it is the value computed in the last substep, before its
  integration (the kinematics are refreshed after it, the touch is not).
- Reward: standing = tolerance(torso xipos z - foot xipos z, (0.6, 2)); stand: standing *
  (4 + mean tolerance(ctrl, margin 1, value_at_margin 0, quadratic)) / 5; hop: standing *
  tolerance(torso subtree linear velocity x, (2, inf), margin 1, value_at_margin 0.5, linear).
- Reset: dm_control's joint randomiser: the limited hinges uniform in their ranges, rooty U(-pi, pi),
  rootx and rootz (unlimited slides) at 0, at rest.
- Episode: 1,000 steps (20 s simulated), never terminated.
"""

from __future__ import annotations

import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv, randomize_joints, tolerance

STAND_HEIGHT = 0.6  # dm_control's _STAND_HEIGHT (m)
HOP_SPEED = 2.0  # _HOP_SPEED (m/s)


class DmcHopper(DmControlEnv):
    """dm_control's `hopper.Hopper(hopping)`; the two tasks below fix it."""

    domain = "hopper"
    control_timestep = 0.02  # dm_control's _CONTROL_TIMESTEP
    observation_shapes = (("position", 6), ("velocity", 7), ("touch", 2))
    hopping: bool

    def initial_qpos_qvel(self, key):
        return randomize_joints(self.mj_model, jnp.asarray(self.mj_model.qpos0), key), jnp.zeros(self.mj_model.nv)

    def observations(self, data):
        touch = jnp.concatenate([self.sensor(data, "touch_toe"), self.sensor(data, "touch_heel")])
        return {"position": data.qpos[1:], "velocity": data.qvel, "touch": jnp.log1p(touch)}

    def reward(self, data, action, prev):
        torso, foot = self.mj_model.body("torso").id, self.mj_model.body("foot").id
        standing = tolerance(data.xipos[torso, 2] - data.xipos[foot, 2], (STAND_HEIGHT, 2.0))
        if self.hopping:
            speed = self.sensor(data, "torso_subtreelinvel")[0]
            return standing * tolerance(speed, (HOP_SPEED, float("inf")), margin=HOP_SPEED / 2,
                                        value_at_margin=0.5, sigmoid="linear")
        small_control = tolerance(data.ctrl, margin=1, value_at_margin=0, sigmoid="quadratic").mean()
        return standing * (small_control + 4) / 5


class DmcHopperStand(DmcHopper):
    task, hopping = "stand", False


class DmcHopperHop(DmcHopper):
    task, hopping = "hop", True
