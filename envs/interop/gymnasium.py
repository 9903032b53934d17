"""The suite's envs as Gymnasium envs: `envs.to_gymnasium(name)` for one env,
`envs.to_gymnasium(name, num_envs=N)` for a `gymnasium.vector.VectorEnv`.

Both run the jitted JAX env underneath: `reset` and `step` are each one jitted
call (compiled once per instance) whose results come back to the host as one
packed float32 array. The episode state stays on the device between calls.

Gymnasium semantics, checked against Gymnasium's CartPole-v1 in the tests:
- `terminated` is our `done` without `info["truncation"]`; `truncated` is True on
  the registry's `episode_length`-th step, also when that step terminates (as
  Gymnasium's `TimeLimit` does; the suite's own `info["truncation"]` stays 0 there).
- Observations are float32 numpy arrays; `observation_space` is an unbounded Box,
  as no env declares bounds; discrete envs take `Discrete(num_actions)` actions,
  continuous ones Gymnasium's own action space `Box(env.action_low, env.action_high)`
  (an MJX task's: its actuators' ctrlrange, as `gymnasium.make("HalfCheetah-v5")` has
  it), mapped to the env's [-1, 1] actions with `env.from_env_action` before the step.
- `reset(seed=s)` seeds the env's numpy generator, which draws every episode's JAX
  key: the same seed gives the same episodes.
- An action outside the action space raises a ValueError naming the env; `step`
  before the first `reset` raises `gymnasium.error.ResetNeeded`; `step` after an
  episode ended warns once, as Gymnasium's CartPole does, and goes on stepping.
- `info` is empty, except `info["nan"] = True` on a step where the physics became
  non-finite (the episode terminates there; see `envs.mjx_env`).
- The vector env resets sub-envs in the same step they end (the suite's
  `AutoReset`), which is Gymnasium's `AutoresetMode.SAME_STEP`: `obs` holds the new
  episode's first observation, and `info["final_obs"]` / `info["final_info"]` (with
  masks `_final_obs` / `_final_info`) the ended episode's last ones, laid out as
  `gymnasium.vector.SyncVectorEnv` lays them out.
- `render_mode="rgb_array"` (single env) draws the env's MJCF scene with
  `mujoco.Renderer`; headless machines need `MUJOCO_GL=egl` (or `osmesa`) set
  before Python starts.

Gymnasium is an optional dependency (`pip install "mjxsuite[gymnasium]"`); this
module is imported only when `envs.to_gymnasium` is called.
"""

from __future__ import annotations

from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np

try:
    import gymnasium
    from gymnasium import spaces
    from gymnasium.envs.registration import EnvSpec
    from gymnasium.vector import AutoresetMode
    from gymnasium.vector.utils import batch_space
except ImportError as err:  # gymnasium is an optional extra
    raise ImportError(
        'envs.to_gymnasium needs Gymnasium: pip install "mjxsuite[gymnasium]" '
        f"(which installs gymnasium==1.4.0); importing it failed with: {err}"
    ) from err

from envs.core import Env, State
from envs.registry import make
from envs.core import Wrapper
from envs.wrappers import AutoReset, TimeLimit, VmapWrapper

# Packed per-env step results after the observation: reward, terminated, truncated, nan.
_REWARD, _TERMINATED, _TRUNCATED, _NAN = range(4)
_STEP_SCALARS = 4


def to_gymnasium(name: str | Env, num_envs: int | None = None, *, render_mode: str | None = None, **overrides: Any):
    """`envs.make(name, **overrides)`, or an env instance (as `envs.to_brax` takes one: from
    `envs.make`, or a bare task with `episode_length=...`), as a `gymnasium.Env`, or with
    `num_envs` as a `gymnasium.vector.VectorEnv` of that many auto-resetting copies (see the
    module docs)."""
    if num_envs is None:
        return GymnasiumEnv(name, render_mode=render_mode, **overrides)
    if render_mode is not None:
        raise ValueError(f"env {name!r}: the vector env does not render; render_mode must be None, got {render_mode!r}")
    return GymnasiumVectorEnv(name, num_envs, **overrides)


