"""Gymnasium's Pusher-v5, stepped by MJX.

A seven-joint arm on a table pushes a cylinder (the object) to a goal. The MJCF is Gymnasium's
`pusher_v5.xml`, read from the installed gymnasium package (no gravity, Euler at timestep 0.01,
the object's cylinder and the arm's three finger capsules collide with the table and each other);
the rest follows `gymnasium/envs/mujoco/pusher_v5.py`:

- frame skip 5 (dt 0.05 s);
- observation (23 values): the arm's joint angles qpos[:7], its joint velocities qvel[:7], and the
  positions (`xpos`) of the bodies tips_arm, object and goal. `xpos` after a step is what MuJoCo's
  last `mj_forward` computed, from the qpos before the last Euler substep, in C MuJoCo and in
  MJX alike;
- reward = reward_dist + reward_ctrl + reward_near: -reward_dist_weight * |object - goal|,
  -reward_control_weight * sum(ctrl^2) (ctrl in Gymnasium's action units) and
  -reward_near_weight * |object - tips_arm|, the positions read AFTER the physics step (v5 fixed
  v4's reward from the state before it: Gymnasium's `step` runs `do_simulation`, then `_get_obs`
  and `_get_rew`); it never terminates (Gymnasium truncates at 100 steps);
- reset: the arm at qpos0 (no position noise), the object's two slide joints (qpos[7]:
  obj_slidey, qpos[8]: obj_slidex) drawn from U(-0.3, 0) x U(-0.2, 0.2) until farther than 0.17
  from the goal's (0, 0), the goal's joints at 0; the arm's velocities U(-0.005, 0.005), the object's
  and the goal's 0. Gymnasium draws the object by rejection with NumPy; so do we, with JAX's
  random numbers in a `lax.while_loop` (a candidate is rejected with probability 0.378, the loop
  ends after 1.6 draws on average): the same distribution, not the same numbers.

Actions: ours in [-1, 1] scaled to the ctrlrange, which is [-2, 2] for every joint: Gymnasium's
action is twice ours (`to_env_action`; `load_policy` returns Gymnasium's units).
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco
from flax import struct

from envs.mjx_env import mjx
from envs.ranges import FINITE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv

_JOINTS = ("shoulder_pan", "shoulder_lift", "upper_arm_roll", "elbow_flex", "forearm_roll", "wrist_flex", "wrist_roll")


@struct.dataclass
class PusherParams:
    """Pusher-v5's constructor arguments (same names and defaults)."""

    reward_near_weight: float = 0.5
    reward_dist_weight: float = 1.0
    reward_control_weight: float = 0.1

    RANGES: ClassVar[dict[str, Valid]] = {
        "reward_near_weight": FINITE, "reward_dist_weight": FINITE, "reward_control_weight": FINITE}


class Pusher(GymnasiumMujocoEnv):
    """Gymnasium's Pusher-v5 (see the module docs)."""

    gymnasium_id = "Pusher-v5"
    xml_file = "pusher_v5.xml"
    frame_skip = 5
    observation_size = 23
    observation_names = (*(f"{j}_angle" for j in _JOINTS), *(f"{j}_velocity" for j in _JOINTS),
                         *(f"{body}_{axis}" for body in ("tips_arm", "object", "goal") for axis in "xyz"))
    forward_on_reset = True  # the observation reads body positions, which mj_forward computes at reset
    arm_joints = 7  # qpos[:7], qvel[:7]: the arm; then the object's two slide joints, then the goal's
    arm_speed_noise = 0.005  # arm velocities U(-0.005, 0.005) at reset
    object_low, object_high = (-0.3, -0.2), (0.0, 0.2)  # qpos[7], qpos[8] before the rejection
    min_goal_distance = 0.17  # a drawn object position is kept when farther than this from the goal's (0, 0)

    def __init__(self, params: PusherParams = PusherParams(), xml: str | None = None):
        super().__init__(params, xml)
        body = lambda name: mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_BODY, name)
        self._tips_arm, self._object, self._goal = body("tips_arm"), body("object"), body("goal")

    def initial_qpos_qvel(self, key):
        object_key, speed_key = jax.random.split(key)
        low, high = jnp.array(self.object_low), jnp.array(self.object_high)

        def draw(carry):
            key, _ = carry
            key, sample_key = jax.random.split(key)
            return key, jax.random.uniform(sample_key, (2,), minval=low, maxval=high)

        rejected = lambda carry: jnp.linalg.norm(carry[1]) <= self.min_goal_distance
        _, cylinder = jax.lax.while_loop(rejected, draw, draw((object_key, jnp.zeros(2))))
        arm = self.init_qpos[:self.arm_joints]
        qpos = jnp.concatenate([arm, cylinder, jnp.zeros(2)])  # the goal's slide joints at 0
        arm_speed = jax.random.uniform(speed_key, (self.arm_joints,), minval=-self.arm_speed_noise,
                                       maxval=self.arm_speed_noise)
        return qpos, jnp.concatenate([arm_speed, jnp.zeros(self.mj_model.nv - self.arm_joints)])

    def forward_at_reset(self, model: mjx.Model, data: mjx.Data) -> mjx.Data:
        # The reset observation reads body positions only: kinematics, not the whole mj_forward
        # (which adds the contacts and the constraint solve: reset compiles several times faster on
        # the CPU, and a batch auto-resetting every env per step does less work).
        return mjx.kinematics(model, data)

    def observation(self, data: mjx.Data) -> jax.Array:
        n = self.arm_joints
        return jnp.concatenate([data.qpos[:n], data.qvel[:n], data.xpos[self._tips_arm], data.xpos[self._object],
                                data.xpos[self._goal]])

    def reward(self, data, action, prev):
        p = self.params
        reward_near = -jnp.linalg.norm(data.xpos[self._object] - data.xpos[self._tips_arm]) * p.reward_near_weight
        reward_dist = -jnp.linalg.norm(data.xpos[self._object] - data.xpos[self._goal]) * p.reward_dist_weight
        reward_ctrl = -jnp.sum(jnp.square(data.ctrl)) * p.reward_control_weight
        return reward_dist + reward_ctrl + reward_near, {
            "reward_dist": reward_dist, "reward_ctrl": reward_ctrl, "reward_near": reward_near}

    def terminated(self, data: mjx.Data) -> jax.Array:
        return jnp.zeros((), bool)
