"""The DeepMind Control Suite's quadruped walk, run and fetch (dm_control/suite/quadruped.py), stepped
by MJX: `envs.make("dmc-quadruped-walk")`, `-run` and `-fetch`. A four-legged body with an ellipsoid torso on a free
joint, 12 position actuators with a first-order filter (`act`) and 4 couplings (Euler, timestep
0.005, 4 physics steps per control step: dt 0.02) moves forward at 0.5 m/s (walk) or 5 m/s (run).
The MJCF is dm_control's `quadruped.xml`, read from the installed package, edited as dm_control's
`make_model` edits it for these tasks: the floor's size set to 10 (walk) or 100 (run), the walls,
the ball, the target site, the terrain geom and the rangefinder sensors removed.

- Action: dm_control's, the actuators' ctrlrange: yaw [-1, 1], lift [-1, 1.1], extend [-0.8, 0.8].
- Observation (78), dm_control's order: egocentric_state (44) = the 16 hinges' qpos, their qvel and
  the 12 actuators' act; torso_velocity (3) = the velocimeter; torso_upright (1) = torso xmat zz;
  imu (6) = the gyro and accelerometer sensors (in sensor order: accelerometer first); force_torque
  (24) = arcsinh of the 4 toes' force and torque sensors. Accelerometer, force and torque are
  acceleration-stage sensors: the last substep's values, as in dm_control's legacy step.
- Reward: upright * move: upright = tolerance(torso zz, (1, inf), margin 2, value_at_margin 0,
  linear); move = tolerance(velocimeter x, (speed, inf), margin speed, value_at_margin 0.5, linear).
- Reset: a root orientation N(0, 1)^4 normalised (dm_control's `randn`: uniform on the sphere), the
  joints at qpos0, at rest; the body starts embedded at z = 0 and rises 1 cm per try until nothing
  touches (dm_control's `_find_non_contacting_height`: a reset and a forward pass per try, up to
  10,000; here a `lax.while_loop` on MJX's contact slots closer than their margin, without a cap).
- Fetch (dm_control's EXTRA task, `make_model(walls_and_ball=True)`: the floor's size the MJCF's 15,
  the four walls, the ball (a free sphere, condim 6) and the target site kept): bring the ball to the
  target at the origin. Observation (90): walk's, then ball_state (9) = the ball's position and linear
  velocity relative to the torso's and its angular velocity (qvel), each in the torso's frame;
  target_position (3) = the target relative to the torso, in its frame. Reward: upright * reach *
  (0.5 + 0.5 fetch), reach = tolerance(horizontal workspace-site-to-ball distance, (0, workspace
  radius + ball radius), margin floor size * sqrt 2, value_at_margin 0, linear), fetch the same of the
  horizontal ball-to-target distance within the target's radius. Reset: a random yaw U(0, 2 pi) and
  a position U(±13.5)^2 (0.9 x the floor's size), the height searched as above there (the ball at
  qpos0, 3 m up at the origin; every height 1e-6 m up, see `clearance`); then the ball at U(±13.5)^2,
  2 m up, its horizontal velocity 5 N(0, 1)^2, the rest at rest (as dm_control's, the ball is placed
  after the search and not checked for contact).
- Episode: 1,000 steps (20 s simulated), never terminated.
"""

from __future__ import annotations

import os
from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.tasks.dm_control_suite import DmControlEnv, tolerance

WALK_SPEED, RUN_SPEED = 0.5, 5.0  # dm_control's _WALK_SPEED, _RUN_SPEED (m/s)
TIME_LIMIT = 20.0  # _DEFAULT_TIME_LIMIT (s): the floor's half-size is TIME_LIMIT * speed
HEIGHT_STEP = 0.01  # _find_non_contacting_height's rise per try (m)
REMOVED_GEOMS = ("wall_px", "wall_py", "wall_nx", "wall_ny", "terrain")


def sensor_values(model: mujoco.MjModel, *kinds: int) -> np.ndarray:
    """The `sensordata` indices of every sensor of the given types, in sensor order (dm_control's
    `_get_sensor_names`, which picks them by type, not by name)."""
    sensors = np.flatnonzero(np.isin(model.sensor_type, kinds))
    return np.concatenate([np.arange(model.sensor_adr[i], model.sensor_adr[i] + model.sensor_dim[i]) for i in sensors])


