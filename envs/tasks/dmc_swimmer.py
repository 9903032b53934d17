"""The DeepMind Control Suite's swimmers (dm_control/suite/swimmer.py), stepped by MJX:
`envs.make("dmc-swimmer-swimmer6")` (6 links) and `envs.make("dmc-swimmer-swimmer15")` (15 links).
A planar chain of a head and n - 1 segments, each hinged to the one before and driven by a motor,
in a fluid (density 3000, contacts disabled; Euler, timestep 0.002, 15 physics steps per control
step: dt 0.03) swims its nose to a target that moves every episode. The MJCF is dm_control's
`swimmer.xml`, read from the installed package, with the segments, motors and sensors added as
dm_control's `_make_model(n)` adds them to its XML (here on MuJoCo's `MjSpec`; the test proves the
compiled models equal to dm_control's).

- Action: Box(-1, 1, (n - 1,)): the joints' motors (5 for swimmer6, 14 for swimmer15).
- Observation (swimmer6: 25, swimmer15: 61), dm_control's order: joints (n - 1) = qpos[3:] (the
  hinges between segments), to_target (2) = target - nose (geom_xpos) in the head's frame, x and y;
  body_velocities (3 n) = x, y linear and z angular velocity of the head and each segment, from the
  velocimeter and gyro sensors (sensordata[12:], past the four 3-D frame sensors).
- Reward: tolerance(|to_target|, (0, r), margin 5 r, long_tail), r the target's radius (0.1).
- Reset: dm_control's joint randomiser (rootz U(-pi, pi), the hinges uniform in their range,
  +-360 / n degrees, rootx and rooty, unlimited slides, at 0), at rest; the target at x, y U(-b, b) with b = 0.3 with
  probability 0.2, else 2.
- Episode: 1,000 steps (30 s simulated), never terminated.

Model edits. The one edit dm_control does not make: every geom's contype and conaffinity are set
to 0. MJX's `put_model` checks every geom pair the contype/conaffinity filter lets through and has
no (ellipsoid, box) collision (the head against the segments' inertial boxes), even where the
model disables contacts by flag; swimmer.xml disables them (`<flag contact="disable"/>`), so C
MuJoCo never runs collision detection for it and the edit changes nothing (a task configured with
contacts enabled is refused). The target is per episode in dm_control (`geom_pos` of a world geom,
and its light's `light_pos`); here it is kept in `state.info["target"]` and written after each
physics call into `geom_xpos` and the `target_pos` frame sensor's reading (`with_episode`), where
dm_control's edited model puts them: every env and every MuJoCo Warp world steps the task's one
model. The target's light, which only lights the pictures, is moved over the target where MuJoCo
Warp renders them (its data's `light_xpos`); the CPU's ray caster draws no lights.
"""

from __future__ import annotations

import os
from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco

from envs.mjx_env import mjx
from envs.tasks.dm_control_suite import (DmControlEnv, EpisodeTarget, check_disabled, randomize_joints, tolerance,
                                         without_collisions)

CLOSE_TARGET_PROBABILITY = 0.2  # dm_control's chance of a target within CLOSE_TARGET_BOX
CLOSE_TARGET_BOX, FAR_TARGET_BOX = 0.3, 2.0  # the target's x, y half-range (m)
FRAME_SENSOR_VALUES = 12  # nose_pos, target_pos, head_xaxis, head_yaxis: dm_control's sensordata[12:]
VX_VY_WZ = (0, 1, 5)  # of each body's (velocimeter, gyro) readings


