"""Ant-v5 of Gymnasium (gymnasium/envs/mujoco/ant_v5.py), stepped by MJX: `envs.make("ant")`.
A four-legged robot walks forward on a plane. The MJCF is Gymnasium's own `ant.xml`, read from the
installed package.

## Action Space
| | ours | Gymnasium v5 |
| --- | --- | --- |
| `step` takes | Box(-1, 1, (8,), float32) | Box(-1, 1, (8,), float32) |
| becomes `ctrl` | scaled to the ctrlrange [-1, 1]: unchanged | as given |

Hip and ankle torques of the four legs. `env.action_low`/`action_high` and `envs.to_gymnasium` give
Gymnasium's space.

## Observation Space
105 values, float32 (Gymnasium: float64), as v5: qpos[2:] (13: the torso's z and quaternion, 8
joint angles), qvel (14), then `cfrc_ext` of bodies 1..13 (6 each) clipped to contact_force_range.
- `exclude_current_positions_from_observation=False`: all of qpos (+2);
  `include_cfrc_ext_in_observation=False`: no contact forces (-78).
- `cfrc_ext` is computed as v5's `mj_rnePostConstraint` after the step: `mjx.rne_postconstraint`
  under impl "jax"; under "warp" MuJoCo Warp's forward pass with `opt.run_rne_postconstraint` set.
  Either way those of RK4's last stage, as in C MuJoCo; zero at reset, as v5's `mj_forward` leaves it.

## Rewards
- reward = reward_forward + reward_survive + reward_ctrl + reward_contact, as v5:
  - reward_forward = forward_reward_weight * x_velocity: main_body's `xpos` before and after the step
    over dt (after an RK4 step `xpos` is RK4's last stage's, as in C MuJoCo);
  - reward_survive = healthy_reward while healthy (every qpos, qvel finite, the torso's z inside
    healthy_z_range, ends included), else 0;
  - reward_ctrl = -ctrl_cost_weight * sum(ctrl^2);
  - reward_contact = -contact_cost_weight * sum(clipped cfrc_ext^2).
- `state.metrics` holds v5's `info`: the four terms, x/y_position, distance_from_origin, x/y_velocity.

## Starting State
- qpos = qpos0 + U(-s, s), qvel = s * N(0, 1), s = reset_noise_scale (0.1), as v5; JAX's random
  numbers: the same distribution, not the same draws. `mjx.forward` at reset (qpos kept as drawn),
  as v5's `set_state`, so the first step's velocity starts from the reset pose's `xpos`.

## Episode End
- Terminated: when unhealthy, unless terminate_when_unhealthy=False (as v5). Truncated: after 1000
  steps (`envs.make`'s TimeLimit, v5's max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make("ant", **options)`, `AntParams`: v5's names and defaults.

| argument | default |
| --- | --- |
| forward_reward_weight | 1.0 |
| ctrl_cost_weight | 0.5 |
| contact_cost_weight | 5e-4 |
| healthy_reward | 1.0 |
| terminate_when_unhealthy | True |
| healthy_z_range | (0.2, 1.0) |
| contact_force_range | (-1.0, 1.0) |
| reset_noise_scale | 0.1 |
| main_body | 1 (a body id or name) |
| exclude_current_positions_from_observation | True |
| include_cfrc_ext_in_observation | True |

v5's xml_file, frame_skip, camera and render arguments are not taken: frame skip 5 at timestep
0.01 (dt = 0.05), RK4. Ours besides: every MJX task's `impl` ("jax" or "warp"), `opt`,
`nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
Two proofs (tests/test_ant.py), because MJX's contacts are not C MuJoCo's where a leg touches the floor:
- test_task_reads_mujocos_data_as_gymnasium_does (slow): v5's own MjData before and after each of
  200 steps, put on the device, through our post_step, observation, reward and termination:
  cfrc_ext within 1e-3 of C's (+1e-4 relative); observation, reward and every metric within 1e-5
  (+1e-5 relative); termination equal; the metrics are exactly v5's `info` names.
- test_steps_match_gymnasium_where_mjx_can (slow, impl "jax"): one env step each from the same 200
  states (16 episodes x 40 random actions) and actions: the median step's observation within 1e-3
  and more than half of the steps within 1e-3; on those, reward within 1e-3 (+1e-4 relative);
  termination equal on every step.
- test_the_steps_differ_by_mjxs_plane_capsule_frame (slow): the rest is MJX's contact frame for a
  capsule steeper than 60 degrees to the floor; with C MuJoCo's frame patched in, over 90% of the
  200 steps are within 1e-3.
- test_reset_distribution_matches_gymnasium: 4,000 resets each; per coordinate of qpos and qvel the
  means within 5 standard errors, the spreads within 10%; the contact forces exactly 0 in both.
- test_options_are_gymnasiums: argument names, defaults, sizes and episode length equal v5's.
- impl "warp": tests/test_gymnasium_warp.py::test_ant_steps_as_under_jax (slow): the second proof's
  assertions, MuJoCo Warp framing the contact as MJX does;
  tests/test_warp.py::test_gymnasium_tasks_step_alike_under_both_implementations: "warp" against
  "jax", 4 envs x 10 steps, observation and reward within 2e-3 (+2e-3 relative).
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from envs.mjx_env import mjx
from envs.ranges import FINITE, FLAG, INTERVAL, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class AntParams:
    """Ant-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.0
    ctrl_cost_weight: float = 0.5
    contact_cost_weight: float = 5e-4
    healthy_reward: float = 1.0
    terminate_when_unhealthy: bool = True
    healthy_z_range: tuple[float, float] = (0.2, 1.0)  # the torso's z while healthy (ends included)
    contact_force_range: tuple[float, float] = (-1.0, 1.0)  # cfrc_ext is clipped to it
    reset_noise_scale: float = 0.1
    # main_body (whose x, y velocity is rewarded) and what the observation holds are fixed at
    # construction (not pytree leaves): they pick array elements and the observation's size.
    main_body: int | str = struct.field(pytree_node=False, default=1)  # a body id or name
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)
    include_cfrc_ext_in_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {
        "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "contact_cost_weight": FINITE,
        "healthy_reward": FINITE, "terminate_when_unhealthy": FLAG, "healthy_z_range": INTERVAL,
        "contact_force_range": INTERVAL, "reset_noise_scale": NON_NEGATIVE,
        "exclude_current_positions_from_observation": FLAG, "include_cfrc_ext_in_observation": FLAG,
    }


