"""Gymnasium's Humanoid-v5, stepped by MJX.

A 3-D biped (torso, arms, legs; 17 hinge motors) walks forward on a plane. The MJCF is read from
the installed gymnasium package; the rest follows `gymnasium/envs/mujoco/humanoid_v5.py`:

- frame skip 5 (timestep 0.003, dt 0.015 s; the MJCF integrates with RK4);
- observation (348 values by default): qpos without the torso's x, y (22; all 24 with
  exclude_current_positions_from_observation=False), qvel (23), and for bodies 1..13 (the world
  left out) `cinert` (130: 10 each), `cvel` (78: 6 each), then `qfrc_actuator` of the 17 hinges
  (qvel's dofs after the free joint's 6) and `cfrc_ext` (78: 6 each), each of the last four left
  out by its `include_*_in_observation=False`. Nothing is clipped (Ant clips cfrc_ext; Humanoid
  does not);
- reward = reward_forward + reward_survive - ctrl cost - contact cost: forward_reward_weight times
  the x velocity of the centre of mass (the mass-weighted mean of the bodies' `xipos`, Gymnasium's
  `mass_center`: MuJoCo's `subtree_com` of the world body), healthy_reward while healthy (the
  torso's z strictly inside healthy_z_range), ctrl_cost_weight * sum(ctrl^2) (ctrl in Gymnasium's action units, the ctrlrange [-0.4, 0.4]) and
  contact_cost_weight * sum(cfrc_ext^2) over every body, that total clipped to contact_cost_range
  (default (-inf, 10]); terminated when unhealthy (with terminate_when_unhealthy);
- reset: qpos = qpos0 + U(-s, s), qvel = U(-s, s), s = reset_noise_scale (1e-2).

**The one change to Gymnasium's model: the constraint solver.** humanoid.xml sets
`solver="PGS" iterations="50"`. MJX (impl "jax") and MuJoCo Warp solve constraints with CG or
Newton only: `mjx.put_model` raises NotImplementedError(mjSOL_PGS) for this model as it is, and
MuJoCo Warp's `put_model` refuses it as "mjSOL_PGS is unsupported" (their `SolverType` enums say
"unsupported: PGS"). So the task steps the model with Newton (`MODEL_SOLVER`, set in
`GymnasiumMujocoEnv` for any v5 MJCF that names PGS), every other option of the MJCF as it is
(RK4, timestep 0.003, iterations 50, tolerance, cone, ...). PGS and Newton solve the same convex
problem, to different precision after 50 iterations; tests/test_humanoid.py measures the
difference against Gymnasium's unmodified env (docs/tasks.md has the figures). `opt={"solver":
"cg"}` picks CG instead; `opt={"solver": "pgs"}` is refused by MJX as before.

Quantities read as Gymnasium reads them, after MuJoCo's step:
- `cinert`, `cvel`, `qfrc_actuator` and `subtree_com` are those MuJoCo derives in its last forward
  evaluation: after an RK4 step that is RK4's last stage, not the new qpos, in C MuJoCo and MJX
  alike. Reset runs `mjx.forward` (`forward_on_reset`) as Gymnasium's `set_state` runs
  `mj_forward`, so the reset observation holds the reset pose's cinert and cvel and the first
  step's "before" centre of mass is the reset pose's.
- `cfrc_ext`: Gymnasium runs `mj_rnePostConstraint` after `mj_step`. Under impl "jax" this task
  runs MJX's `mjx.rne_postconstraint` after the step; under impl "warp" MuJoCo Warp runs it inside
  each forward pass when `opt.run_rne_postconstraint` is set, which this task sets (as `ant`).
  At reset it is zero, as Gymnasium's `mj_forward` leaves it.

Gymnasium's `info` also holds `tendon_length` and `tendon_velocity` (arrays of 2, the hip-knee
tendons): `state.metrics` holds scalars only (Brax's evaluator sums each per episode), so they are
left out of it; they are `state.pipeline_state.ten_length` and `.ten_velocity`.

Actions: ours in [-1, 1], scaled to the ctrlrange [-0.4, 0.4]: our action a is Gymnasium's 0.4a
(`env.to_env_action`; `load_policy` returns actions in the same [-0.4, 0.4] through
`env.action_low`/`action_high`, so a policy trained here acts on `gymnasium.make("Humanoid-v5")`).
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
    forward_on_reset = True  # the reset observation's cinert/cvel, and the first step's centre of mass
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