def compiled_without_rangefinders(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """`spec` compiled without its rangefinders, as every `make_model` but escape's leaves them out."""
    for sensor in [s for s in spec.sensors if s.type == mujoco.mjtSensor.mjSENS_RANGEFINDER]:
        spec.delete(sensor)
    return spec.compile()


class DmcQuadruped(DmControlEnv):
    """dm_control's `quadruped.Move(desired_speed)`; the two tasks below fix it."""
    costly_reset = True

    # DrQ-v2 films the quadruped with camera 2 ("y", tracking it from the side); the rest as every domain.
    pixel_defaults = {**DmControlEnv.pixel_defaults, "camera": 2}
    domain = "quadruped"
    control_timestep = 0.02  # dm_control's _CONTROL_TIMESTEP
    observation_shapes = (("egocentric_state", 44), ("torso_velocity", 3), ("torso_upright", 1), ("imu", 6),
                          ("force_torque", 24))
    desired_speed: float
    clearance: ClassVar[float] = 0.0  # added to every height the search tries (m): fetch's, below

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        """dm_control's `make_model(floor_size=TIME_LIMIT * speed)` for walk and run."""
        spec = mujoco.MjSpec.from_file(str(path))
        size = TIME_LIMIT * self.desired_speed
        spec.geom("floor").size = [size, size, 0.5]
        for name in REMOVED_GEOMS:
            spec.delete(spec.geom(name))
        spec.delete(spec.body("ball"))
        spec.delete(spec.site("target"))
        return compiled_without_rangefinders(spec)

    def __init__(self, xml: str | None = None):
        super().__init__(xml)
        model = self.mj_model
        # dm_control's egocentric_state reads the hinges, in joint order, picked by type.
        self._hinges = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
        self._root = model.joint("root").qposadr[0]
        self._imu = sensor_values(model, mujoco.mjtSensor.mjSENS_GYRO, mujoco.mjtSensor.mjSENS_ACCELEROMETER)
        self._force_torque = sensor_values(model, mujoco.mjtSensor.mjSENS_FORCE, mujoco.mjtSensor.mjSENS_TORQUE)

    def at_height(self, orientation: jax.Array, tries: jax.Array, xy: jax.Array | None = None) -> jax.Array:
        """qpos0 with the root at (x, y, tries x 1 cm) and `orientation` (x, y: `xy`, else 0)."""
        qpos = jnp.asarray(self.mj_model.qpos0, self._initial_data.qpos.dtype)
        xy = jnp.zeros(2) if xy is None else xy
        position = jnp.concatenate([xy, jnp.stack([tries * HEIGHT_STEP + self.clearance])]).astype(qpos.dtype)
        return qpos.at[self._root:self._root + 3].set(position).at[self._root + 3:self._root + 7].set(orientation)

    def lowest_free(self, orientation: jax.Array, xy: jax.Array | None = None) -> jax.Array:
        """dm_control's `_find_non_contacting_height`: qpos0 posed at the first height, from 0 up in 1 cm
        steps, where nothing touches."""
        orientation = orientation.astype(self._initial_data.qpos.dtype)
        tries = jax.lax.while_loop(lambda n: self.touching(self.at_height(orientation, n, xy)), lambda n: n + 1,
                                   jnp.zeros((), jnp.int32))
        return self.at_height(orientation, tries, xy)

    def initial_qpos_qvel(self, key):
        orientation = jax.random.normal(key, (4,))
        return self.lowest_free(orientation / jnp.linalg.norm(orientation)), jnp.zeros(self.mj_model.nv)

    def _torso_velocity(self, data):
        return self.sensor(data, "velocimeter")

    def _torso_upright(self, data):
        return self.body_xmat(data, "torso")[2, 2]

    def observations(self, data):
        dofs = self.mj_model.jnt_dofadr[self._hinges]
        egocentric = jnp.concatenate([data.qpos[self.mj_model.jnt_qposadr[self._hinges]], data.qvel[dofs], data.act])
        return {"egocentric_state": egocentric, "torso_velocity": self._torso_velocity(data),
                "torso_upright": self._torso_upright(data), "imu": data.sensordata[self._imu],
                "force_torque": jnp.arcsinh(data.sensordata[self._force_torque])}

    def reward(self, data, action, prev):
        upright = tolerance(self._torso_upright(data), (1.0, float("inf")), margin=2.0, value_at_margin=0.0,
                            sigmoid="linear")
        move = tolerance(self._torso_velocity(data)[0], (self.desired_speed, float("inf")),
                         margin=self.desired_speed, value_at_margin=0.5, sigmoid="linear")
        return upright * move


class DmcQuadrupedWalk(DmcQuadruped):
    task, desired_speed = "walk", WALK_SPEED


class DmcQuadrupedRun(DmcQuadruped):
    task, desired_speed = "run", RUN_SPEED


class DmcQuadrupedFetch(DmcQuadruped):
    """dm_control's `quadruped.Fetch`: the ball brought to the target, in the walled arena."""
    task = "fetch"
    # Upright, the body's toes touch the floor at exactly 0.52 m, where dm_control's float64 search
    # stops (its toes on the floor to float64's rounding, no contact). In float32 that height rounds
    # 2e-8 into the floor and the contact test flips on rounding (in MJX and in C MuJoCo alike: most
    # searches stopped 1 cm higher, the rest touched at the reset). A micrometre up keeps the toes clear.
    clearance = 1e-6
    observation_shapes = DmcQuadruped.observation_shapes + (("ball_state", 9), ("target_position", 3))

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        """dm_control's `make_model(walls_and_ball=True)`: the terrain and the rangefinders removed only."""
        spec = mujoco.MjSpec.from_file(str(path))
        spec.delete(spec.geom("terrain"))
        return compiled_without_rangefinders(spec)

    def __init__(self, xml: str | None = None):
        super().__init__(xml)
        model = self.mj_model
        self._ball_qpos = model.joint("ball_root").qposadr[0]
        self._ball_dof = model.joint("ball_root").dofadr[0]
        self._spawn = 0.9 * float(model.geom("floor").size[0])  # dm_control's spawn_radius
        self._arena = float(model.geom("floor").size[0]) * np.sqrt(2)  # the reward's margin
        self._reach = float(model.site("workspace").size[0] + model.geom("ball").size[0])
        self._target_radius = float(model.site("target").size[0])

    def initial_qpos_qvel(self, key):
        """Fetch's `initialize_episode`, its draws in its order: yaw, the body's x, y (searched for a free
        height with the ball at qpos0), the ball's x, y (2 m up) and horizontal velocity."""
        yaw_key, xy_key, ball_key, velocity_key = jax.random.split(key, 4)
        yaw = jax.random.uniform(yaw_key, (), minval=0.0, maxval=2 * jnp.pi)
        orientation = jnp.stack([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
        xy = jax.random.uniform(xy_key, (2,), minval=-self._spawn, maxval=self._spawn)
        qpos = self.lowest_free(orientation, xy)
        ball_xy = jax.random.uniform(ball_key, (2,), minval=-self._spawn, maxval=self._spawn)
        qpos = qpos.at[self._ball_qpos:self._ball_qpos + 3].set(jnp.append(ball_xy, 2.0).astype(qpos.dtype))
        qvel = jnp.zeros(self.mj_model.nv, qpos.dtype)
        velocity = 5 * jax.random.normal(velocity_key, (2,))
        return qpos, qvel.at[self._ball_dof:self._ball_dof + 2].set(velocity.astype(qpos.dtype))

    def _in_torso_frame(self, data, vectors):
        """Row vectors in the torso's frame (dm_control's `vectors.dot(torso_frame)`)."""
        return vectors @ self.body_xmat(data, "torso")

    def _ball(self, data):
        return data.xpos[self.mj_model.body("ball").id]

    def _site(self, data, name):
        return data.site_xpos[self.mj_model.site(name).id]

    def observations(self, data):
        torso = data.xpos[self.mj_model.body("torso").id]
        ball_dof, root_dof = self._ball_dof, self.mj_model.joint("root").dofadr[0]
        ball = jnp.stack([self._ball(data) - torso,
                          data.qvel[ball_dof:ball_dof + 3] - data.qvel[root_dof:root_dof + 3],
                          data.qvel[ball_dof + 3:ball_dof + 6]])
        return {**super().observations(data), "ball_state": self._in_torso_frame(data, ball).ravel(),
                "target_position": self._in_torso_frame(data, self._site(data, "target") - torso)}

    def reward(self, data, action, prev):
        upright = tolerance(self._torso_upright(data), (1.0, float("inf")), margin=2.0, value_at_margin=0.0,
                            sigmoid="linear")
        to_ball = jnp.linalg.norm((self._site(data, "workspace") - self._ball(data))[:2])
        reach = tolerance(to_ball, (0.0, self._reach), margin=self._arena, value_at_margin=0.0, sigmoid="linear")
        to_target = jnp.linalg.norm((self._site(data, "target") - self._ball(data))[:2])
        fetch = tolerance(to_target, (0.0, self._target_radius), margin=self._arena, value_at_margin=0.0,
                          sigmoid="linear")
        return upright * reach * (0.5 + 0.5 * fetch)
