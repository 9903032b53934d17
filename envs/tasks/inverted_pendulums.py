"""InvertedPendulum-v5 and InvertedDoublePendulum-v5 of Gymnasium (gymnasium/envs/mujoco/
inverted_pendulum_v5.py, inverted_double_pendulum_v5.py), stepped by MJX: `envs.make("inverted-pendulum")`,
`envs.make("inverted-double-pendulum")`. A cart on a rail balances one pole, or two stacked poles.
The MJCFs are Gymnasium's own, read from the installed package.

## Action Space
| | InvertedPendulum | InvertedDoublePendulum |
| --- | --- | --- |
| `step` takes | Box(-1, 1, (1,), float32) | Box(-1, 1, (1,), float32) |
| becomes `ctrl` (the cart's force) | scaled to the ctrlrange [-3, 3]: 3a | scaled to [-1, 1]: unchanged |
| Gymnasium v5's space | Box(-3, 3, (1,), float32) | Box(-1, 1, (1,), float32) |

`env.action_low`/`action_high`, `env.to_env_action` and `envs.to_gymnasium` give Gymnasium's space
(a policy trained here acts on Gymnasium's env through them).

## Observation Space
float32 (Gymnasium: float64), as v5:
- InvertedPendulum, 4 values: cart x, pole angle, cart velocity, pole angular velocity.
- InvertedDoublePendulum, 9 values: cart x, sin and cos of the two hinge angles, qvel clipped to
  +-10, the cart's constraint force (`qfrc_constraint[0]`) clipped to +-10. After a step MuJoCo's
  derived values (tip site, constraint force) are those of RK4's last stage, in C MuJoCo and MJX alike.

## Rewards
As v5; `state.metrics` holds v5's `info`:
- InvertedPendulum: reward_survive = 1 on every step, 0 on the step that terminates.
- InvertedDoublePendulum: reward = reward_survive + distance_penalty + velocity_penalty, with
  reward_survive = healthy_reward (0 on the terminating step), distance_penalty = -(0.01 x_tip^2 +
  (y_tip - 2)^2), velocity_penalty = -(1e-3 w1^2 + 5e-3 w2^2).

## Starting State
As v5; JAX's random numbers: the same distribution, not the same draws.
- InvertedPendulum: qpos, qvel = qpos0, 0 + U(-s, s), s = reset_noise_scale (0.01).
- InvertedDoublePendulum: qpos = qpos0 + U(-s, s), qvel = s * N(0, 1), s = 0.1; `mjx.forward` at
  reset, as v5's `set_state` runs `mj_forward`, for the tip and the constraint force.

## Episode End
- Terminated, as v5: InvertedPendulum when |pole angle| > 0.2 or the observation is non-finite;
  InvertedDoublePendulum when the tip's height y_tip <= 1.
- Truncated: after 1000 steps (`envs.make`'s TimeLimit, v5's max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make(name, **options)`, `InvertedPendulumParams` / `InvertedDoublePendulumParams`: v5's names
and defaults.

| argument | InvertedPendulum | InvertedDoublePendulum |
| --- | --- | --- |
| reset_noise_scale | 0.01 | 0.1 |
| healthy_reward | (none) | 10.0 |

v5's xml_file, frame_skip, camera and render arguments are not taken: RK4, frame skip 2 at
timestep 0.02 (dt = 0.04) and frame skip 5 at timestep 0.01 (dt = 0.05). Ours besides: every MJX
task's `impl` ("jax" or "warp"), `opt`, `nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
One env step of ours (float32) and of Gymnasium's env (C MuJoCo, float64) from the same state (qpos,
qvel, solver warm start) with the same action (`envs.interop.gymnasium_equality`);
tests/test_inverted_pendulums.py (bounds plus 1e-4 relative, termination equal, unless said):
- test_inverted_pendulum_steps_match_gymnasium (impl "jax"): 320 steps (64 episodes x 8 random
  actions, 5-95% of them terminating). Observation, reward and reward_survive within 2e-5; v5's
  reward is 1 exactly where it does not terminate.
- test_inverted_double_pendulum_steps_match_gymnasium (slow): 320 steps (32 episodes x 10, the
  constraint force and the velocity clip both seen), the same 2e-5 bounds, all three metrics.
- test_inverted_double_pendulum_episodes_match_gymnasium (slow): whole episodes side by side from
  our reset state (16 episodes x 12 steps, up to each first termination): observation and reward
  within 1e-4.
- test_steps_match_gymnasium_with_every_option_changed (slow, double pendulum): 80 steps, 2e-5.
- test_*_reset_distribution_matches_gymnasium: 4,000 resets each; per coordinate of qpos, qvel (and
  the double pendulum's observation) the means within 5 standard errors, the spreads within 10%;
  the uniform noise inside its bounds, both ends reached.
- test_options_are_gymnasiums: argument names, defaults, action bounds and episode length equal v5's.
- impl "warp": tests/test_gymnasium_warp.py::test_steps_match_gymnasium (slow), 320 steps of 32
  episodes x 40: 99% within the 2e-5 bounds, every step within 1e-2, termination equal;
  tests/test_warp.py::test_gymnasium_tasks_step_alike_under_both_implementations: "warp" against
  "jax", 4 envs x 10 steps, observation and reward within 2e-3 (+2e-3 relative).

Not compared: the reset's draws themselves (only their distribution).
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from envs.mjx_env import mjx
from envs.ranges import FINITE, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class InvertedPendulumParams:
    """InvertedPendulum-v5's constructor arguments (same names and defaults)."""

    reset_noise_scale: float = 0.01  # qpos, qvel = init + U(-scale, scale)

    RANGES: ClassVar[dict[str, Valid]] = {"reset_noise_scale": NON_NEGATIVE}


