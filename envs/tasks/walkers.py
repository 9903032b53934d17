"""Hopper-v5 and Walker2d-v5 of Gymnasium (gymnasium/envs/mujoco/hopper_v5.py, walker2d_v5.py),
stepped by MJX: `envs.make("hopper")`, `envs.make("walker2d")`. Planar walkers on three root joints
(rootx, rootz, rooty: the torso's x, height and pitch) hop or walk forward while healthy. The MJCFs
are Gymnasium's own `hopper.xml` and `walker2d_v5.xml`, read from the installed package.

## Action Space
| | Hopper | Walker2d | Gymnasium v5 |
| --- | --- | --- | --- |
| `step` takes | Box(-1, 1, (3,), float32) | Box(-1, 1, (6,), float32) | the same boxes |
| becomes `ctrl` | scaled to the ctrlrange [-1, 1]: unchanged | the same | as given |

Hinge torques: thigh, leg, foot (Walker2d: right then left). `env.action_low`/`action_high` and
`envs.to_gymnasium` give Gymnasium's space.

## Observation Space
- float32 (Gymnasium: float64): qpos[1:], then qvel clipped to +-10 (the state itself is not
  clipped), as v5. Hopper 11 values (5 + 6), Walker2d 17 (8 + 9).
- `exclude_current_positions_from_observation=False`: all of qpos (12 and 18 values).

## Rewards
- reward = reward_forward + reward_survive + reward_ctrl, as v5:
  - reward_forward = forward_reward_weight * x_velocity (rootx's change over dt);
  - reward_survive = healthy_reward in a healthy state, else 0 (also with terminate_when_unhealthy=False);
  - reward_ctrl = -ctrl_cost_weight * sum(ctrl^2).
- Healthy: z and pitch strictly inside healthy_z_range and healthy_angle_range; the Hopper also
  every qpos[2:] and qvel strictly inside healthy_state_range.
- `state.metrics` holds v5's `info`: reward_forward, reward_ctrl, reward_survive, x_position,
  z_distance_from_origin, x_velocity.

## Starting State
- qpos = qpos0 + U(-s, s), qvel = U(-s, s), s = reset_noise_scale (5e-3), as v5; JAX's random
  numbers: the same distribution, not the same draws.

## Episode End
- Terminated: when unhealthy, unless terminate_when_unhealthy=False (as v5). Truncated: after 1000
  steps (`envs.make`'s TimeLimit, v5's max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make(name, **options)`, `HopperParams` / `Walker2dParams`: v5's names and defaults.

| argument | Hopper | Walker2d |
| --- | --- | --- |
| forward_reward_weight | 1.0 | 1.0 |
| ctrl_cost_weight | 1e-3 | 1e-3 |
| healthy_reward | 1.0 | 1.0 |
| terminate_when_unhealthy | True | True |
| healthy_state_range | (-100, 100) | (none) |
| healthy_z_range | (0.7, inf) | (0.8, 2.0) |
| healthy_angle_range | (-0.2, 0.2) | (-1.0, 1.0) |
| reset_noise_scale | 5e-3 | 5e-3 |
| exclude_current_positions_from_observation | True | True |

v5's xml_file, frame_skip, camera and render arguments are not taken: frame skip 4 at timestep
0.002 (dt = 0.008), RK4. Ours besides: every MJX task's `impl` ("jax" or "warp"), `opt`,
`nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
One env step of ours (float32) and of Gymnasium's env (C MuJoCo, float64) from the same state (qpos,
qvel, solver warm start) with the same action (`envs.interop.gymnasium_equality`); tests/test_walkers.py,
each test for both tasks:
- test_steps_match_gymnasium (slow, impl "jax"): 320 steps (32 episodes x 40 random actions; 70%
  (Hopper) and 47% (Walker2d) touching the floor, about half unhealthy). Observation within 1e-4
  (Hopper) and 5e-4 (Walker2d), reward and every metric within 2e-5, each plus 1e-4 relative;
  termination equal.
- test_steps_match_gymnasium_with_every_option_changed (slow): 80 steps, every option changed, the
  same bounds.
- test_health_at_the_edges_is_gymnasiums: states on and just inside each bound of the healthy
  ranges, our is_healthy equal to v5's.
- test_reset_distribution_matches_gymnasium: 4,000 resets each; per coordinate of qpos and qvel the
  means within 5 standard errors, the spreads within 10%; the noise inside +-5e-3, both ends reached.
- test_options_are_gymnasiums: argument names, defaults and episode length equal v5's.
- impl "warp": tests/test_gymnasium_warp.py::test_steps_match_gymnasium (slow), the same 320 steps:
  99% within the bounds above, every step within 1e-2, termination equal;
  tests/test_warp.py::test_gymnasium_tasks_step_alike_under_both_implementations: "warp" against
  "jax", 4 envs x 10 steps, observation and reward within 2e-3 (+2e-3 relative).

Not compared: whole episodes (float32 and float64 trajectories part over many steps) and the reset's
draws themselves (only their distribution).
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from envs.mjx_env import mjx
from envs.ranges import FINITE, FLAG, INTERVAL, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv

# The options both walkers take, checked by envs.make before anything compiles.
WALKER_RANGES: dict[str, Valid] = {
    "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "healthy_reward": FINITE,
    "terminate_when_unhealthy": FLAG, "healthy_z_range": INTERVAL, "healthy_angle_range": INTERVAL,
    "reset_noise_scale": NON_NEGATIVE, "exclude_current_positions_from_observation": FLAG}


@struct.dataclass
class HopperParams:
    """Hopper-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-3
    healthy_reward: float = 1.0
    terminate_when_unhealthy: bool = struct.field(pytree_node=False, default=True)
    healthy_state_range: tuple[float, float] = (-100.0, 100.0)  # every qpos[2:] and qvel
    healthy_z_range: tuple[float, float] = (0.7, math.inf)
    healthy_angle_range: tuple[float, float] = (-0.2, 0.2)
    reset_noise_scale: float = 5e-3
    # Changes the observation's size, so it is fixed at construction (not a pytree leaf).
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {**WALKER_RANGES, "healthy_state_range": INTERVAL}