def _time_limited(name: str | Env, overrides: dict) -> tuple[str, Env, bool]:
    """(label, the env with its time limit, whether it came by name) for `to_gymnasium`'s argument."""
    if isinstance(name, str):
        return name, make(name, **overrides), True
    label = repr(name)
    unknown = sorted(set(overrides) - {"episode_length"})
    if unknown:
        raise ValueError(f"to_gymnasium({label}): options {unknown} only apply to a registered name "
                         "(envs.make does them); for an env instance only episode_length is accepted")
    env, episode_length = name, overrides.get("episode_length")
    if isinstance(env, TimeLimit):
        env, episode_length = env.env, episode_length or env.episode_length
    layer = env
    while isinstance(layer, Wrapper):  # auto-reset, vmap or statistics: the adapter adds what it needs
        if type(layer).__module__ == TimeLimit.__module__:
            raise ValueError(f"to_gymnasium({label}): the env is already wrapped in {type(layer).__name__}; "
                             "pass the env from envs.make(name) or the bare task")
        layer = layer.env
    if episode_length is None:
        raise ValueError(f"to_gymnasium({label}): the env has no time limit; pass episode_length=...")
    return label, TimeLimit(env, episode_length), False


# ---- spaces and action checks, shared by the single and the vector env ----------
def _single_spaces(env: Env) -> tuple[spaces.Box, spaces.Space]:
    observation_space = spaces.Box(-np.inf, np.inf, (env.observation_size,), np.float32)
    if env.num_actions is not None:
        action_space = spaces.Discrete(env.num_actions)
    else:
        action_space = spaces.Box(env.action_low, env.action_high, (env.action_size,), np.float32)
    return observation_space, action_space


def _checked_action(name: str, env: Env, space: spaces.Space, action: Any, batch: tuple[int, ...]) -> np.ndarray:
    """`action` as the array the jitted step takes (int32 indices, or float32 vectors in the env's
    [-1, 1] mapped from Gymnasium's action space), after checking it lies in `space`; `batch` is
    () for one env, (num_envs,) for a vector env."""
    values = np.asarray(action)
    if env.num_actions is not None:
        ok = (
            values.shape == batch
            and np.issubdtype(values.dtype, np.integer)
            and bool(np.all((values >= 0) & (values < env.num_actions)))
        )
        converted = values.astype(np.int32) if ok else None
    else:
        shape = batch + (env.action_size,)
        ok = values.shape == shape and (np.issubdtype(values.dtype, np.floating) or np.issubdtype(values.dtype, np.integer))
        converted = values.astype(np.float32) if ok else None
        # Checked after the cast, so a float64 1.0000000001 that rounds to 1.0 passes.
        ok = ok and bool(np.all(np.isfinite(converted) & (converted >= space.low) & (converted <= space.high)))
        converted = env.from_env_action(converted).astype(np.float32) if ok else None
    if not ok:
        what = "integer" if env.num_actions is not None else "float"
        raise ValueError(
            f"env {name!r}: action {action!r} (shape {values.shape}, dtype {values.dtype}) is outside "
            f"the action space {space}; expected {what} values of shape {space.shape}"
        )
    return converted


def _episode_seed(np_random: np.random.Generator) -> np.uint32:
    """The seed of an episode's JAX key, drawn on the host from the env's numpy generator."""
    return np.uint32(np_random.integers(0, 2**32, dtype=np.uint64))


def _step_outputs(state_before: State, state: State, episode_length: int) -> jax.Array:
    """reward, terminated, truncated, nan of one env as float32, inside the jitted step."""
    truncation = state.info["truncation"] > 0
    terminated = (state.done > 0) & ~truncation
    # Gymnasium's TimeLimit truncates on the last step even when that step terminates.
    truncated = truncation | (state_before.info["steps"] + 1 >= episode_length)
    nan = state.info.get("nan", jnp.zeros(()))
    return jnp.stack([state.reward, terminated, truncated, nan]).astype(jnp.float32)


