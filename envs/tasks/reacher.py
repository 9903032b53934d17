"""Reacher-v5 of Gymnasium (gymnasium/envs/mujoco/reacher_v5.py), stepped by MJX: `envs.make("reacher")`.
A two-link arm on a table reaches for a target placed at random. The MJCF is Gymnasium's own
`reacher.xml`, read from the installed package.

## Action Space
| | ours | Gymnasium v5 |
| --- | --- | --- |
| `step` takes | Box(-1, 1, (2,), float32) | Box(-1, 1, (2,), float32) |
| becomes `ctrl` | scaled to the ctrlrange [-1, 1]: unchanged | as given |

The two hinge torques (shoulder, elbow). `env.action_low`/`action_high` and `envs.to_gymnasium`
give Gymnasium's space.

## Observation Space
10 values, float32 (Gymnasium: float64), as v5: cos and sin of the two arm angles (4), the target's
x, y (qpos[2:]), the arm's two angular velocities, fingertip - target in x and y. The body
positions after a step are those of RK4's last stage, in C MuJoCo and MJX alike.

## Rewards
- reward = reward_dist + reward_ctrl, as v5:
  - reward_dist = -reward_dist_weight * |fingertip - target| (3-D);
  - reward_ctrl = -reward_control_weight * sum(ctrl^2).
- `state.metrics` holds v5's `info`: reward_dist, reward_ctrl.

## Starting State
- Arm angles qpos0 + U(-0.1, 0.1), arm velocities U(-0.005, 0.005), target velocity 0, as v5.
- The target uniform in the disc of radius 0.2: v5 draws it by rejection from the square
  [-0.2, 0.2]^2; ours draws radius 0.2 sqrt(u) at a uniform angle (the same distribution, no loop).
- `mjx.forward` at reset, as v5's `set_state` runs `mj_forward`, so the first observation's
  fingertip is the reset pose's.

## Episode End
- Terminated: never (as v5). Truncated: after 50 steps (`envs.make`'s TimeLimit, v5's max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make("reacher", **options)`, `ReacherParams`: v5's names and defaults.

| argument | default |
| --- | --- |
| reward_dist_weight | 1.0 |
| reward_control_weight | 1.0 |

v5's xml_file, frame_skip, camera and render arguments are not taken: frame skip 2 at timestep
0.01 (dt = 0.02), RK4. Ours besides: every MJX task's `impl` ("jax" or "warp"), `opt`,
`nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
One env step of ours (float32) and of Gymnasium's env (C MuJoCo, float64) from the same state (qpos,
qvel, solver warm start) with the same action (`envs.interop.gymnasium_equality`); tests/test_reacher.py:
- test_steps_match_gymnasium (slow, impl "jax"): 320 steps (32 episodes x 50 random actions, arm
  velocities above 10). Observation within 1e-4, reward and both metrics within 2e-5, each plus 1e-4
  relative; termination equal.
- test_episodes_match_gymnasium (slow): whole episodes side by side from our reset state (8 episodes
  x 50 steps, Gymnasium carrying its own state): every step within 1e-3 (observation) and 1e-4
  (reward), plus 1e-4 relative.
- test_steps_match_gymnasium_with_every_option_changed (slow): 80 steps, both weights changed, the
  bounds of the first test.
- test_reset_distribution_matches_gymnasium: 4,000 resets each; per coordinate of qpos, the arm's
  qvel and the observation the means within 5 standard errors, the spreads within 10%; the noise
  inside its bounds, both ends reached; the target inside radius 0.2, a quarter (+-0.03) inside 0.1.
- test_options_are_gymnasiums: argument names, defaults, action bounds and episode length equal v5's.
- impl "warp": tests/test_gymnasium_warp.py::test_steps_match_gymnasium (slow), 320 steps of 32
  episodes x 40: 99% within the bounds of the first test, every step within 1e-2, termination equal;
  tests/test_warp.py::test_gymnasium_tasks_step_alike_under_both_implementations: "warp" against
  "jax", 4 envs x 10 steps, observation and reward within 2e-3 (+2e-3 relative).

Not compared: the reset's draws themselves (only their distribution).
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
    reset_computes_derived = True  # the observation reads body positions, which mj_forward computes at reset
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
