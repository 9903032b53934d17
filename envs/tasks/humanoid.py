"""Humanoid-v5 of Gymnasium (gymnasium/envs/mujoco/humanoid_v5.py), stepped by MJX: `envs.make("humanoid")`.
A 3-D biped (torso, arms, legs; 17 hinge motors) walks forward on a plane. The MJCF is Gymnasium's
own `humanoid.xml`, read from the installed package, with one change: the constraint solver.

## Action Space
| | ours | Gymnasium v5 |
| --- | --- | --- |
| `step` takes | Box(-1, 1, (17,), float32) | Box(-0.4, 0.4, (17,), float32) |
| becomes `ctrl` | scaled to the ctrlrange [-0.4, 0.4]: 0.4a | as given |

Abdomen, hip, knee, shoulder and elbow torques. `env.action_low`/`action_high`, `env.to_env_action`
and `envs.to_gymnasium` give Gymnasium's space (`load_policy` returns Gymnasium's units).

## Observation Space
348 values, float32 (Gymnasium: float64), as v5, nothing clipped: qpos[2:] (22), qvel (23), then
for bodies 1..13 `cinert` (130), `cvel` (78), `qfrc_actuator` of the 17 hinges (qvel[6:]) and
`cfrc_ext` (78).
- `exclude_current_positions_from_observation=False`: all of qpos (+2); each
  `include_{cinert,cvel,qfrc_actuator,cfrc_ext}_in_observation=False` leaves its part out.
- After an RK4 step MuJoCo's derived values are RK4's last stage's, in C MuJoCo and MJX alike.
  `cfrc_ext`: v5's `mj_rnePostConstraint` after the step is `mjx.rne_postconstraint` under impl
  "jax" and MuJoCo Warp's forward pass with `opt.run_rne_postconstraint` under "warp"; 0 at reset.

## Rewards
- reward = reward_forward + reward_survive + reward_ctrl + reward_contact, as v5:
  - reward_forward = forward_reward_weight * x_velocity of the centre of mass (`subtree_com` of the
    world body: v5's mass-weighted mean of `xipos`), before and after the step over dt;
  - reward_survive = healthy_reward while the torso's z is strictly inside healthy_z_range, else 0;
  - reward_ctrl = -ctrl_cost_weight * sum(ctrl^2), ctrl in Gymnasium's units;
  - reward_contact = -(contact_cost_weight * sum(cfrc_ext^2) over all bodies, clipped to contact_cost_range).
- `state.metrics` holds v5's scalar `info`: the four terms, x/y_position, distance_from_origin,
  x/y_velocity. v5's tendon_length and tendon_velocity (arrays) are left out: they are
  `state.pipeline_state.ten_length` and `.ten_velocity`.

## Starting State
- qpos = qpos0 + U(-s, s), qvel = U(-s, s), s = reset_noise_scale (1e-2), as v5; JAX's random
  numbers: the same distribution, not the same draws. `mjx.forward` at reset, as v5's `set_state`
  runs `mj_forward` (the reset observation's cinert and cvel, the first step's centre of mass).

## Episode End
- Terminated: when unhealthy, unless terminate_when_unhealthy=False (as v5). Truncated: after 1000
  steps (`envs.make`'s TimeLimit, v5's max_episode_steps).
- Ours besides (every MjxEnv): a non-finite step (`info["nan"]`) or, under impl="warp", an overflow
  of MuJoCo Warp's buffers (`info["overflow"]`) ends the episode with reward 0.

## Arguments
`envs.make("humanoid", **options)`, `HumanoidParams`: v5's names and defaults.

| argument | default |
| --- | --- |
| forward_reward_weight | 1.25 |
| ctrl_cost_weight | 0.1 |
| contact_cost_weight | 5e-7 |
| contact_cost_range | (-inf, 10.0) |
| healthy_reward | 5.0 |
| terminate_when_unhealthy | True |
| healthy_z_range | (1.0, 2.0) |
| reset_noise_scale | 1e-2 |
| exclude_current_positions_from_observation | True |
| include_cinert/cvel/qfrc_actuator/cfrc_ext_in_observation | True |

v5's xml_file, frame_skip, camera and render arguments are not taken: frame skip 5 at timestep
0.003 (dt = 0.015), RK4. Ours besides: every MJX task's `impl` ("jax" or "warp"), `opt`,
`nconmax`/`naconmax`/`njmax` and `randomize` (`envs.make`).

**The one change to v5's model: the solver.** humanoid.xml names `solver="PGS" iterations="50"`,
which neither MJX (`put_model` raises NotImplementedError(mjSOL_PGS)) nor MuJoCo Warp ("mjSOL_PGS
is unsupported") has. The task steps it with Newton (`MODEL_SOLVER`, set in `GymnasiumMujocoEnv`
for any v5 MJCF that names PGS), every other option as the MJCF's; `opt={"solver": "cg"}` picks CG,
`opt={"solver": "pgs"}` is refused. Both solve the same convex problem, to different precision.

## Version History
- v5 only (Gymnasium 1.x); v4 and earlier are not offered.

## Equality with Gymnasium
Two proofs (tests/test_humanoid.py), the second against v5's env with the same solver change:
- test_task_reads_mujocos_data_as_gymnasium_does (impl "jax"): v5's own MjData (its model
  unmodified) before and after each of 200 random-action steps, put on the device, through our
  post_step, observation, reward and termination: cfrc_ext within 1e-2 of C's (+1e-4 relative);
  observation, reward and every metric within 1e-4 (+1e-5 relative); termination equal; the metrics
  are v5's scalar `info` names. `..._with_every_option_changed` (slow): 120 steps, the same bounds.
- test_steps_match_gymnasium_with_the_same_solver (slow): one env step each from the same 200
  states (16 episodes x 40 random actions) and actions, v5's model set to Newton: qpos[2:],
  cinert and qfrc_actuator within 1e-4; qvel and cvel within 1e-2; cfrc_ext within 1 (+1e-2
  relative); all but cfrc_ext within 1e-3 on over 95% of the steps; reward and metrics within 2e-3
  (+1e-4 relative); termination equal.
- test_the_solver_change_moves_a_step_less_than_float32_does (slow): v5's unmodified (PGS) env
  against its Newton one, from those states: each part within a fifth of the bounds above,
  cfrc_ext 0.2, reward 1e-4, termination equal; ours against the unmodified env within the bounds above.
- test_reset_distribution_matches_gymnasium: 4,000 resets' qpos and qvel by mean and spread, noise
  inside +-0.01; test_reset_observation_is_gymnasiums (slow): 50 reset states set in v5's env, the
  observation within 1e-5 (+1e-5 relative), cfrc_ext 0 in both.
- test_options_are_gymnasiums: argument names, defaults, sizes, action units and episode length
  equal v5's; test_the_model_is_gymnasiums_but_for_the_solver.
- impl "warp": tests/test_gymnasium_warp.py::test_humanoid_steps_as_under_jax (slow): the second
  proof's assertions; tests/test_warp.py::test_gymnasium_tasks_step_alike_under_both_implementations:
  "warp" against "jax", 4 envs x 10 steps, observation and reward within 2e-3 (+2e-3 relative).
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from envs.mjx_env import mjx
from envs.ranges import FINITE, FLAG, INTERVAL, NON_NEGATIVE, Valid
from envs.tasks.gymnasium_mujoco import GymnasiumMujocoEnv


@struct.dataclass
class HumanoidParams:
    """Humanoid-v5's constructor arguments (same names and defaults)."""

    forward_reward_weight: float = 1.25
    ctrl_cost_weight: float = 0.1
    contact_cost_weight: float = 5e-7
    contact_cost_range: tuple[float, float] = (-math.inf, 10.0)  # the contact cost is clipped to it
    healthy_reward: float = 5.0
    terminate_when_unhealthy: bool = True
    healthy_z_range: tuple[float, float] = (1.0, 2.0)  # the torso's z while healthy (ends excluded)
    reset_noise_scale: float = 1e-2
    # What the observation holds is fixed at construction (not pytree leaves): it sets its size.
    exclude_current_positions_from_observation: bool = struct.field(pytree_node=False, default=True)
    include_cinert_in_observation: bool = struct.field(pytree_node=False, default=True)
    include_cvel_in_observation: bool = struct.field(pytree_node=False, default=True)
    include_qfrc_actuator_in_observation: bool = struct.field(pytree_node=False, default=True)
    include_cfrc_ext_in_observation: bool = struct.field(pytree_node=False, default=True)

    RANGES: ClassVar[dict[str, Valid]] = {
        "forward_reward_weight": FINITE, "ctrl_cost_weight": FINITE, "contact_cost_weight": FINITE,
        "contact_cost_range": INTERVAL, "healthy_reward": FINITE, "terminate_when_unhealthy": FLAG,
        "healthy_z_range": INTERVAL, "reset_noise_scale": NON_NEGATIVE,
        "exclude_current_positions_from_observation": FLAG, "include_cinert_in_observation": FLAG,
        "include_cvel_in_observation": FLAG, "include_qfrc_actuator_in_observation": FLAG,
        "include_cfrc_ext_in_observation": FLAG,
    }


