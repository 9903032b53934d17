"""The DeepMind Control Suite's LQR tasks (dm_control/suite/lqr.py, EXTRA), stepped by MJX:
`envs.make("dmc-lqr-lqr-2-1")` and `envs.make("dmc-lqr-lqr-6-2")`. A chain of n spheres, each on a slide
joint (along y) riding on the one before, each joint a spring of its own stiffness and no damping,
the first m joints motorised (Euler, timestep 0.03, one physics step per control step; constraints
disabled): lqr_2_1 has n = 2, m = 1; lqr_6_2 n = 6, m = 2. The controller must bring the chain to
rest at zero at a quadratic cost. The MJCF is dm_control's `_make_model(n, m)`: `lqr.xml`, read from
the installed package, with the chain added as its XML edits add it (`lqr_spec`; equal to
dm_control's model in every number and name for the same stiffness).

- Action: the m motors' forces. dm_control's actuators have no ctrlrange, so its action spec is
  unbounded (+-mjMAXVAL) and nothing clips: `env.step` applies any action as the force, as
  dm_control does. The Gymnasium space and the agents' actions are [-1, 1] (the suite's rule for an
  actuator without a ctrlrange: `MjxEnv.action_low`), which bounds what a trained policy can push.
- Observation (2n), dm_control's order: position = qpos, velocity = qvel.
- Reward: 1 - (|qpos|^2 / 2 + 0.1 |ctrl|^2 / 2) (dm_control's `LQRLevel.get_reward`, control cost
  coefficient 0.1): at most 1, 0 at a reset without control, unbounded below.
- Reset: qpos = sqrt(2) u with u a uniformly random unit vector (N(0, 1)^n normalised), at rest.
- Termination, as dm_control's (its only task that ends early): when the state's norm |(qpos, qvel)|
  is below 1e-6 after a step, the episode ends with discount 0 (dm_control's `get_termination`
  returns 0.0: a LAST step of discount 0).
- Episode: dm_control's time limit is infinite. Here 1,000 control steps (30 s simulated, the
  length of every other dm_control task's episode), truncated by `envs.make`'s TimeLimit; the judge
  (`returns_on_dm_control`) stops dm_control's episodes there too.

Each joint's stiffness is drawn U(15, 25) (dm_control's damping U(0, 0) is 0). dm_control draws it
once per env *instance*, when `_make_model` writes the XML (from the env's RandomState, before any
reset): every episode of one dm_control env has the same springs. Here it is drawn per *episode*
from the reset key, kept in `state.info["stiffness"]` and put in the env's model by `episode_model`,
so every env of a batch (and every episode) has springs of its own: the same distribution per
episode, a different one over an env's episodes. The MJCF's model (`env.mj_model`, what is drawn and
what `mjx_model` holds) has 20, the range's middle, in every joint; no episode steps it. Each env
then steps its own model values (`jnt_stiffness`), under impl="jax" only: MuJoCo Warp's worlds step
one model, so impl="warp" is refused.
"""

from __future__ import annotations

import os
from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.mjx_env import mjx
from envs.tasks.dm_control_suite import DmControlEnv

STIFFNESS_RANGE = (15.0, 25.0)  # dm_control's _make_model stiffness_range (its damping_range is (0, 0))
CONTROL_COST_COEF = 0.1  # dm_control's _CONTROL_COST_COEF
TERMINAL_TOL = 1e-6  # dm_control's LQRLevel._TERMINAL_TOL: the state norm below which an episode ends


