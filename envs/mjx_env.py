"""Base class for tasks defined by an MJCF model and stepped by `mjx.step`.

A task is an MJCF file plus a short subclass: it names the XML, sets
`observation_size`, fills in four hooks (reset distribution, observation, reward,
termination) and either lists its discrete actions as named `action_bins` or
leaves actions continuous. This class does the MuJoCo plumbing: loading the file,
`put_model`, the initial `mjx.Data`, substeps, the action -> `ctrl` mapping,
ending an episode cleanly when the physics produces NaNs (or MuJoCo Warp runs out of a
buffer), MuJoCo's solver options (`opt`) and checking that the hooks return what the env API
promises (errors name the task).
"""

from __future__ import annotations

import abc
import contextvars
import copy
import os
import sys
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.assets import asset_path, load_model
from envs.core import Env, State
from envs.mjx_options import apply_opt, check_opt
from envs.mjx_warp import (BUFFER_OPTIONS, WarpBuffers, WarpWorlds, check_buffer_sizes, either_overflow,
                           import_mjx, put_model_and_data, require_warp)


class _MjxOnFirstUse:
    """`mujoco.mjx`, imported where a task first uses it, not where its module is imported: reading a
    task's options or action spec (`envs.registry.spec`) then loads no MJX, which loads MuJoCo Warp
    (seconds of start-up for the parent of per-GPU processes, `agents.processes`)."""

    def __getattr__(self, name: str):
        return getattr(sys.modules.get("mujoco.mjx") or import_mjx(), name)


mjx = _MjxOnFirstUse()  # tasks import it from here: `from envs.mjx_env import mjx`


def physics_steps(model: mjx.Model, data: mjx.Data, substeps: int) -> mjx.Data:
    """`substeps` calls of `mjx.step`: one env step's physics."""
    if substeps == 1:
        return mjx.step(model, data)
    return jax.lax.fori_loop(0, substeps, lambda _, d: mjx.step(model, d), data)


# The physics under `jax.jit` (impl="jax"). Called outside a program (a notebook, the README's
# first lines) MJX's step then runs as one XLA program rather than op by op, which compiled
# hundreds of small ones; inside a program JAX keeps its trace, so the programs of a run that
# step the env (training, judge, final evaluation) trace MJX once (XLA inlines the call).
compiled_physics_steps = jax.jit(physics_steps, static_argnums=2)
compiled_forward = jax.jit(lambda model, data: mjx.forward(model, data))


def without_constraints(model: mjx.Model) -> mjx.Model:
    """`model` with its constraint stage disabled: `mjx.forward` then skips collision and the solve,
    and every position and velocity it derives is the full forward's."""
    flags = model.opt.disableflags | mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    return model.tree_replace({"opt.disableflags": flags})


def _time_pinned(data: mjx.Data, model: mjx.Model) -> mjx.Data:
    """`data` with `time` in the timestep's dtype: a weakly typed `time` makes jit(mjx.step) compile
    twice (float64 under jax_enable_x64, else `time + timestep` changes dtype in a scan)."""
    return data.replace(time=jnp.asarray(data.time, model.opt.timestep.dtype))


# True while `envs.registry.spec` builds a task to read what it is (its actions, its observation):
# the task then skips `_put_on_device`, which loads MJX and MuJoCo Warp and starts JAX's backend.
SPEC_ONLY = contextvars.ContextVar("mjxsuite_spec_only", default=False)

ActionBins = Mapping[str, Sequence[float]]
IMPLS = ("jax", "warp")  # MJX's implementations an MjxEnv can step with (`impl=` in envs.make)


# Hooks under their former names, which a task would now set to no effect: refused by name.
_RENAMED_HOOKS = {"forward_on_reset": "reset_computes_derived", "forward_at_reset": "compute_derived_at_reset"}


