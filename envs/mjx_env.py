"""Base class for tasks defined by an MJCF model and stepped by `mjx.step`.

A task names its XML and fills in five small hooks (reset distribution,
observation, reward, termination, action -> ctrl); this class does the
MuJoCo plumbing: loading the file, `put_model`, the initial `mjx.Data`,
substeps, and ending an episode cleanly when the physics produces NaNs.
"""

from __future__ import annotations

import abc
import contextlib
import io
import os

import jax
import jax.numpy as jnp
import mujoco

# MJX prints "Failed to import warp" when the optional warp-lang is absent; we use
# the pure-JAX implementation, so keep that message off the user's console.
with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx

from envs.assets import load_model
from envs.core import Env, State


class MjxEnv(Env):
    """An MJX-stepped environment. Subclasses set `xml` and implement the hooks below.

    `info["nan"]` is 1.0 on the step where the physics became non-finite: that step
    terminates the episode, its reward is 0 and its observation is the previous
    one, so no NaN reaches a learner.
    """

    xml: str | os.PathLike  # a file in the suite's assets/ or a path
    n_substeps: int = 1  # mjx.step calls per env step (env dt = n_substeps * timestep)
    # Reset only sets qpos/qvel; mjx.step recomputes everything else before it
    # integrates. Tasks whose observation or reward at reset needs derived
    # quantities (site positions, sensors...) set this to run mjx.forward there.
    forward_on_reset: bool = False

    def __init__(self, xml: str | os.PathLike | None = None):
        self.mj_model: mujoco.MjModel = load_model(xml if xml is not None else self.xml)
        self.mjx_model: mjx.Model = mjx.put_model(self.mj_model, impl="jax")
        data = mjx.make_data(self.mjx_model, impl="jax")
        # A weakly typed `time` makes jit(mjx.step) compile twice; pin its dtype.
        self._initial_data: mjx.Data = data.replace(time=jnp.asarray(data.time, jnp.float32))

    @property
    def dt(self) -> float:
        return float(self.mj_model.opt.timestep) * self.n_substeps

    def scene_model(self) -> mujoco.MjModel:
        """The model `envs.recording` draws."""
        return self.mj_model

    def scene_qpos(self, pipeline_state: mjx.Data) -> jax.Array:
        return pipeline_state.qpos

    # ---- task hooks -------------------------------------------------------
    @abc.abstractmethod
    def initial_qpos_qvel(self, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Draw the start of an episode."""

    @abc.abstractmethod
    def observation(self, data: mjx.Data) -> jax.Array: ...

    @abc.abstractmethod
    def reward(self, data: mjx.Data, action: jax.Array) -> jax.Array: ...

    @abc.abstractmethod
    def terminated(self, data: mjx.Data) -> jax.Array: ...

    @abc.abstractmethod
    def action_to_ctrl(self, action: jax.Array) -> jax.Array:
        """Map an action (index or vector) to the model's `ctrl` vector."""

    # ---- the env API --------------------------------------------------------
    def reset(self, key: jax.Array) -> State:
        qpos, qvel = self.initial_qpos_qvel(key)
        data = self._initial_data.replace(
            qpos=qpos.astype(self._initial_data.qpos.dtype), qvel=qvel.astype(self._initial_data.qvel.dtype)
        )
        if self.forward_on_reset:
            data = mjx.forward(self.mjx_model, data)
        obs = self.observation(data)
        zero = jnp.zeros((), obs.dtype)
        return State(data, obs, zero, zero, info={"truncation": zero, "nan": zero})

    def step(self, state: State, action: jax.Array) -> State:
        action = self.check_action(action)
        data = state.pipeline_state.replace(ctrl=self.action_to_ctrl(action))
        if self.n_substeps == 1:
            data = mjx.step(self.mjx_model, data)
        else:
            data = jax.lax.fori_loop(0, self.n_substeps, lambda _, d: mjx.step(self.mjx_model, d), data)
        finite = jnp.isfinite(data.qpos).all() & jnp.isfinite(data.qvel).all()
        obs = jnp.where(finite, self.observation(data), state.obs)
        reward = jnp.where(finite, self.reward(data, action), 0.0).astype(obs.dtype)
        done = (self.terminated(data) | ~finite).astype(obs.dtype)
        info = {**state.info, "nan": (~finite).astype(obs.dtype)}
        return state.replace(pipeline_state=data, obs=obs, reward=reward, done=done, info=info)