def swimmer_spec(path: os.PathLike, n_bodies: int) -> mujoco.MjSpec:
    """dm_control's `swimmer._make_model(n_bodies)` on `swimmer.xml`: a chain of `n_bodies - 1`
    segments under the head, each with its visual and inertial geoms, a site, a hinge limited to
    +-360 / n_bodies degrees, a motor and a velocimeter and gyro on its site (added in that order,
    after the MJCF's own sensors), and the tracking cameras moved out by n_bodies / 6."""
    if n_bodies < 3:
        raise ValueError(f"the swimmer needs at least 3 bodies, got {n_bodies}")
    spec = mujoco.MjSpec.from_file(str(path))
    swimmer, visual, inertial = (spec.find_default(name) for name in ("swimmer", "visual", "inertial"))
    parent, limit = spec.body("head"), 360.0 / n_bodies
    for index in range(n_bodies - 1):
        # The head's childclass ("swimmer") is every segment's class, as in dm_control's nested XML.
        child = parent.add_body(default=swimmer, name=f"segment_{index}", pos=[0.0, 0.1, 0.0])
        child.add_geom(default=visual, name=f"visual_{index}")
        child.add_geom(default=inertial, name=f"inertial_{index}")
        child.add_site(default=swimmer, name=f"site_{index}")
        child.add_joint(default=swimmer, name=f"joint_{index}", range=[-limit, limit])
        spec.add_actuator(name=f"motor_{index}", target=f"joint_{index}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        for kind, name in ((mujoco.mjtSensor.mjSENS_VELOCIMETER, "velocimeter"), (mujoco.mjtSensor.mjSENS_GYRO, "gyro")):
            spec.add_sensor(name=f"{name}_{index}", type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE,
                            objname=f"site_{index}")
        parent = child
    scale = n_bodies / 6.0  # dm_control's float(dim) * scale, in that order (the same rounding)
    for camera in spec.body("head").cameras:
        if camera.mode == mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM:
            camera.pos = [value * scale for value in camera.pos]
    return spec


class DmcSwimmer(EpisodeTarget, DmControlEnv):
    """dm_control's `swimmer.Swimmer` on `_make_model(n_bodies)`; the task below fixes n_bodies."""

    domain = "swimmer"
    control_timestep = 0.03  # dm_control's _CONTROL_TIMESTEP
    n_bodies: ClassVar[int]

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        return without_collisions(swimmer_spec(path, self.n_bodies).compile())

    def _put_on_device(self, impl: str) -> None:
        # dm_control's swimmer.xml disables contacts; `opt` may clear the flag in a configured copy.
        check_disabled(self.mj_model, mujoco.mjtDisableBit.mjDSBL_CONTACT, self.name)
        super()._put_on_device(impl)

    def draw_episode(self, key: jax.Array) -> tuple[jax.Array, dict]:
        key, close_key, target_key = jax.random.split(key, 3)
        box = jnp.where(jax.random.uniform(close_key) < CLOSE_TARGET_PROBABILITY, CLOSE_TARGET_BOX, FAR_TARGET_BOX)
        target = box * jax.random.uniform(target_key, (2,), minval=-1.0, maxval=1.0)
        return key, {"target": target.astype(self.mjx_model.geom_pos.dtype)}

    def with_episode(self, data: mjx.Data, info) -> mjx.Data:
        # The frame sensor on the target reads its geom_xpos too.
        sensor = int(self.mj_model.sensor("target_pos").adr[0])
        data = super().with_episode(data, info)
        data = data.replace(sensordata=data.sensordata.at[sensor:sensor + 2].set(info["target"]))
        warp = data._impl
        if hasattr(warp, "light_xpos"):  # MuJoCo Warp's data, which its renderer lights the pictures from
            light = int(self.mj_model.light("target_light").id)
            data = data.replace(_impl=warp.replace(light_xpos=warp.light_xpos.at[light, :2].set(info["target"])))
        return data

    def put_episode(self, physics, info) -> None:
        super().put_episode(physics, info)
        physics.named.model.light_pos["target_light", :2] = info["target"]

    def initial_qpos_qvel(self, key):
        return randomize_joints(self.mj_model, jnp.asarray(self.mj_model.qpos0), key), jnp.zeros(self.mj_model.nv)

    def _nose_to_target(self, data):
        """dm_control's `nose_to_target`: target - nose in the head's frame (row vector times xmat), x, y."""
        target, nose = self.mj_model.geom("target").id, self.mj_model.geom("nose").id
        return ((data.geom_xpos[target] - data.geom_xpos[nose]) @ self.body_xmat(data, "head"))[:2]

    def observations(self, data):
        velocities = data.sensordata[FRAME_SENSOR_VALUES:].reshape(-1, 6)[:, jnp.array(VX_VY_WZ)]
        return {"joints": data.qpos[3:], "to_target": self._nose_to_target(data),
                "body_velocities": velocities.ravel()}

    def reward(self, data, action, prev):
        size = float(self.mj_model.geom_size[self.mj_model.geom("target").id, 0])
        return tolerance(jnp.linalg.norm(self._nose_to_target(data)), (0.0, size), margin=5 * size,
                         sigmoid="long_tail")


class DmcSwimmerSwimmer6(DmcSwimmer):
    task, n_bodies = "swimmer6", 6
    observation_shapes = (("joints", 5), ("to_target", 2), ("body_velocities", 18))


class DmcSwimmerSwimmer15(DmcSwimmer):
    task, n_bodies = "swimmer15", 15
    observation_shapes = (("joints", 14), ("to_target", 2), ("body_velocities", 45))