# ---- one env -----------------------------------------------------------------------
class GymnasiumEnv(gymnasium.Env):
    """One suite env as a `gymnasium.Env` (build it with `envs.to_gymnasium(name)`).

    `self.state` is the running episode's suite `State` (JAX arrays on the device).
    """

    # What the class can do (gymnasium.make reads it before building); each instance
    # narrows it to its env: envs without an MJCF scene do not render.
    metadata = {"render_modes": ["rgb_array"]}  # noqa: RUF012 (instances replace it)

    def __init__(self, name: str | Env, render_mode: str | None = None, **overrides: Any):
        self.name, self.env, by_name = _time_limited(name, overrides)  # TimeLimit(task): truncation
        self.episode_length: int = self.env.episode_length
        self.observation_space, self.action_space = _single_spaces(self.env)

        unwrapped = self.env.unwrapped
        can_render = hasattr(unwrapped, "scene_model") and hasattr(unwrapped, "scene_qpos")
        self._scene_model = unwrapped.scene_model() if can_render else None
        self.metadata = {"render_modes": ["rgb_array"] if can_render else []}
        if can_render:
            dt = getattr(unwrapped, "dt", None) or float(self._scene_model.opt.timestep)
            self.metadata["render_fps"] = 1.0 / dt
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"env {self.name!r}: render_mode {render_mode!r} is not supported; "
                f"choose one of {self.metadata['render_modes'] + [None]}"
            )
        self.render_mode = render_mode
        self._renderer = None
        self._scene_data = None

        # gymnasium.make(self.spec) (used by check_env and RecordVideo) builds the same env again;
        # an env instance has no name to build it from.
        self.spec = EnvSpec(
            id=f"mjxsuite/{name}",
            entry_point="envs.interop.gymnasium:GymnasiumEnv",
            kwargs={"name": name, **overrides},
            nondeterministic=False,
        ) if by_name else None

        self._reset = jax.jit(self._reset_and_observe)
        self._step = jax.jit(self._step_and_pack)
        self.state: State | None = None
        self._episode_over = False
        self._warned_episode_over = False

    def _reset_and_observe(self, seed: jax.Array) -> tuple[State, jax.Array]:
        state = self.env.reset(jax.random.PRNGKey(seed))
        return state, state.obs.astype(jnp.float32)

    def _step_and_pack(self, state: State, action: jax.Array) -> tuple[State, jax.Array]:
        stepped = self.env.step(state, action)
        outputs = _step_outputs(state, stepped, self.episode_length)
        return stepped, jnp.concatenate([stepped.obs.astype(jnp.float32), outputs])

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        if options:
            raise ValueError(f"env {self.name!r}: reset takes no options, got {sorted(options)}")
        self.state, obs = self._reset(_episode_seed(self.np_random))
        self._episode_over = False
        self._warned_episode_over = False
        return np.array(obs), {}

    def step(self, action: Any):
        if self.state is None:
            raise gymnasium.error.ResetNeeded(f"env {self.name!r}: call reset() before step()")
        action = _checked_action(self.name, self.env, self.action_space, action, ())
        if self._episode_over and not self._warned_episode_over:
            gymnasium.logger.warn(
                f"env {self.name!r}: step() called after the episode ended (terminated or truncated); "
                "call reset() first -- further steps are undefined behaviour."
            )
            self._warned_episode_over = True
        self.state, packed = self._step(self.state, action)
        packed = np.array(packed)  # the one transfer to the host
        size = self.env.observation_size
        obs, scalars = packed[:size], packed[size:]
        terminated, truncated = bool(scalars[_TERMINATED]), bool(scalars[_TRUNCATED])
        self._episode_over = terminated or truncated
        info = {"nan": True} if scalars[_NAN] else {}
        return obs, float(scalars[_REWARD]), terminated, truncated, info

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn(
                f"env {self.name!r}: render() called without a render_mode; "
                f"build it with envs.to_gymnasium({self.name!r}, render_mode='rgb_array')"
            )
            return None
        if self.state is None:
            raise gymnasium.error.ResetNeeded(f"env {self.name!r}: call reset() before render()")
        import mujoco

        if self._renderer is None:
            model = self._scene_model
            try:
                self._renderer = mujoco.Renderer(model, model.vis.global_.offheight, model.vis.global_.offwidth)
            except Exception as err:  # no usable OpenGL: MuJoCo raises FatalError, ImportError, AttributeError...
                raise RuntimeError(
                    f"env {self.name!r}: render_mode='rgb_array' needs an OpenGL context and MuJoCo could not "
                    f"create one ({type(err).__name__}: {err}). On a machine without a display, set "
                    "MUJOCO_GL=egl (or MUJOCO_GL=osmesa) in the environment before starting Python."
                ) from err
            self._scene_data = mujoco.MjData(model)
        qpos = self.env.unwrapped.scene_qpos(self.state.pipeline_state)
        self._scene_data.qpos[:] = np.asarray(qpos)
        mujoco.mj_kinematics(self._scene_model, self._scene_data)
        self._renderer.update_scene(self._scene_data)
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __repr__(self) -> str:
        return f"GymnasiumEnv({self.name!r})"