class Ant(GymnasiumMujocoEnv):
    """Gymnasium's Ant-v5 (see the module docs)."""

    gymnasium_id = "Ant-v5"
    xml_file = "ant.xml"
    frame_skip = 5
    skipped_qpos = 2  # the torso's x and y
    reset_computes_derived = True  # the first step's velocity needs the reset pose's xpos
    reads_contact_forces = True  # cfrc_ext after each step (GymnasiumMujocoEnv)

    def __init__(self, params: AntParams = AntParams(), xml: str | None = None):
        super().__init__(params, xml)
        kind, main_body = mujoco.mjtObj.mjOBJ_BODY, params.main_body
        body = -1  # not a body
        if isinstance(main_body, (int, np.integer)) and not isinstance(main_body, bool):
            body = int(main_body)
        elif isinstance(main_body, str):
            body = mujoco.mj_name2id(self.mj_model, kind, main_body)
        if not 0 <= body < self.mj_model.nbody:
            names = [mujoco.mj_id2name(self.mj_model, kind, i) for i in range(self.mj_model.nbody)]
            raise ValueError(f"task {self.name}: main_body must be a body id in [0, {self.mj_model.nbody}) "
                             f"or one of the body names {names}, got {main_body!r}")
        self.main_body = body

    @property
    def observation_size(self) -> int:
        contact_forces = 6 * (self.mj_model.nbody - 1) if self.params.include_cfrc_ext_in_observation else 0
        return super().observation_size + contact_forces

    def initial_qvel_noise(self, key: jax.Array) -> jax.Array:
        return self.params.reset_noise_scale * jax.random.normal(key, self.init_qvel.shape)

    def contact_forces(self, data: mjx.Data) -> jax.Array:
        """cfrc_ext of every body (world first), clipped to contact_force_range: shape (nbody, 6)."""
        low, high = self.params.contact_force_range
        return jnp.clip(self.cfrc_ext(data), low, high)

    def observation(self, data: mjx.Data) -> jax.Array:
        obs = super().observation(data)
        if self.params.include_cfrc_ext_in_observation:
            obs = jnp.concatenate([obs, self.contact_forces(data)[1:].ravel()])
        return obs

    def is_healthy(self, data: mjx.Data) -> jax.Array:
        low, high = self.params.healthy_z_range
        finite = jnp.isfinite(data.qpos).all() & jnp.isfinite(data.qvel).all()
        return finite & (data.qpos[2] >= low) & (data.qpos[2] <= high)

    def terminated(self, data: mjx.Data) -> jax.Array:
        return ~self.is_healthy(data) & self.params.terminate_when_unhealthy

    def reward(self, data, action, prev):
        p = self.params
        x_velocity, y_velocity = (data.xpos[self.main_body, :2] - prev.xpos[self.main_body, :2]) / self.dt
        forward = p.forward_reward_weight * x_velocity
        survive = jnp.where(self.is_healthy(data), p.healthy_reward, 0.0)
        ctrl_cost = self.control_cost(data)
        contact_cost = p.contact_cost_weight * jnp.sum(jnp.square(self.contact_forces(data))) if self.needs_cfrc_ext else 0.0
        terms = {
            "x_position": data.qpos[0], "y_position": data.qpos[1],
            "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
            "x_velocity": x_velocity, "y_velocity": y_velocity,
            "reward_forward": forward, "reward_ctrl": -ctrl_cost,
            "reward_contact": -jnp.asarray(contact_cost), "reward_survive": survive,
        }
        return forward + survive - ctrl_cost - contact_cost, terms
