"""HalfCheetah-v5 of Gymnasium (gymnasium/envs/mujoco/half_cheetah_v5.py), stepped by MJX:
`envs.make("half-cheetah")`. A planar cheetah (9 joints, 6 motors) runs forward on a plane. The MJCF
is Gymnasium's own `half_cheetah.xml`, read from the installed package.

## Action Space
| | ours | Gymnasium v5 |
| --- | --- | --- |
| `step` takes | Box(-1, 1, (6,), float32) | Box(-1, 1, (6,), float32) |
| becomes `ctrl` | scaled to the ctrlrange [-1, 1]: unchanged | as given |

Motors: bthigh, bshin, bfoot, fthigh, fshin, ffoot (torques). `env.action_low`/`action_high` and
`envs.to_gymnasium` give Gymnasium's space.

## Observation Space
- 17 values, float32 (Gymnasium: float64): qpos[1:] (rootz, rooty, six joint angles), then qvel (9).
- `exclude_current_positions_from_observation=False`: all of qpos, 18 values.

## Rewards
- reward = reward_forward + reward_ctrl, as v5:
  - reward_forward = forward_reward_weight * x_velocity, x_velocity = rootx's change over dt;
  - reward_ctrl = -ctrl_cost_weight * sum(ctrl^2).
- `state.metrics` holds v5's `info`: reward_forward, reward_ctrl, x_position, x_velocity.

## Starting State
- qpos = qpos0 + U(-s, s), qvel = s * N(0, 1), s = reset_noise_scale (0.1), as v5;
  JAX's random numbers: the same distribution, not the same draws.

## Episode End
- Terminated: never (as v5). Truncated: after 1000 steps (`envs.make`'s TimeLimit, v5's
  max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make("half-cheetah", **options)`, `HalfCheetahParams`: v5's names and defaults.

| argument | default |
| --- | --- |
| forward_reward_weight | 1.0 |
| ctrl_cost_weight | 0.1 |
| reset_noise_scale | 0.1 |
| exclude_current_positions_from_observation | True |

v5's xml_file, frame_skip, camera and render arguments are not taken: frame skip 5 at timestep
0.01 (dt = 0.05), Euler. Ours besides: every MJX task's `impl` ("jax" or "warp"), `opt`,
`nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
One env step of ours (float32) and of Gymnasium's env (C MuJoCo, float64) from the same state (qpos,
qvel, solver warm start) with the same action (`envs.interop.gymnasium_equality`); tests/test_half_cheetah.py:
- test_steps_match_gymnasium (impl "jax"): 320 steps (32 episodes x 40 random actions, 46% touching
  the floor). Observation within 1e-3, reward and every metric within 2e-5 (x_position 1e-5), each
  plus 1e-4 relative; termination equal.
- test_steps_match_gymnasium_with_every_option_changed (slow): 80 steps, all four options changed,
  the same bounds.
- test_reset_distribution_matches_gymnasium: 4,000 resets each; per coordinate of qpos and qvel the
  means within 5 standard errors, the spreads within 10%; the qpos noise inside +-0.1, both ends reached.
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

import jax
import jax.numpy as jnp
from flax import struct

from envs.ranges import FINITE, FLAG, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class HalfCheetahParams:
    """HalfCheetah-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 0.1
    reset_noise_scale: float = 0.1
    # Changes the observation's size, so it is fixed at construction (not a pytree leaf).
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {
        "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "reset_noise_scale": NON_NEGATIVE,
        "exclude_current_positions_from_observation": FLAG}


class HalfCheetah(GymnasiumMujocoEnv):
    gymnasium_id = "HalfCheetah-v5"
    xml_file = "half_cheetah.xml"
    frame_skip = 5

    def __init__(self, params: HalfCheetahParams = HalfCheetahParams(), xml: str | None = None):
        super().__init__(params, xml)

    def initial_qvel_noise(self, key):
        # HalfCheetah alone draws its velocities from a normal distribution.
        return self.params.reset_noise_scale * jax.random.normal(key, self.init_qvel.shape)

    def reward(self, data, action, prev):
        x_velocity = self.velocity(data, prev)
        forward_reward = self.params.forward_reward_weight * x_velocity
        ctrl_cost = self.control_cost(data)
        terms = {"reward_forward": forward_reward, "reward_ctrl": -ctrl_cost,
                 "x_position": data.qpos[0], "x_velocity": x_velocity}
        return forward_reward - ctrl_cost, terms

    def terminated(self, data):
        return jnp.zeros((), bool)
