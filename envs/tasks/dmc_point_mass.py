"""The DeepMind Control Suite's point mass, easy and hard (dm_control/suite/point_mass.py), stepped by MJX:
`envs.make("dmc-point-mass-easy")`, `envs.make("dmc-point-mass-hard")`. A mass on two slides in a walled
plane (Euler, timestep 0.02, one physics step per control step), pushed through two tendons, must reach
the target at the centre. The MJCF is dm_control's `point_mass.xml`, read from the installed package.

- Action: Box(-1, 1, (2,)): the two tendon motors (x and y in "easy"; in "hard" each pushes along a
  direction drawn per episode).
- Observation (4), dm_control's order: position = qpos, velocity = qvel.
- Reward: near_target * small_control, near_target = tolerance(|target - mass|, (0, r), margin r)
  with r the target's radius, small_control = (4 + mean tolerance(ctrl, margin 1,
  value_at_margin 0, quadratic)) / 5.
- Reset: both slides uniform in their ranges (dm_control's joint randomiser), at rest.
- Episode: 1,000 steps (20 s simulated), never terminated.
- "hard" (dm_control's EXTRA task, `randomize_gains=True`): each episode the tendons' coefficients
  (`model.wrap_prm`, tendon t1's on root_x, root_y, then t2's) are two unit vectors, dir1 = randn(2)
  normalised, dir2 drawn likewise again until |dir1 . dir2| <= 0.9, kept in `state.info["wrap_prm"]`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs.mjx_env import mjx
from envs.tasks.dm_control_suite import DmControlEnv, randomize_joints, tolerance

PARALLEL = 0.9  # dm_control's rejection: |dir1 . dir2| above it draws dir2 again


class DmcPointMassEasy(DmControlEnv):
    domain, task = "point_mass", "easy"
    observation_shapes = (("position", 2), ("velocity", 2))

    def initial_qpos_qvel(self, key):
        return randomize_joints(self.mj_model, jnp.asarray(self.mj_model.qpos0), key), jnp.zeros(2)

    def observations(self, data):
        return {"position": data.qpos, "velocity": data.qvel}

    def reward(self, data, action, prev):
        target, mass = self.mj_model.geom("target").id, self.mj_model.geom("pointmass").id
        size = float(self.mj_model.geom_size[target, 0])
        near_target = tolerance(jnp.linalg.norm(data.geom_xpos[target] - data.geom_xpos[mass]), (0.0, size),
                                margin=size)
        control = tolerance(data.ctrl, margin=1, value_at_margin=0, sigmoid="quadratic").mean()
        return near_target * (control + 4) / 5


def unit_direction(key: jax.Array) -> jax.Array:
    direction = jax.random.normal(key, (2,))
    return direction / jnp.linalg.norm(direction)


def with_tendons(model: mjx.Model, data: mjx.Data, jacobian: jax.Array, velocity: bool = True) -> mjx.Data:
    """`data` with the fixed tendons of coefficients `jacobian` (tendon x joint; the point mass's slides:
    qpos and dofs alike) in place of the model's `wrap_prm`: their lengths and Jacobian (MJX's
    `smooth.tendon`), the actuators' lengths and moments from them (`mjx.transmission`), and with
    `velocity` the tendons' and actuators' velocities (`mjx.fwd_velocity`'s first lines)."""
    jacobian = jacobian.astype(data.qpos.dtype)
    data = data.replace(ten_length=jacobian @ data.qpos).tree_replace({"_impl.ten_J": jacobian})
    data = mjx.transmission(model, data)
    if velocity:
        data = data.tree_replace({"_impl.ten_velocity": jacobian @ data.qvel,
                                  "_impl.actuator_velocity": data._impl.actuator_moment @ data.qvel})
    return data


@jax.jit
def step_with_tendons(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """`mjx.step` (mjx.forward's stages, then Euler) with the tendons' coefficients read from
    `data`'s tendon Jacobian (a fixed tendon's Jacobian is its coefficients: `with_tendons` put the
    episode's there) in place of the model's `wrap_prm`, right after the position stage computed them."""
    jacobian = data._impl.ten_J
    data = with_tendons(model, mjx.fwd_position(model, data), jacobian, velocity=False)
    data = mjx.fwd_acceleration(model, mjx.fwd_actuation(model, mjx.sensor_vel(model, mjx.fwd_velocity(
        model, mjx.sensor_pos(model, data)))))
    if data._impl.efc_J.size == 0:
        data = data.replace(qacc=data.qacc_smooth)
    else:
        data = mjx.sensor_acc(model, mjx.solve(model, data))
    return mjx.euler(model, data)


class DmcPointMassHard(DmcPointMassEasy):
    """dm_control's point_mass hard: easy with the tendons' coefficients drawn per episode (the
    module docstring). MJX keeps `wrap_prm` as static numpy metadata of its Model (its `smooth.tendon`
    reads it with numpy), so no env can step a model of its own coefficients: the episode's
    coefficients live in `state.info["wrap_prm"]` and in the state's tendon Jacobian
    (`with_episode` writes them there after every physics call), and the step computes the tendons
    from that Jacobian (`step_with_tendons`), under impl="jax" only."""

    task = "hard"
    episode_info = ("wrap_prm",)  # dm_control's per-episode edit, for envs.interop.dm_control
    per_env_model = "its tendons' coefficients (wrap_prm) are drawn"

    def _put_on_device(self, impl: str) -> None:
        wraps = self.mj_model.wrap_objid.reshape(2, 2)
        if self.mj_model.nv != 2 or not (wraps == [[0, 1], [0, 1]]).all():  # the layout `with_tendons` assumes
            raise ValueError(f"task {self.name}: expected tendons t1, t2 over joints root_x, root_y")
        super()._put_on_device(impl)

    def draw_episode(self, key):
        key, first, second = jax.random.split(key, 3)
        dir1 = unit_direction(first)

        def redraw(carry):
            key, _ = carry
            key, draw = jax.random.split(key)
            return key, unit_direction(draw)

        key_left, dir2_key = jax.random.split(second)
        _, dir2 = jax.lax.while_loop(lambda carry: jnp.abs(dir1 @ carry[1]) > PARALLEL, redraw,
                                     (key_left, unit_direction(dir2_key)))
        dtype = self._initial_data.qpos.dtype
        return key, {"wrap_prm": jnp.concatenate([dir1, dir2]).astype(dtype)}

    def with_episode(self, data, info):
        return with_tendons(self.mjx_model, data, info["wrap_prm"].reshape(2, 2))

    def _physics(self, model, data):
        return self.refresh(model, step_with_tendons(model, data))

    def put_episode(self, physics, info) -> None:
        physics.model.wrap_prm[:] = info["wrap_prm"]

    def get_episode(self, physics) -> dict:
        return {"wrap_prm": np.array(physics.model.wrap_prm)}
