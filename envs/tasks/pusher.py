"""Pusher-v5 of Gymnasium (gymnasium/envs/mujoco/pusher_v5.py), stepped by MJX: `envs.make("pusher")`.
A seven-joint arm on a table pushes a cylinder (the object) to a goal. The MJCF is Gymnasium's own
`pusher_v5.xml`, read from the installed package (no gravity; the object and the arm's three finger
capsules collide with the table and each other).

## Action Space
| | ours | Gymnasium v5 |
| --- | --- | --- |
| `step` takes | Box(-1, 1, (7,), float32) | Box(-2, 2, (7,), float32) |
| becomes `ctrl` | scaled to the ctrlrange [-2, 2]: 2a | as given |

The seven arm joints' torques (shoulder pan/lift, upper arm roll, elbow flex, forearm roll, wrist
flex/roll). `env.action_low`/`action_high`, `env.to_env_action` and `envs.to_gymnasium` give
Gymnasium's space (`load_policy` returns Gymnasium's units).

## Observation Space
23 values, float32 (Gymnasium: float64), as v5: the arm's joint angles qpos[:7] and velocities
qvel[:7], then `xpos` of the bodies tips_arm, object and goal (3 each). After a step `xpos` is that
of MuJoCo's last forward pass (before the last Euler substep), in C MuJoCo and MJX alike.

## Rewards
- reward = reward_dist + reward_ctrl + reward_near, as v5 (positions read after the step, v5's fix of v4):
  - reward_dist = -reward_dist_weight * |object - goal|;
  - reward_ctrl = -reward_control_weight * sum(ctrl^2), ctrl in Gymnasium's units;
  - reward_near = -reward_near_weight * |object - tips_arm|.
- `state.metrics` holds v5's `info`: reward_dist, reward_ctrl, reward_near.

## Starting State
- The arm at qpos0, its velocities U(-0.005, 0.005); the goal's joints and every other velocity 0.
- The object's slides (qpos[7], qpos[8]) from U(-0.3, 0) x U(-0.2, 0.2), redrawn until farther than
  0.17 from the goal: v5's rejection with NumPy, ours with JAX in a `lax.while_loop` (the same
  distribution, not the same draws).

## Episode End
- Terminated: never (as v5). Truncated: after 100 steps (`envs.make`'s TimeLimit, v5's max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make("pusher", **options)`, `PusherParams`: v5's names and defaults.

| argument | default |
| --- | --- |
| reward_near_weight | 0.5 |
| reward_dist_weight | 1.0 |
| reward_control_weight | 0.1 |

v5's xml_file, frame_skip, camera and render arguments are not taken: frame skip 5 at timestep
0.01 (dt = 0.05), Euler. Ours besides: every MJX task's `impl` ("jax" or "warp"), `opt`,
`nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
One env step of ours (float32) and of Gymnasium's env (C MuJoCo, float64) from the same state (qpos,
qvel, solver warm start) with the same action (`envs.interop.gymnasium_equality`); tests/test_pusher.py:
- test_steps_match_gymnasium (slow, impl "jax"): 3,200 steps (32 episodes x 100 random actions, some
  with a finger on the table). Observation within 1e-4, reward and all three metrics within 2e-5,
  each plus 1e-4 relative; termination equal.
- test_steps_while_pushing_differ_as_measured (slow): where a finger pushes the object (at least 50
  states built so), MJX's capsule-cylinder contact is not C MuJoCo's: the object moves 1.5-2.5 times
  as far (median) as in v5's step; held to observation within 1e-2 (25-75% of the steps within 1e-3),
  arm angles 5e-4, reward 3e-3, metrics 2e-3.
- test_episodes_match_gymnasium (slow): whole episodes side by side from our reset state (8 x 100
  steps): the first 30 steps within 1e-3 (observation) and 1e-4 (reward); later, where a finger meets
  the table, float32 and float64 trajectories part.
- test_reset_distribution_matches_gymnasium: 4,000 resets each; the object's slides, the arm's
  velocities and the object's xpos by mean (within 5 standard errors) and spread (within 10%); the
  arm's angles, the goal and the other velocities exactly 0; the fingertips and goal within 1e-6.
- test_options_are_gymnasiums: argument names, defaults, action bounds and episode length equal v5's.
- impl "warp": tests/test_gymnasium_warp.py::test_steps_match_gymnasium (slow), 320 steps of 32
  episodes x 40: 99% within the first test's bounds, every step within 1e-2, termination equal;
  test_pusher_pushes_as_gymnasium (slow): MuJoCo Warp's pushing contact is C MuJoCo's (object moved
  0.9-1.1 times as far, median; over 95% of the steps within 1e-3, all within 1e-2, reward 1e-4);
  tests/test_warp.py::test_gymnasium_tasks_step_alike_under_both_implementations: "warp" against
  "jax", 4 envs x 10 steps, observation and reward within 2e-3 (+2e-3 relative).
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
    reset_computes_derived = True  # the observation reads body positions, which mj_forward computes at reset
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

    def compute_derived_at_reset(self, model: mjx.Model, data: mjx.Data) -> mjx.Data:
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
