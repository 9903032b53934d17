"""Gymnasium's Ant-v5, stepped by MJX.

A four-legged robot walks forward on a plane. The MJCF is read from the installed gymnasium
package; the rest follows `gymnasium/envs/mujoco/ant_v5.py`:

- frame skip 5 (dt 0.05 s; the MJCF integrates with RK4);
- observation: qpos without the torso's x, y (unless exclude_current_positions_from_observation
  is False), qvel, and each body's external contact force `cfrc_ext` (bodies 1..13, 6 values each,
  clipped to contact_force_range; left out with include_cfrc_ext_in_observation=False): 105 values;
- reward = reward_forward + reward_survive - ctrl cost - contact cost: forward_reward_weight times
  the main body's x velocity, healthy_reward while healthy (every state finite and the torso's z
  in healthy_z_range), ctrl_cost_weight * sum(ctrl^2) (ctrl in Gymnasium's action units) and
  contact_cost_weight * sum(clipped cfrc_ext^2); terminated when unhealthy (with
  terminate_when_unhealthy); reset qpos = qpos0 + U(-s, s), qvel = s * N(0, 1), s = reset_noise_scale.

Two quantities are read as Gymnasium reads them, after MuJoCo's step:
- `cfrc_ext`: Gymnasium runs `mj_rnePostConstraint` after `mj_step`. MJX's pure-JAX implementation
  has the same function (`mjx.rne_postconstraint`), run here after the step; under impl="warp"
  MuJoCo Warp runs it inside each forward pass when the model's `opt.run_rne_postconstraint` is
  set, which this task sets. Either way the contact forces are those of RK4's last stage, the
  data `mj_rnePostConstraint` reads in C MuJoCo. At reset Gymnasium's `mj_forward` leaves
  cfrc_ext at zero (nothing asks for it), and so does ours.
- x and y velocity: the main body's `xpos` before and after the step over dt. MuJoCo leaves
  `xpos` at RK4's last stage, not at the new qpos, so this is not qpos's change; reset runs
  `mjx.forward` so the first step's "before" is the reset pose, as Gymnasium's `set_state` makes it.

Actions: ours in [-1, 1] scaled to the ctrlrange, which is [-1, 1]: the same as Gymnasium's.
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
    forward_on_reset = True  # the first step's velocity needs the reset pose's xpos
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
