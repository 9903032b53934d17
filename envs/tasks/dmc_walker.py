"""The DeepMind Control Suite's planar walker (dm_control/suite/walker.py), stepped by MJX:
`envs.make("dmc-walker-stand")`, `-walk`, `-run`. A planar biped (9 joints, 6 motors; Euler,
timestep 0.0025, 10 physics steps per control step: dt 0.025) stands up, walks at 1 m/s or runs at 8 m/s.
The MJCF is dm_control's `walker.xml`, read from the installed package.

- Action: Box(-1, 1, (6,)): right and left hip, knee, ankle.
- Observation (24), dm_control's order: orientations = (xmat xx, xz) of the 7 bodies after the
  world, height = the torso's z (xpos), velocity = qvel.
- Reward: stand = (3 * standing + upright) / 4 with standing = tolerance(height, (1.2, inf),
  margin 0.6), upright = (1 + torso xmat zz) / 2; walk and run: stand * (5 * move + 1) / 6 with
  move = tolerance(torso subtree linear velocity x, (speed, inf), margin speed / 2,
  value_at_margin 0.5, linear).
- Reset: dm_control's joint randomiser: limited hinges uniform in their ranges, rooty U(-pi, pi),
  rootx and rootz (unlimited slides) at 0, at rest; the walker starts in the air and falls.
- Episode: 1,000 steps (25 s simulated), never terminated.
"""

from __future__ import annotations

import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv, randomize_joints, tolerance

STAND_HEIGHT = 1.2  # dm_control's _STAND_HEIGHT (m)
WALK_SPEED, RUN_SPEED = 1.0, 8.0  # _WALK_SPEED, _RUN_SPEED (m/s)


class DmcWalker(DmControlEnv):
    """dm_control's `walker.PlanarWalker(move_speed)`; the three tasks below fix it."""

    domain = "walker"
    control_timestep = 0.025  # dm_control's _CONTROL_TIMESTEP
    observation_shapes = (("orientations", 14), ("height", 1), ("velocity", 9))
    move_speed: float

    def initial_qpos_qvel(self, key):
        return randomize_joints(self.mj_model, jnp.asarray(self.mj_model.qpos0), key), jnp.zeros(self.mj_model.nv)

    def observations(self, data):
        orientations = data.xmat[1:][:, [0, 0], [0, 2]]  # xx and xz of every body but the world
        torso = self.mj_model.body("torso").id
        return {"orientations": orientations, "height": data.xpos[torso, 2], "velocity": data.qvel}

    def reward(self, data, action, prev):
        height = data.xpos[self.mj_model.body("torso").id, 2]
        standing = tolerance(height, (STAND_HEIGHT, float("inf")), margin=STAND_HEIGHT / 2)
        upright = (1 + self.body_xmat(data, "torso")[2, 2]) / 2
        stand = (3 * standing + upright) / 4
        if self.move_speed == 0:
            return stand
        move = tolerance(self.sensor(data, "torso_subtreelinvel")[0], (self.move_speed, float("inf")),
                         margin=self.move_speed / 2, value_at_margin=0.5, sigmoid="linear")
        return stand * (5 * move + 1) / 6


class DmcWalkerStand(DmcWalker):
    task, move_speed = "stand", 0.0


class DmcWalkerWalk(DmcWalker):
    task, move_speed = "walk", WALK_SPEED


class DmcWalkerRun(DmcWalker):
    task, move_speed = "run", RUN_SPEED