def lqr_spec(path: os.PathLike, n_bodies: int, n_actuators: int, stiffness) -> mujoco.MjSpec:
    """dm_control's `lqr._make_model(n_bodies, n_actuators)` on `lqr.xml`, with the joints' `stiffness`
    (one per body) in place of its draws: body_i 0.25 m along x from its parent (body_0 also 0.1 m
    up), each with slide joint_i (the MJCF's default: along y) of that stiffness and damping 0,
    sphere geom_i and site_i; motor_i on joint_i for the first `n_actuators`; spatial tendon_i from
    site_i to site_{i+1} (dm_control draws them, the physics ignores them: no stiffness, no limit)."""
    if not 1 <= n_actuators <= n_bodies or len(stiffness) != n_bodies:
        raise ValueError(f"lqr: {n_bodies} bodies, {n_actuators} actuators and {len(stiffness)} stiffnesses")
    spec = mujoco.MjSpec.from_file(str(path))
    parent = spec.worldbody
    for body in range(n_bodies):
        child = parent.add_body(name=f"body_{body}", pos=[0.25, 0.0, 0.1 if body == 0 else 0.0])
        child.add_joint(name=f"joint_{body}", stiffness=float(stiffness[body]), damping=0.0)
        child.add_geom(name=f"geom_{body}")
        child.add_site(name=f"site_{body}")
        if body < n_actuators:
            spec.add_actuator(name=f"motor_{body}", target=f"joint_{body}", trntype=mujoco.mjtTrn.mjTRN_JOINT)
        if body < n_bodies - 1:
            tendon = spec.add_tendon(name=f"tendon_{body}")
            tendon.wrap_site(f"site_{body}")
            tendon.wrap_site(f"site_{body + 1}")
        parent = child
    return spec


class DmcLqr(DmControlEnv):
    """dm_control's `LQRLevel` on `_make_model(n_bodies, n_actuators)` (the module docstring); the
    tasks below fix the two sizes."""

    domain = "lqr"
    n_bodies: ClassVar[int]
    n_actuators: ClassVar[int]
    per_env_model = "its joints' stiffness (jnt_stiffness) is drawn"
    episode_info = ("stiffness",)  # the joints' stiffness, dm_control's model edit, for envs.interop.dm_control

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        middle = np.full(self.n_bodies, sum(STIFFNESS_RANGE) / 2)
        return lqr_spec(path, self.n_bodies, self.n_actuators, middle).compile()

    # ---- the episode's springs ----------------------------------------------------------
    def draw_episode(self, key):
        key, stiffness_key = jax.random.split(key)
        stiffness = jax.random.uniform(stiffness_key, (self.n_bodies,), self.mjx_model.jnt_stiffness.dtype,
                                       *STIFFNESS_RANGE)
        return key, {"stiffness": stiffness}

    def episode_model(self, model: mjx.Model, info) -> mjx.Model:
        # Every joint is a body's slide joint, in body order: the stiffness vector is the model's row.
        return model.replace(jnt_stiffness=jnp.asarray(info["stiffness"], model.jnt_stiffness.dtype))

    def put_episode(self, physics, info) -> None:
        physics.model.jnt_stiffness[:] = info["stiffness"]

    def get_episode(self, physics) -> dict:
        return {"stiffness": np.array(physics.model.jnt_stiffness)}

    # ---- dm_control's LQRLevel -----------------------------------------------------------
    def initial_qpos_qvel(self, key):
        unit = jax.random.normal(key, (self.n_bodies,))
        return np.sqrt(2) * unit / jnp.linalg.norm(unit), jnp.zeros(self.n_bodies)

    def observations(self, data):
        return {"position": data.qpos, "velocity": data.qvel}

    def reward(self, data, action, prev):
        state_cost = 0.5 * jnp.dot(data.qpos, data.qpos)
        control_cost = 0.5 * jnp.dot(data.ctrl, data.ctrl)  # dm_control's physics.control(): the step's ctrl
        return 1 - (state_cost + CONTROL_COST_COEF * control_cost)

    def terminated(self, data):
        # dm_control's physics.state_norm(): the norm of (qpos, qvel, act); no activations here.
        return jnp.linalg.norm(jnp.concatenate([data.qpos, data.qvel])) < TERMINAL_TOL


class DmcLqrLqr21(DmcLqr):
    task, n_bodies, n_actuators = "lqr_2_1", 2, 1
    observation_shapes = (("position", 2), ("velocity", 2))


class DmcLqrLqr62(DmcLqr):
    task, n_bodies, n_actuators = "lqr_6_2", 6, 2
    observation_shapes = (("position", 6), ("velocity", 6))