# ---- a batch of envs ---------------------------------------------------------------
class GymnasiumVectorEnv(gymnasium.vector.VectorEnv):
    """`num_envs` copies of a suite env, stepped together by one jitted `jax.vmap` call
    (build it with `envs.to_gymnasium(name, num_envs=N)`). Same-step autoreset."""

    metadata: ClassVar[dict[str, Any]] = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}

    def __init__(self, name: str | Env, num_envs: int, **overrides: Any):
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"env {name!r}: num_envs must be a positive int, got {num_envs!r}")
        self.name, self.env, _ = _time_limited(name, overrides)
        self.num_envs = num_envs
        self.episode_length: int = self.env.episode_length
        self._batched = VmapWrapper(AutoReset(self.env), num_envs)
        self.single_observation_space, self.single_action_space = _single_spaces(self.env)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.render_mode = None

        self._reset = jax.jit(self._reset_and_observe)
        self._step = jax.jit(self._step_and_pack)
        self.state: State | None = None

    def _reset_and_observe(self, seed: jax.Array) -> tuple[State, jax.Array]:
        state = self._batched.reset(jax.random.PRNGKey(seed))
        return state, state.obs.astype(jnp.float32)

    def _step_and_pack(self, state: State, actions: jax.Array) -> tuple[State, jax.Array]:
        stepped = self._batched.step(state, actions)
        outputs = jax.vmap(lambda before, after: _step_outputs(before, after, self.episode_length))(state, stepped)
        final_obs = stepped.info["final_obs"].astype(jnp.float32)
        return stepped, jnp.concatenate([stepped.obs.astype(jnp.float32), final_obs, outputs], axis=1)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None and not isinstance(seed, (int, np.integer)):
            raise TypeError(f"env {self.name!r}: the vector env takes one int seed, got {seed!r}")
        super().reset(seed=seed)
        if options:
            raise ValueError(f"env {self.name!r}: reset takes no options, got {sorted(options)}")
        self.state, obs = self._reset(_episode_seed(self.np_random))
        return np.array(obs), {}

    def step(self, actions: Any):
        if self.state is None:
            raise gymnasium.error.ResetNeeded(f"env {self.name!r}: call reset() before step()")
        actions = _checked_action(self.name, self.env, self.action_space, actions, (self.num_envs,))
        self.state, packed = self._step(self.state, actions)
        packed = np.array(packed)  # the one transfer to the host
        size = self.env.observation_size
        obs, final_obs, scalars = packed[:, :size], packed[:, size : 2 * size], packed[:, 2 * size :]
        rewards = scalars[:, _REWARD].astype(np.float64)  # float64, as SyncVectorEnv returns
        terminated, truncated = scalars[:, _TERMINATED] > 0, scalars[:, _TRUNCATED] > 0
        return obs.copy(), rewards, terminated, truncated, self._infos(final_obs, terminated | truncated, scalars[:, _NAN] > 0)

    def _infos(self, final_obs: np.ndarray, ended: np.ndarray, nan: np.ndarray) -> dict[str, Any]:
        """SyncVectorEnv's SAME_STEP layout: the ended episodes' last obs and info, with masks."""
        if not ended.any():
            return {}
        last_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(ended):
            last_obs[i] = final_obs[i].copy()
        final_info = {"nan": nan.copy(), "_nan": nan.copy()} if nan.any() else {}
        return {"final_obs": last_obs, "_final_obs": ended.copy(), "final_info": final_info, "_final_info": ended.copy()}

    def __repr__(self) -> str:
        return f"GymnasiumVectorEnv({self.name!r}, num_envs={self.num_envs})"