class Humanoid(GymnasiumMujocoEnv):
    """Gymnasium's Humanoid-v5 (see the module docs)."""

    gymnasium_id = "Humanoid-v5"
    xml_file = "humanoid.xml"
    frame_skip = 5
    skipped_qpos = 2  # the torso's x and y
    reset_computes_derived = True  # the reset observation's cinert/cvel, and the first step's centre of mass
    reads_contact_forces = True  # cfrc_ext after each step (GymnasiumMujocoEnv)

    def __init__(self, params: HumanoidParams = HumanoidParams(), xml: str | None = None):
        super().__init__(params, xml)

    @property
    def observation_size(self) -> int:
        p, bodies, nv = self.params, self.mj_model.nbody - 1, self.mj_model.nv
        return (super().observation_size + 10 * bodies * p.include_cinert_in_observation
                + 6 * bodies * p.include_cvel_in_observation + (nv - 6) * p.include_qfrc_actuator_in_observation
                + 6 * bodies * p.include_cfrc_ext_in_observation)

    def observation(self, data: mjx.Data) -> jax.Array:
        p = self.params
        parts = [super().observation(data)]
        if p.include_cinert_in_observation:
            parts.append(self.cinert(data)[1:].ravel())
        if p.include_cvel_in_observation:
            parts.append(data.cvel[1:].ravel())
        if p.include_qfrc_actuator_in_observation:
            parts.append(data.qfrc_actuator[6:])
        if p.include_cfrc_ext_in_observation:
            parts.append(self.cfrc_ext(data)[1:].ravel())
        return jnp.concatenate(parts)

    def mass_center(self, data: mjx.Data) -> jax.Array:
        """x, y of the centre of mass: Gymnasium's mass_center, the bodies' xipos weighted by body_mass,
        is the world body's subtree_com, which MuJoCo computes beside xipos from the model's own masses
        (so with envs.randomize's too)."""
        return data.subtree_com[0, :2]

    def is_healthy(self, data: mjx.Data) -> jax.Array:
        low, high = self.params.healthy_z_range
        return (low < data.qpos[2]) & (data.qpos[2] < high)

    def terminated(self, data: mjx.Data) -> jax.Array:
        return ~self.is_healthy(data) & self.params.terminate_when_unhealthy

    def reward(self, data, action, prev):
        p = self.params
        x_velocity, y_velocity = (self.mass_center(data) - self.mass_center(prev)) / self.dt
        forward = p.forward_reward_weight * x_velocity
        survive = jnp.where(self.is_healthy(data), p.healthy_reward, 0.0)
        ctrl_cost = self.control_cost(data)
        squared_forces = jnp.sum(jnp.square(self.cfrc_ext(data))) if self.needs_cfrc_ext else 0.0
        low, high = p.contact_cost_range
        contact_cost = jnp.clip(p.contact_cost_weight * squared_forces, low, high)  # clipped even when 0
        terms = {
            "x_position": data.qpos[0], "y_position": data.qpos[1],
            "distance_from_origin": jnp.linalg.norm(data.qpos[:2]),
            "x_velocity": x_velocity, "y_velocity": y_velocity,
            "reward_survive": survive, "reward_forward": forward,
            "reward_ctrl": -ctrl_cost, "reward_contact": -contact_cost,
        }
        return forward + survive - ctrl_cost - contact_cost, terms
