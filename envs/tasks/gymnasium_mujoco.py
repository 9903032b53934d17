"""What Gymnasium's MuJoCo v5 tasks share, read from gymnasium/envs/mujoco/mujoco_env.py.

A task is Gymnasium's MJCF (loaded from the installed gymnasium package, never copied here)
stepped `frame_skip` times per env step, reset to the model's `qpos0` (and zero velocity)
plus noise, observing qpos and qvel with the first `skipped_qpos` positions (the
horizontal position, which no reward depends on) left out unless
`exclude_current_positions_from_observation=False`. The forward reward is the
torso's displacement over the env step divided by its duration, measured from qpos
before and after the step, as Gymnasium does; the control cost is the weight times
the sum of the squared controls (Gymnasium's action is the ctrl it sets: the env's
[-1, 1] action scaled to the actuators' ctrlrange, `data.ctrl` here).

MJX (impl "jax") and MuJoCo Warp solve constraints with CG or Newton only. Where Gymnasium's MJCF
names PGS (humanoid.xml and humanoidstandup.xml: `solver="PGS" iterations="50"`), the task steps
the model with `MODEL_SOLVER` (Newton) instead and keeps every other option of the MJCF: the one
change made to a Gymnasium model, made here and nowhere else (docs/tasks.md).

Each task reports the terms of its reward and Gymnasium's other `info` values
(`reward_forward`, `reward_ctrl`, `x_velocity`, `x_position`, ...) in `state.metrics`.
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.assets import gymnasium_asset
from envs.mjx_env import MjxEnv, mjx
from envs.ranges import check_fields

# The solver a Gymnasium MJCF that names PGS is stepped with: MJX's `put_model` raises
# NotImplementedError(mjSOL_PGS) and MuJoCo Warp's refuses it ("mjSOL_PGS is unsupported").
MODEL_SOLVER = mujoco.mjtSolver.mjSOL_NEWTON


class GymnasiumMujocoEnv(MjxEnv):
    """A Gymnasium MuJoCo v5 task (public as `envs.GymnasiumMujocoEnv`; docs/tasks.md, "A
    Gymnasium-style task"). Subclasses set the class attributes below, take a params dataclass
    (v5's constructor arguments; `RANGES` optional) and fill in `reward`, `terminated` and, where
    Gymnasium draws velocities differently, `initial_qvel_noise`. The params need
    `reset_noise_scale`; `exclude_current_positions_from_observation` and `ctrl_cost_weight` are
    read where present (`observation`, `control_cost`), and a task that reads contact forces may
    have `include_cfrc_ext_in_observation` and `contact_cost_weight` (`needs_cfrc_ext`).
    `envs.interop.gymnasium_equality` proves such a task step for step against Gymnasium's env."""

    gymnasium_id: ClassVar[str]  # Gymnasium's name of the task, e.g. "HalfCheetah-v5"
    xml_file: ClassVar[str]  # the MJCF file in gymnasium/envs/mujoco/assets
    frame_skip: ClassVar[int]  # MuJoCo steps per env step (Gymnasium's default for the task)
    skipped_qpos: ClassVar[int] = 1  # leading qpos left out by exclude_current_positions_from_observation
    velocity_clip: ClassVar[float | None] = None  # Hopper and Walker2d clip qvel to +-10 in the observation
    # Ant and Humanoid read each body's contact force `cfrc_ext` after a step (`cfrc_ext(data)`).
    # Gymnasium computes it with
    # mj_rnePostConstraint after mj_step; here MJX's `mjx.rne_postconstraint` after the step under
    # impl "jax", and MuJoCo Warp inside each forward pass, asked by opt.run_rne_postconstraint, under "warp".
    reads_contact_forces: ClassVar[bool] = False

    def __init__(self, params, xml: str | None = None):
        check_fields(params, getattr(params, "RANGES", {}))  # also when built without envs.make
        self.params = params
        self.n_substeps = self.frame_skip
        super().__init__(xml if xml is not None else gymnasium_asset(self.xml_file))
        # Gymnasium's init_qpos/init_qvel: what mj_resetData leaves (qpos0, zero velocity).
        self.init_qpos = self.mj_model.qpos0.copy()
        self.init_qvel = np.zeros(self.mj_model.nv)

    def _put_on_device(self, impl: str) -> None:
        # At construction (no `opt` given yet) a PGS model becomes MODEL_SOLVER's; an explicit
        # opt={"solver": "pgs"} is left for MJX to refuse.
        if self.mj_model.opt.solver == mujoco.mjtSolver.mjSOL_PGS and "solver" not in self.opt:
            self.mj_model.opt.solver = MODEL_SOLVER
        super()._put_on_device(impl)

    def device_model(self, mjx_model: mjx.Model) -> mjx.Model:
        if self.impl == "warp" and self.reads_contact_forces:
            return mjx_model.tree_replace({"opt._impl.run_rne_postconstraint": True})
        return mjx_model

    @property
    def needs_cfrc_ext(self) -> bool:
        """Whether a step computes cfrc_ext: a task that reads it, unless both its observation and its
        contact cost leave it out. Each of the two params fields counts only where the task has it:
        a task without `include_cfrc_ext_in_observation` is taken to observe the forces, one without
        `contact_cost_weight` to have no contact cost of that name."""
        p = self.params
        observed = getattr(p, "include_cfrc_ext_in_observation", True)
        costed = getattr(p, "contact_cost_weight", 0) != 0
        return self.reads_contact_forces and bool(observed or costed)

    # ---- what MuJoCo derives that Gymnasium's tasks read (MJX keeps some of it in `data._impl`) ----
    def cfrc_ext(self, data: mjx.Data) -> jax.Array:
        """Each body's external contact force, (nbody, 6) as MuJoCo's `data.cfrc_ext` (rotation then
        force, in the body's centre-of-mass frame). Computed after a step only for a task with
        `reads_contact_forces` (see `needs_cfrc_ext`); zero at reset, as Gymnasium's `mj_forward`
        leaves it."""
        return data._impl.cfrc_ext

    def cinert(self, data: mjx.Data) -> jax.Array:
        """Each body's inertia in its centre-of-mass frame, (nbody, 10) as MuJoCo's `data.cinert`."""
        return data._impl.cinert

    def post_step(self, prev: mjx.Data, data: mjx.Data) -> mjx.Data:
        if self.needs_cfrc_ext and self.impl == "jax":
            data = mjx.rne_postconstraint(self.mjx_model, data)
        return data

    @property
    def name(self) -> str:
        return self.gymnasium_id

    @property
    def _excludes_positions(self) -> bool:
        return getattr(self.params, "exclude_current_positions_from_observation", True)

    @property
    def observation_size(self) -> int:
        skipped = self.skipped_qpos if self._excludes_positions else 0
        return self.mj_model.nq - skipped + self.mj_model.nv

    # ---- reset --------------------------------------------------------------
    def initial_qpos_qvel(self, key):
        qpos_key, qvel_key = jax.random.split(key)
        scale = self.params.reset_noise_scale
        qpos = self.init_qpos + jax.random.uniform(qpos_key, self.init_qpos.shape, minval=-scale, maxval=scale)
        return qpos, self.init_qvel + self.initial_qvel_noise(qvel_key)

    def initial_qvel_noise(self, key: jax.Array) -> jax.Array:
        """Most v5 tasks add U(-reset_noise_scale, reset_noise_scale) to every velocity."""
        scale = self.params.reset_noise_scale
        return jax.random.uniform(key, self.init_qvel.shape, minval=-scale, maxval=scale)

    # ---- what the tasks compute alike ------------------------------------------
    def observation(self, data: mjx.Data) -> jax.Array:
        position = data.qpos[self.skipped_qpos:] if self._excludes_positions else data.qpos
        velocity = data.qvel if self.velocity_clip is None else jnp.clip(data.qvel, -self.velocity_clip, self.velocity_clip)
        return jnp.concatenate([position, velocity])

    def velocity(self, data: mjx.Data, prev: mjx.Data, index: int = 0) -> jax.Array:
        """qpos[index]'s change over the env step divided by its duration (Gymnasium's x_velocity)."""
        return (data.qpos[index] - prev.qpos[index]) / self.dt

    def control_cost(self, data: mjx.Data) -> jax.Array:
        return self.params.ctrl_cost_weight * jnp.sum(jnp.square(data.ctrl))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(params={self.params})"

