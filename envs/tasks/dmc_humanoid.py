"""The DeepMind Control Suite's humanoid (dm_control/suite/humanoid.py), stepped by MJX:
`envs.make("dmc-humanoid-stand")`, `-walk`, `-run` and `-run-pure-state`. A 21-hinge humanoid on a free joint, 21 motors
(Euler, timestep 0.005, 5 physics steps per control step: dt 0.025) stands up, walks at 1 m/s or runs
at 10 m/s. The MJCF is dm_control's `humanoid.xml`, read from the installed package (its touch,
force and other sensors are stepped but not observed).

- Action: Box(-1, 1, (21,)).
- Observation (67), dm_control's order: joint_angles (21) = qpos[7:]; head_height (1) = head xpos z;
  extremities (12) = the left hand, left foot, right hand and right foot relative to the torso, in
  the torso's frame; torso_vertical (3) = torso xmat zx, zy, zz; com_velocity (3) = the torso
  subtree's linear velocity sensor; velocity (27) = qvel. run-pure-state (dm_control's EXTRA task,
  `pure_state=True`): position (28) = qpos, velocity (27) = qvel; otherwise run.
- Reward: small_control * standing * upright * (stand: dont_move; walk, run: move), with standing =
  tolerance(head z, (1.4, inf), margin 0.35), upright = tolerance(torso zz, (0.9, inf), margin 1.9,
  value_at_margin 0, linear), small_control = (4 + mean tolerance(ctrl, margin 1, value_at_margin 0,
  quadratic)) / 5, dont_move = mean tolerance(com velocity x, y, margin 2), move = (5 tolerance(|com
  velocity x, y|, (speed, inf), margin speed, value_at_margin 0, linear) + 1) / 6.
- Reset: dm_control's joint randomiser (the hinges uniform in their ranges, the root's quaternion a
  normalised U(0, 1)^4, dm_control's `rand`, its position at qpos0's), drawn again until nothing touches
  (dm_control's loop on `ncon > 0` after a forward pass; here a `lax.while_loop` on MJX's contact
  slots closer than their margin), at rest.
- Episode: 1,000 steps (25 s simulated), never terminated.
"""

from __future__ import annotations

import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv, tolerance

STAND_HEIGHT = 1.4  # dm_control's _STAND_HEIGHT (m)
WALK_SPEED, RUN_SPEED = 1.0, 10.0  # _WALK_SPEED, _RUN_SPEED (m/s)
EXTREMITIES = ("left_hand", "left_foot", "right_hand", "right_foot")


class DmcHumanoid(DmControlEnv):
    """dm_control's `humanoid.Humanoid(move_speed, pure_state=False)`; the tasks below fix the speed."""
    costly_reset = True

    domain = "humanoid"
    control_timestep = 0.025  # dm_control's _CONTROL_TIMESTEP
    observation_shapes = (("joint_angles", 21), ("head_height", 1), ("extremities", 12), ("torso_vertical", 3),
                          ("com_velocity", 3), ("velocity", 27))
    move_speed: float

    def initial_qpos_qvel(self, key):
        return self.drawn_until_apart(key, self.joints_drawn), jnp.zeros(self.mj_model.nv)

    def _head_height(self, data):
        return data.xpos[self.mj_model.body("head").id, 2]

    def _com_velocity(self, data):
        return self.sensor(data, "torso_subtreelinvel")

    def observations(self, data):
        torso = self.mj_model.body("torso").id
        frame = data.xmat[torso]
        limbs = jnp.array([self.mj_model.body(name).id for name in EXTREMITIES])
        extremities = (data.xpos[limbs] - data.xpos[torso]) @ frame  # dm_control's torso_to_limb.dot(torso_frame)
        return {"joint_angles": data.qpos[7:], "head_height": self._head_height(data), "extremities": extremities,
                "torso_vertical": frame[2], "com_velocity": self._com_velocity(data), "velocity": data.qvel}

    def reward(self, data, action, prev):
        standing = tolerance(self._head_height(data), (STAND_HEIGHT, float("inf")), margin=STAND_HEIGHT / 4)
        upright = tolerance(self.body_xmat(data, "torso")[2, 2], (0.9, float("inf")), margin=1.9, value_at_margin=0.0,
                            sigmoid="linear")
        small_control = tolerance(data.ctrl, margin=1.0, value_at_margin=0.0, sigmoid="quadratic").mean()
        small_control = (4 + small_control) / 5
        horizontal = self._com_velocity(data)[:2]
        if self.move_speed == 0:
            return small_control * standing * upright * tolerance(horizontal, margin=2.0).mean()
        move = tolerance(jnp.linalg.norm(horizontal), (self.move_speed, float("inf")), margin=self.move_speed,
                         value_at_margin=0.0, sigmoid="linear")
        return small_control * standing * upright * (5 * move + 1) / 6


class DmcHumanoidStand(DmcHumanoid):
    task, move_speed = "stand", 0.0


class DmcHumanoidWalk(DmcHumanoid):
    task, move_speed = "walk", WALK_SPEED


class DmcHumanoidRun(DmcHumanoid):
    task, move_speed = "run", RUN_SPEED


class DmcHumanoidRunPureState(DmcHumanoidRun):
    """dm_control's `run_pure_state`: run's physics, reset and reward; the observation is MuJoCo's state."""
    task = "run_pure_state"
    observation_shapes = (("position", 28), ("velocity", 27))

    def observations(self, data):
        return {"position": data.qpos, "velocity": data.qvel}
