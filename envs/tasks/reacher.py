"""Gymnasium's Reacher-v5, stepped by MJX.

A two-link arm on a table reaches for a target placed at random. The MJCF is read from the
installed gymnasium package; the rest follows `gymnasium/envs/mujoco/reacher_v5.py`:

- frame skip 2 (dt 0.02 s; the MJCF integrates with RK4, so the fingertip position read after
  a step is RK4's last stage in C MuJoCo and in MJX alike);
- observation: cos and sin of the two arm angles, the target's position (qpos[2:]), the arm's
  two angular velocities, and fingertip - target in x and y (10 values);
- reward = reward_dist + reward_ctrl with reward_dist = -reward_dist_weight * |fingertip -
  target| (3-D) and reward_ctrl = -reward_control_weight * sum(ctrl^2), ctrl in Gymnasium's
  action units; it never terminates (Gymnasium truncates at 50 steps);
- reset: arm angles qpos0 + U(-0.1, 0.1), the target uniform in the disc of radius 0.2 (Gymnasium
  draws it by rejection from the square [-0.2, 0.2]^2, which gives the same distribution: here
  radius 0.2 sqrt(u) at a uniform angle), arm velocities U(-0.005, 0.005), target velocity 0.

Actions: ours in [-1, 1] scaled to the ctrlrange, which is [-1, 1]: the same as Gymnasium's.
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


@struct.dataclass
class ReacherParams:
    """Reacher-v5's constructor arguments (same names and defaults)."""

    reward_dist_weight: float = 1.0
    reward_control_weight: float = 1.0

    RANGES: ClassVar[dict[str, Valid]] = {"reward_dist_weight": FINITE, "reward_control_weight": FINITE}


class Reacher(GymnasiumMujocoEnv):
    """Gymnasium's Reacher-v5 (see the module docs)."""

    gymnasium_id = "Reacher-v5"
    xml_file = "reacher.xml"
    frame_skip = 2
    observation_size = 10
    observation_names = ("cos_joint0", "cos_joint1", "sin_joint0", "sin_joint1", "target_x", "target_y",
                         "joint0_velocity", "joint1_velocity", "fingertip_minus_target_x", "fingertip_minus_target_y")
    forward_on_reset = True  # the observation reads body positions, which mj_forward computes at reset
    arm_angle_noise = 0.1  # arm angles = qpos0 + U(-0.1, 0.1) at reset
    arm_speed_noise = 0.005  # arm angular velocities U(-0.005, 0.005) at reset
    target_radius = 0.2  # the target is uniform in the disc of this radius

    def __init__(self, params: ReacherParams = ReacherParams(), xml: str | None = None):
        super().__init__(params, xml)
        self._fingertip = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_BODY, "fingertip")
        self._target = mujoco.mj_name2id(self.mj_model, mujoco.mjtObj.mjOBJ_BODY, "target")

    def initial_qpos_qvel(self, key):
        arm_key, radius_key, angle_key, speed_key = jax.random.split(key, 4)
        arm = self.init_qpos[:2] + jax.random.uniform(arm_key, (2,), minval=-self.arm_angle_noise,
                                                      maxval=self.arm_angle_noise)
        radius = self.target_radius * jnp.sqrt(jax.random.uniform(radius_key))
        angle = jax.random.uniform(angle_key, minval=-jnp.pi, maxval=jnp.pi)
        target = radius * jnp.stack([jnp.cos(angle), jnp.sin(angle)])
        arm_speed = jax.random.uniform(speed_key, (2,), minval=-self.arm_speed_noise, maxval=self.arm_speed_noise)
        return jnp.concatenate([arm, target]), jnp.concatenate([arm_speed, jnp.zeros(2)])

    def _fingertip_to_target(self, data: mjx.Data) -> jax.Array:
        return data.xpos[self._fingertip] - data.xpos[self._target]

    def observation(self, data: mjx.Data) -> jax.Array:
        theta = data.qpos[:2]
        return jnp.concatenate([
            jnp.cos(theta), jnp.sin(theta), data.qpos[2:], data.qvel[:2], self._fingertip_to_target(data)[:2],
        ])

    def reward(self, data, action, prev):
        reward_dist = -jnp.linalg.norm(self._fingertip_to_target(data)) * self.params.reward_dist_weight
        reward_ctrl = -jnp.sum(jnp.square(data.ctrl)) * self.params.reward_control_weight
        return reward_dist + reward_ctrl, {"reward_dist": reward_dist, "reward_ctrl": reward_ctrl}

    def terminated(self, data: mjx.Data) -> jax.Array:
        return jnp.zeros((), bool)
