"""The DeepMind Control Suite's fish (dm_control/suite/fish.py), stepped by MJX:
`envs.make("dmc-fish-upright")` and `-swim`. A fish on a free joint, with a two-hinge tail and two
two-hinge fins (5 position actuators, one of them on a fixed tendon coupling the fins' rolls), in a
fluid (density 5000, no gravity, constraints disabled; Euler, timestep 0.004, 10 physics steps per
control step: dt 0.04) turns upright, or swims its mouth into a target. The MJCF is dm_control's
`fish.xml`, read from the installed package.

- Action: Box(-1, 1, (5,)): tail, tail_twist, fins_flap, finleft_pitch, finright_pitch.
- Observation, dm_control's order: joint_angles (7) = the tail's and fins' hinges (dm_control's
  `_JOINTS`), upright (1) = torso xmat zz, swim only: target (3) = target - mouth (geom_xpos) in the
  mouth's frame, velocity (13) = qvel. Upright: 21, swim: 24.
- Reward: upright: tolerance(upright, (1, 1), margin 1); swim: (7 in_target + (upright + 1) / 2) / 8
  with in_target = tolerance(|target - mouth|, (0, r), margin 2 r), r the mouth's and the target's
  radii summed.
- Reset: the root's orientation a normalised N(0, 1)^4 (dm_control's `randn`: uniform on the
  sphere), its position at qpos0, the seven hinges U(-0.2, 0.2), at rest. Swim draws the target at
  x, y U(-0.4, 0.4), z U(0.1, 0.3).
- Episode: 1,000 steps (40 s simulated), never terminated.

Model edits. The one edit dm_control does not make: every geom's contype and conaffinity are set
to 0. MJX's `put_model` checks every geom pair the contype/conaffinity filter lets through, and it
has no (ellipsoid, box) collision (the torso's `torso_massive` box against the ellipsoids), even
where the model disables collisions by flag; fish.xml disables constraints (`<flag
constraint="disable"/>`), so C MuJoCo never runs collision detection for it and the edit changes
nothing (a task configured with constraints enabled is refused). Upright hides the target (alpha 0)
in every episode, as dm_control's `initialize_episode` does: set once. Swim's target position is
per episode in dm_control (`geom_pos` of a world geom); here it is kept in `state.info["target"]`
and written after each physics call into `geom_xpos` (`with_episode`), where dm_control's edited
model puts it: every env and every MuJoCo Warp world steps the task's one model.
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.assets import load_model
from envs.tasks.dm_control_suite import DmControlEnv, EpisodeTarget, check_disabled, tolerance, without_collisions

JOINTS = ("tail1", "tail_twist", "tail2", "finright_roll", "finright_pitch", "finleft_roll", "finleft_pitch")
JOINT_SPREAD = 0.2  # the hinges' U(-0.2, 0.2) at reset (rad)
TARGET_LOW, TARGET_HIGH = (-0.4, -0.4, 0.1), (0.4, 0.4, 0.3)  # Swim's target box (m)


class DmcFish(DmControlEnv):
    """dm_control's fish domain: the reset, the joints and the uprightness."""

    domain = "fish"
    control_timestep = 0.04  # dm_control's _CONTROL_TIMESTEP

    def __init__(self, xml: str | None = None):
        super().__init__(xml)
        self._joints = np.array([self.mj_model.joint(name).qposadr[0] for name in JOINTS])
        self._root = int(self.mj_model.joint("root").qposadr[0])

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        return without_collisions(load_model(path))

    def _put_on_device(self, impl: str) -> None:
        # dm_control's fish.xml disables constraints; `opt` may clear the flag in a configured copy.
        check_disabled(self.mj_model, mujoco.mjtDisableBit.mjDSBL_CONSTRAINT, self.name)
        super()._put_on_device(impl)

    def initial_qpos_qvel(self, key):
        quat_key, joints_key = jax.random.split(key)
        quat = jax.random.normal(quat_key, (4,))
        qpos = jnp.asarray(self.mj_model.qpos0, self._initial_data.qpos.dtype)
        qpos = qpos.at[self._root + 3:self._root + 7].set(quat / jnp.linalg.norm(quat))
        joints = jax.random.uniform(joints_key, (len(JOINTS),), minval=-JOINT_SPREAD, maxval=JOINT_SPREAD)
        return qpos.at[self._joints].set(joints), jnp.zeros(self.mj_model.nv)

    def _upright(self, data):
        return self.body_xmat(data, "torso")[2, 2]


class DmcFishUpright(DmcFish):
    task = "upright"
    observation_shapes = (("joint_angles", 7), ("upright", 1), ("velocity", 13))

    def _put_on_device(self, impl: str) -> None:
        # dm_control hides the target in every initialize_episode (it plays no part here): set once.
        self.mj_model.geom_rgba[self.mj_model.geom("target").id, 3] = 0.0
        super()._put_on_device(impl)

    def observations(self, data):
        return {"joint_angles": data.qpos[self._joints], "upright": self._upright(data), "velocity": data.qvel}

    def reward(self, data, action, prev):
        return tolerance(self._upright(data), (1.0, 1.0), margin=1.0)


class DmcFishSwim(EpisodeTarget, DmcFish):
    task = "swim"
    observation_shapes = (("joint_angles", 7), ("upright", 1), ("target", 3), ("velocity", 13))
    target_axes = 3

    def draw_episode(self, key: jax.Array) -> tuple[jax.Array, dict]:
        key, target_key = jax.random.split(key)
        target = jax.random.uniform(target_key, (3,), minval=jnp.array(TARGET_LOW), maxval=jnp.array(TARGET_HIGH))
        return key, {"target": target.astype(self.mjx_model.geom_pos.dtype)}

    def _mouth_to_target(self, data):
        """dm_control's `mouth_to_target`: target - mouth, in the mouth's frame (row vector times xmat)."""
        target, mouth = self.mj_model.geom("target").id, self.mj_model.geom("mouth").id
        return (data.geom_xpos[target] - data.geom_xpos[mouth]) @ data.geom_xmat[mouth]

    def observations(self, data):
        return {"joint_angles": data.qpos[self._joints], "upright": self._upright(data),
                "target": self._mouth_to_target(data), "velocity": data.qvel}

    def reward(self, data, action, prev):
        radii = float(self.mj_model.geom_size[self.mj_model.geom("mouth").id, 0]
                      + self.mj_model.geom_size[self.mj_model.geom("target").id, 0])
        in_target = tolerance(jnp.linalg.norm(self._mouth_to_target(data)), (0.0, radii), margin=2 * radii)
        return (7 * in_target + 0.5 * (self._upright(data) + 1)) / 8