@struct.dataclass
class InvertedDoublePendulumParams:
    """InvertedDoublePendulum-v5's constructor arguments (same names and defaults)."""

    healthy_reward: float = 10.0  # paid on every step that does not terminate
    reset_noise_scale: float = 0.1  # qpos = init + U(-scale, scale), qvel = init + scale * N(0, 1)

    RANGES: ClassVar[dict[str, Valid]] = {"healthy_reward": FINITE, "reset_noise_scale": NON_NEGATIVE}


class InvertedPendulum(GymnasiumMujocoEnv):
    """Gymnasium's InvertedPendulum-v5: balance a pole on a cart (see the module docs)."""

    gymnasium_id = "InvertedPendulum-v5"
    xml_file = "inverted_pendulum.xml"
    frame_skip = 2
    observation_size = 4  # qpos and qvel, nothing left out
    observation_names = ("cart_x", "pole_angle", "cart_velocity", "pole_angular_velocity")
    max_pole_angle = 0.2  # rad; Gymnasium terminates past it

    def __init__(self, params: InvertedPendulumParams = InvertedPendulumParams(), xml: str | None = None):
        super().__init__(params, xml)

    def observation(self, data: mjx.Data) -> jax.Array:
        return jnp.concatenate([data.qpos, data.qvel])

    def terminated(self, data: mjx.Data) -> jax.Array:
        return ~jnp.isfinite(self.observation(data)).all() | (jnp.abs(data.qpos[1]) > self.max_pole_angle)

    def reward(self, data, action, prev):
        survive = jnp.where(self.terminated(data), 0.0, 1.0)
        return survive, {"reward_survive": survive}


class InvertedDoublePendulum(GymnasiumMujocoEnv):
    """Gymnasium's InvertedDoublePendulum-v5: balance two stacked poles on a cart."""

    gymnasium_id = "InvertedDoublePendulum-v5"
    xml_file = "inverted_double_pendulum.xml"
    frame_skip = 5
    observation_size = 9
    observation_names = ("cart_x", "sin_hinge1", "sin_hinge2", "cos_hinge1", "cos_hinge2",
                         "cart_velocity", "hinge1_velocity", "hinge2_velocity", "cart_constraint_force")
    # The observation reads the tip site and the cart's constraint force, which mjx.forward
    # computes at reset as Gymnasium's set_state (mj_forward) does.
    reset_computes_derived = True
    min_tip_height = 1.0  # m; Gymnasium terminates when the tip is at or below it
    observation_clip = 10.0  # Gymnasium clips qvel and the constraint force to +-10 in the observation

    def __init__(self, params: InvertedDoublePendulumParams = InvertedDoublePendulumParams(), xml: str | None = None):
        super().__init__(params, xml)

    def initial_qvel_noise(self, key: jax.Array) -> jax.Array:
        return self.params.reset_noise_scale * jax.random.normal(key, self.init_qvel.shape)

    def observation(self, data: mjx.Data) -> jax.Array:
        clip = self.observation_clip
        return jnp.concatenate([
            data.qpos[:1],
            jnp.sin(data.qpos[1:]),
            jnp.cos(data.qpos[1:]),
            jnp.clip(data.qvel, -clip, clip),
            jnp.clip(data.qfrc_constraint, -clip, clip)[:1],
        ])

    def terminated(self, data: mjx.Data) -> jax.Array:
        return data.site_xpos[0, 2] <= self.min_tip_height

    def reward(self, data, action, prev):
        x, _, y = data.site_xpos[0]
        w1, w2 = data.qvel[1], data.qvel[2]
        distance_penalty = 0.01 * x**2 + (y - 2) ** 2
        velocity_penalty = 1e-3 * w1**2 + 5e-3 * w2**2
        survive = jnp.where(self.terminated(data), 0.0, self.params.healthy_reward)
        terms = {"reward_survive": survive, "distance_penalty": -distance_penalty, "velocity_penalty": -velocity_penalty}
        return survive - distance_penalty - velocity_penalty, terms
