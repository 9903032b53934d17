"""Swimmer-v5 of Gymnasium (gymnasium/envs/mujoco/swimmer_v5.py), stepped by MJX: `envs.make("swimmer")`.
Three capsules joined by two motored hinges swim forward in a viscous fluid (MuJoCo's fluid forces:
density 4000, viscosity 0.1). The MJCF is Gymnasium's own `swimmer.xml`, read from the installed package.

## Action Space
| | ours | Gymnasium v5 |
| --- | --- | --- |
| `step` takes | Box(-1, 1, (2,), float32) | Box(-1, 1, (2,), float32) |
| becomes `ctrl` | scaled to the ctrlrange [-1, 1]: unchanged | as given |

The two hinge motors' torques. `env.action_low`/`action_high` and `envs.to_gymnasium` give Gymnasium's space.

## Observation Space
- 8 values, float32 (Gymnasium: float64): qpos[2:] (heading, two hinge angles), then qvel (5).
  Both x and y are left out (the other tasks leave out x alone).
- `exclude_current_positions_from_observation=False`: all of qpos, 10 values.

## Rewards
- reward = reward_forward + reward_ctrl, as v5:
  - reward_forward = forward_reward_weight * x_velocity (x's change over dt);
  - reward_ctrl = -ctrl_cost_weight * sum(ctrl^2).
- `state.metrics` holds v5's `info`: reward_forward, reward_ctrl, x_position, y_position,
  distance_from_origin, x_velocity, y_velocity.

## Starting State
- qpos = qpos0 + U(-s, s), qvel = U(-s, s), s = reset_noise_scale (0.1), as v5; JAX's random
  numbers: the same distribution, not the same draws.

## Episode End
- Terminated: never (as v5). Truncated: after 1000 steps (`envs.make`'s TimeLimit, v5's
  max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make("swimmer", **options)`, `SwimmerParams`: v5's names and defaults.

| argument | default |
| --- | --- |
| forward_reward_weight | 1.0 |
| ctrl_cost_weight | 1e-4 |
| reset_noise_scale | 0.1 |
| exclude_current_positions_from_observation | True |

v5's xml_file, frame_skip, camera and render arguments are not taken: frame skip 4 at timestep
0.01 (dt = 0.04), RK4. Ours besides: every MJX task's `impl` ("jax" or "warp"), `opt`,
`nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
One env step of ours (float32) and of Gymnasium's env (C MuJoCo, float64) from the same state (qpos,
qvel, solver warm start) with the same action (`envs.interop.gymnasium_equality`); tests/test_swimmer.py:
- test_steps_match_gymnasium (slow, impl "jax"): 320 steps (32 episodes x 40 random actions, some
  pushing a hinge past its 100-degree limit). Observation within 2e-5, reward and every metric within
  1e-5, each plus 1e-4 relative; termination equal.
- test_steps_match_gymnasium_with_every_option_changed (slow): 80 steps, all four options changed,
  the same bounds.
- test_reset_distribution_matches_gymnasium: 4,000 resets each; per coordinate of qpos and qvel the
  means within 5 standard errors, the spreads within 10%; the noise inside +-0.1, both ends reached;
  the observation is exactly qpos[2:], qvel.
- test_options_are_gymnasiums: argument names, defaults and episode length equal v5's.
- impl "warp": tests/test_gymnasium_warp.py::test_steps_match_gymnasium (slow), the same 320 steps:
  99% within the bounds above, every step within 1e-2, termination equal;
  tests/test_warp.py::test_gymnasium_tasks_step_alike_under_both_implementations: "warp" against
  "jax", 4 envs x 10 steps, observation and reward within 2e-3 (+2e-3 relative).

Not compared: whole episodes (float32 and float64 trajectories part over many steps) and the reset's
draws themselves (only their distribution).
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp
from flax import struct

from envs.ranges import FINITE, FLAG, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class SwimmerParams:
    """Swimmer-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 1e-4
    reset_noise_scale: float = 0.1
    # Changes the observation's size, so it is fixed at construction (not a pytree leaf).
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {
        "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "reset_noise_scale": NON_NEGATIVE,
        "exclude_current_positions_from_observation": FLAG}


class Swimmer(GymnasiumMujocoEnv):
    gymnasium_id = "Swimmer-v5"
    xml_file = "swimmer.xml"
    frame_skip = 4
    skipped_qpos = 2  # x and y

    def __init__(self, params: SwimmerParams = SwimmerParams(), xml: str | None = None):
        super().__init__(params, xml)

    def reward(self, data, action, prev):
        x_velocity, y_velocity = self.velocity(data, prev, 0), self.velocity(data, prev, 1)
        forward_reward = self.params.forward_reward_weight * x_velocity
        ctrl_cost = self.control_cost(data)
        terms = {"reward_forward": forward_reward, "reward_ctrl": -ctrl_cost,
                 "x_position": data.qpos[0], "y_position": data.qpos[1],
                 "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
                 "x_velocity": x_velocity, "y_velocity": y_velocity}
        return forward_reward - ctrl_cost, terms

    def terminated(self, data):
        return jnp.zeros((), bool)