@struct.dataclass
class Walker2dParams:
    """Walker2d-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-3
    healthy_reward: float = 1.0
    terminate_when_unhealthy: bool = struct.field(pytree_node=False, default=True)
    healthy_z_range: tuple[float, float] = (0.8, 2.0)
    healthy_angle_range: tuple[float, float] = (-1.0, 1.0)
    reset_noise_scale: float = 5e-3
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = WALKER_RANGES


def inside(value: jnp.ndarray, interval: tuple[float, float]) -> jnp.ndarray:
    """low < value < high (Gymnasium's strict comparisons), for every element."""
    low, high = interval
    return jnp.all((low < value) & (value < high))


class PlanarWalker(GymnasiumMujocoEnv):
    """What Hopper-v5 and Walker2d-v5 share: everything but the model and the Hopper's state check."""

    frame_skip = 4
    velocity_clip = 10.0

    def is_healthy(self, data: mjx.Data) -> jnp.ndarray:
        z, angle = data.qpos[1], data.qpos[2]
        return inside(z, self.params.healthy_z_range) & inside(angle, self.params.healthy_angle_range)

    def reward(self, data, action, prev):
        p = self.params
        x_velocity = self.velocity(data, prev)
        forward_reward = p.forward_reward_weight * x_velocity
        # v5 pays the healthy reward only in a healthy state, whether or not that ends the episode.
        healthy_reward = jnp.where(self.is_healthy(data), p.healthy_reward, 0.0)
        ctrl_cost = self.control_cost(data)
        terms = {"reward_forward": forward_reward, "reward_ctrl": -ctrl_cost, "reward_survive": healthy_reward,
                 "x_position": data.qpos[0], "z_distance_from_origin": data.qpos[1] - self.init_qpos[1],
                 "x_velocity": x_velocity}
        return forward_reward + healthy_reward - ctrl_cost, terms

    def terminated(self, data):
        return ~self.is_healthy(data) & self.params.terminate_when_unhealthy


class Hopper(PlanarWalker):
    gymnasium_id = "Hopper-v5"
    xml_file = "hopper.xml"

    def __init__(self, params: HopperParams = HopperParams(), xml: str | None = None):
        super().__init__(params, xml)

    def is_healthy(self, data):
        # Gymnasium's state_vector()[2:]: every coordinate but x and z, velocities included.
        state = jnp.concatenate([data.qpos[2:], data.qvel])
        return super().is_healthy(data) & inside(state, self.params.healthy_state_range)


class Walker2d(PlanarWalker):
    gymnasium_id = "Walker2d-v5"
    xml_file = "walker2d_v5.xml"

    def __init__(self, params: Walker2dParams = Walker2dParams(), xml: str | None = None):
        super().__init__(params, xml)
