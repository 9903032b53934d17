"""The DeepMind Control Suite's finger (dm_control/suite/finger.py), stepped by MJX:
`envs.make("dmc-finger-spin")`, `-turn-easy` and `-turn-hard`. A planar two-link finger flicks a
free-spinning body on a hinge (gravity off, elliptic friction cones, 200 solver iterations; Euler,
timestep 0.01, 2 physics steps per control step: dt 0.02). The MJCF is dm_control's `finger.xml`,
read from the installed package.

- Action: Box(-1, 1, (2,)): proximal, distal motors.
- Observation, dm_control's order, every value from sensors: position (4) = proximal and distal
  angles, then the spinner tip's (x, z) relative to the hinge; velocity (3) = proximal, distal and
  hinge angular velocities; touch (2) = log1p of the fingertip's top and bottom touch sensors (an
  acceleration-stage sensor: the last substep's value, as in dm_control's legacy step). Turn adds
  target_position (2) = the target's (x, z) relative to the hinge and dist_to_target (1) = the
  tip-to-target distance less the target's radius (negative inside). Spin: 9, turn: 12.
- Reward: spin: 1 where the hinge turns at -15 rad/s or faster, else 0; turn: 1 where
  dist_to_target <= 0, else 0.
- Reset: dm_control's joint randomiser (proximal, distal uniform in their ranges, hinge
  U(-pi, pi)), drawn again until nothing touches (dm_control tries up to 1,000 times on `ncon > 0`;
  here a `lax.while_loop` on MJX's contact slots closer than their margin, without a cap), at rest.
  Turn first draws the target's angle U(-pi, pi) on the circle of radius 0.13 (cap1's half-length
  plus radius) around the hinge.
- Episode: 1,000 steps (20 s simulated), never terminated.

Model edits, as dm_control makes them in `initialize_episode`: spin sets the hinge's damping to 0.03
(from 0.5) and hides the target and tip sites (alpha 0); turn sets the target site's radius to 0.07
(easy) or 0.03 (hard). These are the same every episode: made once on the model. Turn's target
position is per episode: kept in `state.info["target"]` and written after each physics call into
the site's position and the frame sensor reading it (`with_episode`), where dm_control's edited
model puts them (a world site that collides with nothing): every env and every MuJoCo Warp world
steps the task's one model.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.mjx_env import mjx
from envs.tasks.dm_control_suite import DmControlEnv

EASY_TARGET_SIZE, HARD_TARGET_SIZE = 0.07, 0.03  # dm_control's _EASY_TARGET_SIZE, _HARD_TARGET_SIZE (m)
SPIN_VELOCITY = 15.0  # _SPIN_VELOCITY (rad/s)
SPIN_HINGE_DAMPING = 0.03  # Spin.initialize_episode's dof_damping['hinge']


class DmcFinger(DmControlEnv):
    """dm_control's finger domain: the joint randomiser's collision-free reset, the sensors' readings."""
    costly_reset = True

    domain = "finger"
    control_timestep = 0.02  # dm_control's _CONTROL_TIMESTEP

    def initial_qpos_qvel(self, key):
        return self.drawn_until_apart(key, self.joints_drawn), jnp.zeros(self.mj_model.nv)

    def _relative_to_hinge(self, data, sensor):
        """A frame sensor's (x, z) less the spinner's (dm_control's `tip_position`, `target_position`)."""
        return self.sensor(data, sensor)[jnp.array([0, 2])] - self.sensor(data, "spinner")[jnp.array([0, 2])]

    def observations(self, data):
        position = jnp.concatenate([self.sensor(data, "proximal"), self.sensor(data, "distal"),
                                    self._relative_to_hinge(data, "tip")])
        velocity = jnp.concatenate([self.sensor(data, name) for name in
                                    ("proximal_velocity", "distal_velocity", "hinge_velocity")])
        touch = jnp.log1p(jnp.concatenate([self.sensor(data, "touchtop"), self.sensor(data, "touchbottom")]))
        return {"position": position, "velocity": velocity, "touch": touch}


class DmcFingerSpin(DmcFinger):
    task = "spin"
    observation_shapes = (("position", 4), ("velocity", 3), ("touch", 2))

    def _put_on_device(self, impl: str) -> None:
        # dm_control sets these in every initialize_episode, before the reset's forward pass: set once.
        self.mj_model.dof_damping[self.mj_model.joint("hinge").dofadr[0]] = SPIN_HINGE_DAMPING
        for site in ("target", "tip"):
            self.mj_model.site_rgba[self.mj_model.site(site).id, 3] = 0.0
        super()._put_on_device(impl)

    def reward(self, data, action, prev):
        return (self.sensor(data, "hinge_velocity")[0] <= -SPIN_VELOCITY).astype(data.qpos.dtype)


class DmcFingerTurn(DmcFinger):
    """dm_control's `finger.Turn(target_radius)`; the two tasks below fix it."""

    observation_shapes = (("position", 4), ("velocity", 3), ("touch", 2), ("target_position", 2),
                          ("dist_to_target", 1))
    target_radius: float
    episode_info = ("target",)  # dm_control's per-episode edit, for envs.interop.dm_control

    def _put_on_device(self, impl: str) -> None:
        self.mj_model.site_size[self.mj_model.site("target").id, 0] = self.target_radius
        super()._put_on_device(impl)

    def draw_episode(self, key: jax.Array) -> tuple[jax.Array, dict]:
        key, angle_key = jax.random.split(key)
        angle = jax.random.uniform(angle_key, minval=-jnp.pi, maxval=jnp.pi)
        # The hinge's anchor is its body's position (the spinner turns in place); the radius is cap1's
        # half-length plus its radius, dm_control's `geom_size['cap1'].sum()`.
        spinner = self.mj_model.body("spinner").pos[[0, 2]]
        radius = float(self.mj_model.geom_size[self.mj_model.geom("cap1").id].sum())
        target = (spinner + radius * jnp.stack([jnp.sin(angle), jnp.cos(angle)])).astype(self.mjx_model.site_pos.dtype)
        return key, {"target": target}

    def with_episode(self, data: mjx.Data, info) -> mjx.Data:
        # A world site: its site_xpos is its site_pos, and the frame sensor on it reads that.
        site, sensor = self.mj_model.site("target").id, int(self.mj_model.sensor("target").adr[0])
        xz = jnp.array([0, 2])
        return data.replace(site_xpos=data.site_xpos.at[site, xz].set(info["target"]),
                            sensordata=data.sensordata.at[sensor + xz].set(info["target"]))

    def put_episode(self, physics, info) -> None:
        """dm_control's physics given this episode's edits (`info`: our `state.info` entries)."""
        physics.named.model.site_pos["target", ["x", "z"]] = info["target"]

    def get_episode(self, physics) -> dict:
        return {"target": physics.named.model.site_pos["target", ["x", "z"]].copy()}

    def _dist_to_target(self, data):
        to_target = self._relative_to_hinge(data, "target") - self._relative_to_hinge(data, "tip")
        return jnp.linalg.norm(to_target) - self.target_radius

    def observations(self, data):
        return {**super().observations(data), "target_position": self._relative_to_hinge(data, "target"),
                "dist_to_target": self._dist_to_target(data)}

    def reward(self, data, action, prev):
        return (self._dist_to_target(data) <= 0).astype(data.qpos.dtype)


class DmcFingerTurnEasy(DmcFingerTurn):
    task, target_radius = "turn_easy", EASY_TARGET_SIZE


class DmcFingerTurnHard(DmcFingerTurn):
    task, target_radius = "turn_hard", HARD_TARGET_SIZE
