"""The DeepMind Control Suite's reacher (dm_control/suite/reacher.py), stepped by MJX:
`envs.make("dmc-reacher-easy")` and `-hard`. A planar two-link arm (Euler, timestep 0.02, one
physics step per control step) brings its fingertip onto a target that moves every episode. The
MJCF is dm_control's `reacher.xml`, read from the installed package.

- Action: Box(-1, 1, (2,)): shoulder, wrist.
- Observation (6), dm_control's order: position = qpos, to_target = (target - finger) geom_xpos x, y,
  velocity = qvel.
- Reward: tolerance(|target - finger| in x, y, (0, target radius + finger radius)): 0 or 1.
- Reset: dm_control's joint randomiser (shoulder U(-pi, pi), wrist uniform in its range), at rest;
  the target at radius U(0.05, 0.2), angle U(0, 2 pi), (x, y) = radius (sin, cos) of the angle. Its
  radius is the task's: 0.05 (easy), 0.015 (hard).
- Episode: 1,000 steps (20 s simulated), never terminated.

The target is a per-episode model edit in dm_control (`geom_pos` of a world geom nothing collides
with). Here it lives in `state.info["target"]`, and after each physics call it is written into
`geom_xpos` (`with_episode`, `MjxEnv`'s per-episode markers), where dm_control's edited model puts
it: every env and every MuJoCo Warp world steps the task's one model.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.tasks.dm_control_suite import DmControlEnv, EpisodeTarget, randomize_joints, tolerance

BIG_TARGET, SMALL_TARGET = 0.05, 0.015  # dm_control's _BIG_TARGET, _SMALL_TARGET (m)


class DmcReacher(EpisodeTarget, DmControlEnv):
    """dm_control's `reacher.Reacher(target_size)`; the two tasks below fix it."""

    domain = "reacher"
    observation_shapes = (("position", 2), ("to_target", 2), ("velocity", 2))
    target_size: float

    def _put_on_device(self, impl: str) -> None:
        # The same every episode (dm_control sets it in each initialize_episode): set once.
        self.mj_model.geom_size[self.mj_model.geom("target").id, 0] = self.target_size
        super()._put_on_device(impl)

    def draw_episode(self, key: jax.Array) -> tuple[jax.Array, dict]:
        key, angle_key, radius_key = jax.random.split(key, 3)
        angle = jax.random.uniform(angle_key, minval=0.0, maxval=2 * jnp.pi)
        radius = jax.random.uniform(radius_key, minval=0.05, maxval=0.2)
        target = (radius * jnp.stack([jnp.sin(angle), jnp.cos(angle)])).astype(self.mjx_model.geom_pos.dtype)
        return key, {"target": target}

    def initial_qpos_qvel(self, key):
        return randomize_joints(self.mj_model, jnp.asarray(self.mj_model.qpos0), key), jnp.zeros(2)

    def _to_target(self, data):
        target, finger = self.mj_model.geom("target").id, self.mj_model.geom("finger").id
        return data.geom_xpos[target, :2] - data.geom_xpos[finger, :2]

    def observations(self, data):
        return {"position": data.qpos, "to_target": self._to_target(data), "velocity": data.qvel}

    def reward(self, data, action, prev):
        radii = float(self.mj_model.geom_size[self.mj_model.geom("target").id, 0]
                      + self.mj_model.geom_size[self.mj_model.geom("finger").id, 0])
        return tolerance(jnp.linalg.norm(self._to_target(data)), (0.0, radii))


class DmcReacherEasy(DmcReacher):
    task, target_size = "easy", BIG_TARGET


class DmcReacherHard(DmcReacher):
    task, target_size = "hard", SMALL_TARGET