class MjxEnv(Env):
    """An MJX-stepped environment. Subclasses set `xml` and `observation_size` and
    implement `initial_qpos_qvel`, `observation`, `reward` and `terminated`.

    Actions: with `action_bins` (a mapping from action name to a `ctrl` vector,
    in action-index order) the task is discrete and `num_actions = len(action_bins)`;
    without, it is continuous with `action_size = model.nu` and actions in [-1, 1]
    are scaled to each actuator's `ctrlrange`. Override `action_to_ctrl` for
    anything else.

    `info["nan"]` is 1.0 on the step where the physics, the observation or the reward became
    non-finite: that step
    terminates the episode, its reward is 0 and its observation is the previous
    one, so no NaN reaches a learner. Under impl="warp", `info["overflow"]` is nonzero
    on a step where MuJoCo Warp ran out of its contact pool (1.0: `nconmax`/`naconmax`),
    its constraint rows (2.0: `njmax`) or both (3.0): Warp dropped contacts or constraints,
    so that step is not physics and ends the episode the same way. A reset reports the code of
    its own Warp work (its forward pass, a task's settling steps); an auto-reset adds it to the
    code of the step whose end started that episode (`envs.wrappers`), so it is counted.
    """

    xml: str | os.PathLike  # a file in the suite's assets/ or a path
    observation_size: int
    action_bins: ActionBins | None = None
    n_substeps: int = 1  # mjx.step calls per env step (env dt = n_substeps * timestep)
    # Reset only sets qpos/qvel; mjx.step recomputes everything else before it
    # integrates. Tasks whose observation or reward at reset needs derived
    # quantities (site positions, sensors...) set this to run mjx.forward there.
    reset_computes_derived: bool = False
    # A batch of one stays a batch: one MJX env stepped unbatched was slower on a GPU than as a
    # batch of one (docs/results.md, "The GPU step"), and MuJoCo Warp steps batches of worlds.
    batch_of_one_as_scalars = False
    # observation="pixels" under impl="warp": missed rays show the model's skybox (else black).
    render_skybox = False

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        renamed = [f"`{old}` is now `{new}`" for old, new in _RENAMED_HOOKS.items() if old in vars(cls)]
        if renamed:
            raise TypeError(f"task {cls.__name__}: " + "; ".join(renamed))

    def __init__(self, xml: str | os.PathLike | None = None, action_bins: ActionBins | int | None = None):
        xml = xml if xml is not None else getattr(self, "xml", None)
        if xml is None:
            raise TypeError(f"task {self.name}: set the class attribute `xml` to an MJCF file (or pass xml=...)")
        try:
            self.xml_path = asset_path(xml)  # the MJCF file (envs.pixels adds a camera to it)
            self.mj_model: mujoco.MjModel = self.load_mj_model(self.xml_path)
        except (ValueError, FileNotFoundError) as err:
            raise type(err)(f"task {self.name}: {err}") from err
        if not isinstance(getattr(self, "observation_size", None), int):
            raise TypeError(f"task {self.name}: set the class attribute `observation_size` (an int)")
        self.opt: dict = {}  # MjOption fields set over the MJCF's (see `configured`)
        self._buffer_sizes: dict = dict.fromkeys(BUFFER_OPTIONS)  # Warp buffer overrides (None: from the model)
        self.warp_buffers: WarpBuffers | None = None  # under impl="warp": the sizes in use
        if not SPEC_ONLY.get():
            self._put_on_device("jax")

        if action_bins is not None:
            self.action_bins = action_bins
        if isinstance(self.action_bins, int):
            self.action_bins = uniform_bins(self.mj_model, self.action_bins, self.name)
        if self.action_bins is not None:
            self._bin_table = self._check_bins(self.action_bins)
            self.num_actions, self.action_size = len(self.action_bins), None
        else:
            self.num_actions, self.action_size = None, self.mj_model.nu

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        """The task's MjModel from its MJCF file; a task whose reference edits the file's model before
        compiling it (dm_control's quadruped drops walls and sensors) does the same here."""
        return load_model(path)

    def _put_on_device(self, impl: str) -> None:
        """The MJX model and the initial `mjx.Data` for MJX's implementation `impl`."""
        try:
            mjx_model: mjx.Model = mjx.put_model(self.mj_model, impl=impl)
        except NotImplementedError as err:
            raise NotImplementedError(
                f"task {self.name}: MJX (impl={impl!r}) cannot run this model{self._opt_note()}: {err} (geoms "
                'that never touch should have contype="0" conaffinity="0"; MJX checks collision pairs even with '
                "contacts disabled)"
            ) from err
        self.impl = impl
        if impl == "warp":
            self.warp_buffers = WarpBuffers.for_model(self.mj_model, **self._buffer_sizes)
            mjx_model, data = put_model_and_data(self.mj_model, mjx_model, self.warp_buffers)
        else:
            self.warp_buffers = None
            data = mjx.make_data(mjx_model, impl=impl)
        # The task's own options come before the Warp worlds take the model: they step this one
        # model and refuse any other (`WarpWorlds.run`).
        mjx_model = self.device_model(mjx_model)
        self.mjx_model = mjx_model
        self._initial_data: mjx.Data = _time_pinned(data, mjx_model)
        # Under impl="warp", the batch of worlds every step and forward runs on (None: impl="jax").
        self._warp: WarpWorlds | None = WarpWorlds(mjx_model, data, self.warp_buffers, self.name) \
            if impl == "warp" else None
        # A reset's own physics (cheetah's settling steps, the rejection test for touching geoms)
        # runs on MJX's JAX implementation under either impl: MuJoCo Warp offers MJX's step and
        # forward only (mjx.euler, mjx.collision, ... refuse a Warp model), and only inside the worlds.
        if impl == "warp":
            jax_model = mjx.put_model(self.mj_model, impl="jax")  # `device_model` options are Warp's here
            self.reset_model, self.reset_data = jax_model, _time_pinned(mjx.make_data(jax_model, impl="jax"), jax_model)
        else:
            self.reset_model, self.reset_data = mjx_model, self._initial_data

    def device_model(self, mjx_model: mjx.Model) -> mjx.Model:
        """The MJX model this task steps with, from MJX's `put_model` for the task's impl (`self.impl`):
        a task that needs an MJX option MuJoCo's model does not hold sets it here. The default
        changes nothing."""
        return mjx_model

    def _opt_note(self) -> str:
        return f" with opt={self.opt}" if self.opt else ""

    def configured(self, impl: str | None = None, opt: Mapping | None = None, nconmax: int | None = None,
                   naconmax: int | None = None, njmax: int | None = None) -> MjxEnv:
        """This task with MuJoCo's solver options `opt` (`mujoco.MjOption` fields, set over the
        MJCF's), stepped by MJX's implementation `impl` ("jax" or "warp"; default: as now), with
        MuJoCo Warp's buffers `nconmax` (contacts per env), `naconmax` (contacts of a whole batch)
        and `njmax` (constraint rows per env) in place of the model's defaults (`WarpBuffers`).
        The options go into a copy of the MjModel: the task and the envs sharing it are unchanged."""
        impl = self.impl if impl is None else impl
        if impl not in IMPLS:
            raise ValueError(f"task {self.name}: unknown impl {impl!r}; choose one of {IMPLS}")
        opt = check_opt(opt, f"task {self.name}")
        sizes = check_buffer_sizes({"nconmax": nconmax, "naconmax": naconmax, "njmax": njmax}, f"task {self.name}")
        given = {name: value for name, value in sizes.items() if value is not None}
        if given and impl != "warp":
            raise ValueError(f"task {self.name}: {sorted(given)} size MuJoCo Warp's buffers; they need impl='warp' "
                             f"(this env steps with impl={impl!r})")
        if not opt and not given and impl == self.impl:
            return self
        if impl == "warp":
            require_warp()
        task = copy.copy(self)
        if opt:
            task.mj_model = apply_opt(self.mj_model, opt)
            task.opt = {**self.opt, **opt}
        task._buffer_sizes = {**self._buffer_sizes, **given}
        task._put_on_device(impl)
        return task

    def with_impl(self, impl: str) -> MjxEnv:
        """This task stepped by MJX's implementation `impl`: "jax" (pure JAX, any device; the
        default) or "warp" (MuJoCo Warp, NVIDIA GPUs only, `pip install 'mjxsuite[warp]'`)."""
        return self.configured(impl=impl)

    @property
    def name(self) -> str:
        return type(self).__name__

    @property
    def costly_reset(self) -> bool:
        """Under MuJoCo Warp a reset runs Warp's forward pass, as many kernels as most of a step, so an
        auto-reset batch resets only where an episode ended (`envs.BatchedAutoReset`). A task whose reset
        runs physics or a rejection loop sets it True under either impl."""
        return self.impl == "warp"

    @property
    def action_low(self) -> np.ndarray:
        """Gymnasium's action space: each actuator's ctrlrange (-1 where it has none)."""
        limited = self.mj_model.actuator_ctrllimited.astype(bool)
        return np.where(limited, self.mj_model.actuator_ctrlrange[:, 0], -1.0).astype(np.float32)

    @property
    def action_high(self) -> np.ndarray:
        limited = self.mj_model.actuator_ctrllimited.astype(bool)
        return np.where(limited, self.mj_model.actuator_ctrlrange[:, 1], 1.0).astype(np.float32)

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
    def observation(self, data: mjx.Data) -> jax.Array:
        """A vector of shape (observation_size,)."""

    @abc.abstractmethod
    def reward(self, data: mjx.Data, action: jax.Array, prev: mjx.Data) -> jax.Array | tuple[jax.Array, dict]:
        """The reward for the transition prev --action--> data (a scalar), or (reward, terms) with
        terms a dict of scalars that `step` reports in `state.metrics` (Gymnasium's info names)."""

    @abc.abstractmethod
    def terminated(self, data: mjx.Data) -> jax.Array:
        """True when `data` ends the episode (a scalar bool)."""

    def filmed(self) -> MjxEnv:
        """This task as a camera observes it (`envs.make(..., observation="pixels")`): itself. A task
        whose step leaves out what MuJoCo Warp's renderer reads returns a copy that computes it."""
        return self

    def post_step(self, prev: mjx.Data, data: mjx.Data) -> mjx.Data:
        """Adjust the state after the physics step (e.g. clip velocities as a reference
        implementation does). The default changes nothing."""
        return data

    def compute_derived_at_reset(self, model: mjx.Model, data: mjx.Data) -> mjx.Data:
        """What reset runs with `reset_computes_derived` under impl="jax" (impl="warp" runs mjx.forward):
        `mjx.forward`. A task whose reset observation reads positions only may run the cheaper
        `mjx.kinematics` (no collisions, no constraint solve); the first step is the same either
        way, since `mjx.step` recomputes everything from qpos and qvel and only the integrator
        writes `qacc_warmstart`."""
        return compiled_forward(model, data)

    def compute_derived(self, data: mjx.Data, model: mjx.Model | None = None) -> mjx.Data:
        """`mjx.forward` of `data` (an env state's `pipeline_state`) with this task's model or
        `model`: everything MuJoCo derives from qpos and qvel (positions, contacts, forces). Under
        impl="warp" MuJoCo Warp's buffers that a batch shares are lent for the call."""
        model = self.mjx_model if model is None else model
        return self._warp.run(mjx.forward, model, data) if self._warp else compiled_forward(model, data)

    # True where a step leaves the derived positions of the new qpos (dm_control's legacy step): a
    # renderer then reads them as they are.
    positions_fresh_after_step = False

    def compute_positions(self, data: mjx.Data) -> mjx.Data:
        """What a renderer reads of `data.qpos`: the frames of bodies, geoms, cameras and lights.
        Where the step leaves them fresh (`positions_fresh_after_step`), `data` itself; otherwise
        `compute_derived` without the constraint stage, which skips collision and the solve that no
        position depends on."""
        if self.positions_fresh_after_step:
            return data
        return self.compute_derived(data, without_constraints(self.mjx_model))

    def action_to_ctrl(self, action: jax.Array) -> jax.Array:
        """Map an action to the model's `ctrl` vector (see the class docstring)."""
        if self.action_bins is not None:
            return jnp.asarray(self._bin_table)[action]
        low, high = self.mjx_model.actuator_ctrlrange.T
        limited = jnp.asarray(self.mj_model.actuator_ctrllimited, bool)
        # centre + a * half-range: exact for symmetric ranges (no rounding of a + 1)
        scaled = 0.5 * (high + low) + jnp.clip(action, -1.0, 1.0) * 0.5 * (high - low)
        return jnp.where(limited, scaled, action)

    # ---- per-episode markers ------------------------------------------------
    # dm_control moves some targets every episode by editing the model (reacher's target geom,
    # finger turn's target site: world-fixed, nothing collides with them). Here the episode's value
    # lives in `state.info` (its keys: `episode_info`) and is written into the derived positions
    # after each physics call, so every env of a batch, and every MuJoCo Warp world, steps the
    # task's one model, and the positions read are the ones the edited model would give.
    episode_info: tuple[str, ...] = ()

    def draw_episode(self, key: jax.Array) -> tuple[jax.Array, dict[str, jax.Array]]:
        """(the key left for the reset's state, this episode's `episode_info` values) drawn from
        `key` at reset. The default draws nothing."""
        return key, {}

    def draw_start(self, key: jax.Array) -> tuple[jax.Array, jax.Array, dict[str, jax.Array]]:
        """An episode's start, (qpos, qvel, its `episode_info` values): the episode's values
        (`draw_episode`), then the state (`initial_qpos_qvel`) from the key left. A task that draws
        both in one loop (dm_control's manipulator) overrides this, and so does one whose draw runs
        Warp's physics (dm_control's cheetah settles): its values then add "overflow", that work's
        `info["overflow"]` code."""
        key, episode = self.draw_episode(key)
        return (*self.initial_qpos_qvel(key), episode)

    def episode_model(self, model: mjx.Model, info: Mapping) -> mjx.Model:
        """`model` with the episode's edits that the physics must see (`info` holds `episode_info`): a
        colliding body dm_control moves each episode (manipulator insert_ball's cup), which a
        marker in the derived positions cannot stand for. Each env then steps its own model values
        (impl="jax" only, as `envs.randomize`'s). The default edits nothing."""
        return model

    def with_episode(self, data: mjx.Data, info: Mapping) -> mjx.Data:
        """`data` with the episode's markers (`info` holds `episode_info`) placed in its derived
        positions (geom_xpos, site_xpos, the sensors reading them). The default places nothing."""
        return data

    # ---- the env API --------------------------------------------------------
    def reset(self, key: jax.Array) -> State:
        return self.reset_with_model(key, self.mjx_model)

    def step(self, state: State, action: jax.Array) -> State:
        return self.step_with_model(state, action, self.mjx_model)

    # `envs.randomize` gives each env of a batch its own model values: it calls these two
    # with a model whose leaves differ per env (batched under vmap), so mjx.step runs
    # each env's physics; `reset`/`step` above pass the task's one model at no extra cost.
    def reset_with_model(self, key: jax.Array, model: mjx.Model) -> State:
        """`reset`, running `mjx.forward` (where the task asks for it) with `model`."""
        qpos, qvel, episode = self.draw_start(key)
        episode = dict(episode)
        drawn_overflow = episode.pop("overflow", jnp.zeros((), jnp.float32))  # the draw's own Warp work
        model = self.episode_model(model, episode)
        qpos = jnp.asarray(qpos, self._initial_data.qpos.dtype).reshape(self.mj_model.nq)
        qvel = jnp.asarray(qvel, self._initial_data.qvel.dtype).reshape(self.mj_model.nv)
        if not isinstance(qpos, jax.core.Tracer):  # called outside jit: placed (committed) as the rest of
            # the state is, as a step's output is, so the second step runs the physics the first compiled
            qpos, qvel = jax.device_put((qpos, qvel), self._initial_data.qpos.sharding)
        data = self._initial_data.replace(qpos=qpos, qvel=qvel)
        data = self._warp.without_shared(data) if self._warp else data
        if self.reset_computes_derived:
            # mjx.forward writes unit quaternions back into qpos; C's mj_forward (Gymnasium's
            # set_state) leaves qpos as drawn, and so do we (Ant-v5's reset observation shows it).
            derived = self.compute_derived(data, model) if self._warp else self.compute_derived_at_reset(model, data)
            data = derived.replace(qpos=data.qpos)
        data = self.with_episode(data, episode)
        obs = self.observation(data)
        if obs.shape != (self.observation_size,):
            raise ValueError(
                f"task {self.name}: observation() returned shape {obs.shape} at reset, "
                f"but observation_size is {self.observation_size}"
            )
        zero = jnp.zeros((), obs.dtype)
        # The reward terms' names and shapes, to start every metric at zero (State's structure is fixed).
        no_action = jnp.zeros((self.action_size,), obs.dtype) if self.action_size else jnp.zeros((), jnp.int32)
        _, terms = jax.eval_shape(lambda: self._reward_and_terms(data, no_action, data))
        metrics = {name: jnp.zeros(term.shape, obs.dtype) for name, term in terms.items()}
        overflow = either_overflow(drawn_overflow, self._overflow(data)).astype(obs.dtype)
        info = {"truncation": zero, "nan": zero, "overflow": overflow, **episode}
        return State(data, obs, zero, zero, metrics=metrics, info=info)

    def step_with_model(self, state: State, action: jax.Array, model: mjx.Model) -> State:
        """`step`, with `model` in place of the task's own `mjx_model`."""
        action = self.check_action(action)
        model = self.episode_model(model, state.info)
        prev = state.pipeline_state
        # In the model's dtype: a float32 bin table must not turn float64 ctrl (x64) into float32.
        data = prev.replace(ctrl=self.action_to_ctrl(action).astype(prev.ctrl.dtype))
        data = self._warp.run(self._physics, model, data) if self._warp else self._physics(model, data)
        data = self.with_episode(self.post_step(prev, data), state.info)
        overflow = self._overflow(data)
        obs, terminated = self.observation(data), self.terminated(data)
        reward, terms = self._reward_and_terms(data, action, prev)
        self._check_step_shapes(state.obs, obs, reward, terminated)
        # A task's observation or reward can be non-finite where the physics is not (a user's
        # reward dividing by zero): such a step ends its episode as non-finite physics does.
        finite = (jnp.isfinite(data.qpos).all() & jnp.isfinite(data.qvel).all() & jnp.isfinite(reward)
                  & (jnp.isfinite(obs).all() if jnp.issubdtype(obs.dtype, jnp.floating) else True))
        valid = finite & (overflow == 0)
        obs = jnp.where(valid, obs, state.obs)
        reward = jnp.where(valid, reward, 0.0).astype(obs.dtype)
        metrics = {**state.metrics, **{name: jnp.where(valid, term, 0.0).astype(obs.dtype) for name, term in terms.items()}}
        done = (terminated | ~valid).astype(obs.dtype)
        info = {**state.info, "nan": (~finite).astype(obs.dtype), "overflow": overflow.astype(obs.dtype)}
        return state.replace(pipeline_state=data, obs=obs, reward=reward, done=done, metrics=metrics, info=info)

    def _reward_and_terms(self, data: mjx.Data, action: jax.Array, prev: mjx.Data) -> tuple[jax.Array, dict]:
        """`reward()` as (reward, terms): a task may return its reward's terms beside it (a dict of
        scalars under Gymnasium's info names, e.g. "reward_forward"); they become `state.metrics`."""
        result = self.reward(data, action, prev)
        return result if isinstance(result, tuple) else (result, {})

    def _physics(self, model: mjx.Model, data: mjx.Data) -> mjx.Data:
        return physics_steps(model, data, self.n_substeps) if self._warp else compiled_physics_steps(model, data,
                                                                                                     self.n_substeps)

    def _overflow(self, data: mjx.Data) -> jax.Array:
        """info["overflow"]'s code for the step that gave `data` (0 under impl="jax")."""
        return self._warp.overflow(data) if self._warp else jnp.zeros((), jnp.float32)

    # ---- checks (run once, while tracing) ------------------------------------
    def _check_step_shapes(self, reset_obs, obs, reward, terminated) -> None:
        if obs.shape != reset_obs.shape:
            raise ValueError(
                f"task {self.name}: observation() returned shape {obs.shape} after a step "
                f"but {reset_obs.shape} at reset; it must always be ({self.observation_size},)"
            )
        for hook, value in (("reward", reward), ("terminated", terminated)):
            if jnp.shape(value) != ():
                raise ValueError(f"task {self.name}: {hook}() must return a scalar, got shape {jnp.shape(value)}")

    def _check_bins(self, bins: ActionBins) -> np.ndarray:
        """The bins as a (num_actions, nu) table, after checking each against ctrlrange (numpy: building
        a task starts no JAX backend, `envs.registry.spec`)."""
        model = self.mj_model
        if not isinstance(bins, Mapping) or not bins:
            raise TypeError(f"task {self.name}: action_bins must be a non-empty mapping name -> ctrl vector")
        table = []
        for bin_name, ctrl in bins.items():
            ctrl = np.atleast_1d(np.asarray(ctrl, np.float64))
            if ctrl.shape != (model.nu,):
                raise ValueError(
                    f"task {self.name}: action bin {bin_name!r} has {ctrl.size} ctrl values, "
                    f"but the model has {model.nu} actuator(s)"
                )
            for i, value in enumerate(ctrl):
                low, high = model.actuator_ctrlrange[i]
                if model.actuator_ctrllimited[i] and not low <= value <= high:
                    actuator = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) or f"#{i}"
                    raise ValueError(
                        f"task {self.name}: action bin {bin_name!r} sets actuator {actuator!r} to {value}, "
                        f"outside its ctrlrange [{low}, {high}]"
                    )
            table.append(ctrl)
        return np.stack(table).astype(np.float32)


def uniform_bins(model: mujoco.MjModel, count: int, task: str = "task") -> dict[str, tuple[float]]:
    """`count` evenly spaced ctrl values over the single actuator's ctrlrange, named by value."""
    if model.nu != 1 or not model.actuator_ctrllimited[0]:
        raise ValueError(f"task {task}: action_bins=<int> needs exactly one actuator with a ctrlrange")
    if count < 2:
        raise ValueError(f"task {task}: action_bins needs at least 2 bins, got {count}")
    low, high = model.actuator_ctrlrange[0]
    return {f"{v:+.3g}": (float(v),) for v in np.linspace(low, high, count)}
