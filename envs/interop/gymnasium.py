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

Gymnasium's registry (`envs.interop.gymnasium_ids` registers the ids) builds its envs here:
- `make_env` (the ids' `entry_point`): one env, `gymnasium.make("mjxsuite/Hopper-v5")`, the
  numpy-on-the-host `envs.to_gymnasium` adapter; Gymnasium's `make` adds its `TimeLimit`;
- `make_vector_env` (the `vector_entry_point`): `gymnasium.make_vec("mjxsuite/Hopper-v5",
  num_envs=N)`, a `JaxVectorEnv`: all N envs stepped by one jitted call, JAX arrays in and out,
  which stay on the device (Gymnasium's `JaxToTorch` / `JaxToNumpy` convert them through DLPack).

Gymnasium's keyword arguments keep their names (`ctrl_cost_weight`, `reset_noise_scale`, ...: our
tasks' options are v5's reward, termination, reset and observation arguments; v5's `xml_file`,
`frame_skip` and camera arguments are refused, `V5_NOT_TAKEN`), `max_episode_steps` is the time
limit, and the suite's own options pass the same way (`impl="warp"`, `opt={...}`).

`JaxVectorEnv` autoresets as `gymnasium.vector.SyncVectorEnv` over Gymnasium's env does in the
mode chosen with `autoreset_mode`:
- `AutoresetMode.NEXT_STEP` (the default, as Gymnasium's): the step after an episode ended
  ignores that env's action and returns its new episode's first observation, reward 0, not
  terminated, not truncated; `info` is `{}`.
- `AutoresetMode.SAME_STEP`: an ended env starts its new episode in the same step (`obs` is its
  first observation); `info["final_obs"]` holds the ended episodes' last observations, in the
  rows where the mask `info["_final_obs"]` is True (other rows are 0), and `info["final_info"]`
  / `info["_final_info"]` as SyncVectorEnv lays them out. Unlike SyncVectorEnv's, these keys are
  there on every step (masks all False when nothing ended) and `final_obs` is one (N, obs) array,
  not a numpy object array of rows: a key set that depends on the data would cost a device-to-host
  transfer every step, and an object array cannot pass DLPack.

Rewards are float32 (SyncVectorEnv's are float64): JAX computes in float32 unless x64 is enabled.
Observations are float32, in a float32 Box with the bounds of Gymnasium's space (a MuJoCo task's
is float64 in Gymnasium). Continuous actions are in Gymnasium's action space (the actuators'
ctrlrange); values outside it are clipped to it, as MuJoCo clamps Gymnasium's ctrl; their shape
is checked, their values are not (that would cost a device-to-host transfer every step).

Gymnasium is an optional dependency (`pip install "mjxsuite[gymnasium]"`); this
module is imported only when `envs.to_gymnasium` is called or Gymnasium makes one of our ids.
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
    from gymnasium.vector import AutoresetMode, VectorEnv
    from gymnasium.vector.utils import batch_space
except ImportError as err:  # gymnasium is an optional extra
    raise ImportError(
        'envs.to_gymnasium needs Gymnasium: pip install "mjxsuite[gymnasium]" '
        f"(which installs gymnasium==1.4.0); importing it failed with: {err}"
    ) from err

from envs.compile_cache import enable_unless_off
from envs.core import Env, State
from envs.registry import make
from envs.core import Wrapper
from envs.wrappers import TRANSITION_INFO, AutoReset, TimeLimit, VmapWrapper

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
def _image_shape(env: Env) -> tuple[int, ...] | None:
    """The (height, width, channels) of a task that observes camera images (`observation="pixels"`:
    uint8 frames, kept as they are), else None (a float32 vector)."""
    shape = getattr(env, "observation_shape", None)
    return None if shape is None else tuple(shape)


def _observed(env: Env, obs: jax.Array) -> jax.Array:
    """An observation as Gymnasium gets it: camera frames as uint8 images, vectors as float32."""
    return obs if _image_shape(env) is not None else obs.astype(jnp.float32)


def _pack(env: Env, obs: jax.Array, *rest: jax.Array):
    """A step's arrays in one float32 row per env, one transfer to the host; camera frames stay
    uint8 beside the row (`_unpack`)."""
    if _image_shape(env) is not None:
        return obs, jnp.concatenate([r.astype(jnp.float32) for r in rest], axis=-1)
    return jnp.concatenate([obs.astype(jnp.float32), *[r.astype(jnp.float32) for r in rest]], axis=-1)


def _unpack(env: Env, packed, sizes: tuple[int, ...]) -> list[np.ndarray]:
    """`_pack`'s arrays back, on the host: the observation, then the row's parts of `sizes`."""
    if isinstance(packed, tuple):
        obs, row = np.array(packed[0]), np.array(packed[1])
        parts = [obs]
    else:
        row, parts = np.array(packed), []
    edges = np.cumsum((0,) + sizes)
    return parts + [row[..., a:b] for a, b in zip(edges[:-1], edges[1:])] + [row[..., edges[-1]:]]


def _single_spaces(env: Env) -> tuple[spaces.Box, spaces.Space]:
    image = _image_shape(env)
    observation_space = (spaces.Box(0, 255, image, np.uint8) if image is not None
                         else spaces.Box(-np.inf, np.inf, (env.observation_size,), np.float32))
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
        return state, _observed(self.env, state.obs)

    def _step_and_pack(self, state: State, action: jax.Array) -> tuple[State, jax.Array]:
        stepped = self.env.step(state, action)
        return stepped, _pack(self.env, stepped.obs, _step_outputs(state, stepped, self.episode_length))

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
        sizes = () if _image_shape(self.env) is not None else (self.env.observation_size,)
        obs, scalars = _unpack(self.env, packed, sizes)[-2:]  # the one transfer to the host
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
        return state, _observed(self.env, state.obs)

    def _step_and_pack(self, state: State, actions: jax.Array) -> tuple[State, jax.Array]:
        stepped = self._batched.step(state, actions)
        outputs = jax.vmap(lambda before, after: _step_outputs(before, after, self.episode_length))(state, stepped)
        if _image_shape(self.env) is not None:  # the frames and the final frames side by side, uint8
            return stepped, (jnp.stack([stepped.obs, stepped.info["final_obs"]]), outputs)
        return stepped, _pack(self.env, stepped.obs, stepped.info["final_obs"], outputs)

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
        if _image_shape(self.env) is not None:
            frames, scalars = _unpack(self.env, packed, ())
            obs, final_obs = frames
        else:
            size = self.env.observation_size
            obs, final_obs, scalars = _unpack(self.env, packed, (size, size))  # the one transfer to the host
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


# ---- Gymnasium's registry: the ids' entry points ------------------------------------
# The single env's own time limit: Gymnasium's `make` wraps it in its TimeLimit (max_episode_steps),
# which must be the one that truncates, also when it is longer than the task's default.
_NO_LIMIT = 2**31 - 1


# v5's constructor arguments of the MuJoCo base env that the tasks do not take: each task keeps
# Gymnasium's MJCF and frame skip, the model its physics is proven equal to Gymnasium's on
# (docs/tasks.md); rendering is `render_mode="rgb_array"` and the pixel options.
V5_NOT_TAKEN = ("xml_file", "frame_skip", "default_camera_config", "camera_id", "camera_name", "max_geom",
                "visual_options")


def _suite_options(task: str, max_episode_steps: int | None, kwargs: dict[str, Any]) -> dict[str, Any]:
    overrides = dict(kwargs)
    refused = [name for name in V5_NOT_TAKEN if name in overrides]
    if refused:
        given = ", ".join(f"{name}={overrides[name]!r}" for name in refused)
        raise ValueError(f"env {task!r} through Gymnasium: {given} is not taken. The tasks take v5's reward, "
                         f"termination, reset and observation arguments (envs.options({task!r}) lists them) but "
                         f"not {', '.join(V5_NOT_TAKEN)}: each keeps v5's own MJCF and frame skip, the ones its "
                         "physics is proven equal to Gymnasium's on; drop the argument")
    if "episode_length" in overrides:
        raise ValueError(f"env {task!r} through Gymnasium: pass max_episode_steps=..., not episode_length "
                         f"(got episode_length={overrides['episode_length']!r})")
    if max_episode_steps is not None:
        overrides["episode_length"] = max_episode_steps
    return overrides


def observation_space(task: str, env: Env) -> spaces.Box:
    """Gymnasium's observation space of the task, as float32: CartPole-v1's and Acrobot-v1's bounds
    (from our rules, equal to Gymnasium's at the defaults), unbounded for every other task."""
    if _image_shape(env) is not None:
        return spaces.Box(0, 255, _image_shape(env), np.uint8)
    size = env.observation_size
    low, high = np.full(size, -np.inf, np.float32), np.full(size, np.inf, np.float32)
    rules = getattr(env.unwrapped, "rules", None)
    if task == "cartpole":
        high = np.array([rules.x_threshold * 2, np.inf, rules.theta_threshold * 2, np.inf], np.float32)
        low = -high
    elif task == "acrobot":
        high = np.array([1.0, 1.0, 1.0, 1.0, rules.max_vel_1, rules.max_vel_2], np.float32)
        low = -high
    return spaces.Box(low, high, (size,), np.float32)


def action_space(env: Env) -> spaces.Space:
    if env.num_actions is not None:
        return spaces.Discrete(env.num_actions)
    return spaces.Box(env.action_low, env.action_high, (env.action_size,), np.float32)


class RegisteredEnv(GymnasiumEnv):
    """`envs.to_gymnasium(task)` with Gymnasium's observation bounds, made by `gymnasium.make`."""

    def __init__(self, task: str, render_mode: str | None = None, **kwargs: Any):
        super().__init__(task, render_mode=render_mode, **_suite_options(task, _NO_LIMIT, kwargs))
        self.observation_space = observation_space(task, self.env)


def make_env(task: str, render_mode: str | None = None, **kwargs: Any) -> RegisteredEnv:
    """The ids' `entry_point` (`gymnasium.make`), with JAX's persistent compile cache on as the
    `mjxsuite` command has it (`envs.compile_cache`): a new process loads the env's compiled step."""
    enable_unless_off()
    return RegisteredEnv(task, render_mode=render_mode, **kwargs)


def make_vector_env(task: str, num_envs: int, max_episode_steps: int | None = None,
                    autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs: Any) -> JaxVectorEnv:
    """The ids' `vector_entry_point` (`gymnasium.make_vec`), with the compile cache on (`make_env`)."""
    enable_unless_off()
    return JaxVectorEnv(task, num_envs, max_episode_steps=max_episode_steps, autoreset_mode=autoreset_mode, **kwargs)


def _autoreset_mode(task: str, mode: AutoresetMode | str) -> AutoresetMode:
    supported = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
    try:
        chosen = AutoresetMode(mode)
    except ValueError:
        chosen = None
    if chosen not in supported:
        raise ValueError(f"env {task!r}: autoreset_mode={mode!r} is not supported; pass "
                         f"gymnasium.vector.AutoresetMode.NEXT_STEP (the default) or AutoresetMode.SAME_STEP")
    return chosen


class JaxVectorEnv(VectorEnv):
    """`num_envs` copies of a suite task behind Gymnasium's `VectorEnv` API, JAX arrays in and out
    (see the module docs). `self.state` is the batched suite `State` on the device."""

    metadata: ClassVar[dict[str, Any]] = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, task: str, num_envs: int, max_episode_steps: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, render_mode: str | None = None,
                 **kwargs: Any):
        if not isinstance(num_envs, (int, np.integer)) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"env {task!r}: num_envs must be a positive int, got {num_envs!r}")
        if render_mode is not None:
            raise ValueError(f"env {task!r}: the vector env does not render; render_mode must be None, "
                             f"got {render_mode!r}")
        self.task = task
        self.autoreset_mode = _autoreset_mode(task, autoreset_mode)
        self.metadata = {"autoreset_mode": self.autoreset_mode, "render_modes": []}
        self.env = make(task, **_suite_options(task, max_episode_steps, kwargs))  # TimeLimit(task)
        self.episode_length: int = self.env.episode_length
        self.num_envs = int(num_envs)
        self.render_mode = None
        self.single_observation_space = observation_space(task, self.env)
        self.single_action_space = action_space(self.env)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._auto_reset = AutoReset(self.env)
        self._reset = jax.jit(self._reset_all)
        step = self._step_next if self.autoreset_mode == AutoresetMode.NEXT_STEP else self._step_same
        # The old state is dead after a step: its buffers are reused in place where XLA can (not on a CPU).
        self._step = jax.jit(step, donate_argnums=0 if jax.default_backend() != "cpu" else ())
        self.state: State | None = None

    # ---- inside jit -------------------------------------------------------------
    def _reset_all(self, seed: jax.Array) -> tuple[State, jax.Array]:
        keys = jax.random.split(jax.random.PRNGKey(seed), self.num_envs)
        state = jax.vmap(self._auto_reset.reset)(keys)
        return state, _observed(self.env, state.obs)

    def _env_actions(self, actions: jax.Array) -> jax.Array:
        if self.env.num_actions is not None:
            return actions.astype(jnp.int32)
        low, high = jnp.asarray(self.env.action_low), jnp.asarray(self.env.action_high)
        unit = (actions.astype(jnp.float32) - 0.5 * (high + low)) / (0.5 * (high - low))
        return jnp.clip(unit, -1.0, 1.0)

    def _ends(self, before: State, after: State) -> tuple[jax.Array, jax.Array]:
        """terminated, truncated of each env's step (Gymnasium's TimeLimit truncates on the limit's
        step also when that step terminates)."""
        truncation = after.info["truncation"] > 0
        terminated = (after.done > 0) & ~truncation
        truncated = truncation | (before.info["steps"] + 1 >= self.episode_length)
        return terminated, truncated

    def _step_next(self, state: State, actions: jax.Array):
        # The envs whose episode ended on the last step start a new one now, ignoring their action.
        restart = state.done > 0
        stepped = jax.vmap(self.env.step)(state, self._env_actions(actions))
        fresh = jax.vmap(self._auto_reset.reset_if_done)(state)  # a new episode where `restart`

        def pick(new, old):
            return jnp.where(jnp.reshape(restart, restart.shape + (1,) * (new.ndim - 1)), new, old)

        terminated, truncated = self._ends(state, stepped)
        terminated, truncated = terminated & ~restart, truncated & ~restart
        zero = jnp.zeros_like(stepped.done)
        merged = jax.tree.map(pick, fresh, stepped)
        # What describes the last step (truncation, nan, ...) is nothing for an env that restarted.
        transition = {k: jnp.where(restart, jnp.zeros_like(stepped.info[k]), stepped.info[k])
                      for k in TRANSITION_INFO if k in stepped.info}
        merged = merged.replace(reward=jnp.where(restart, zero, stepped.reward),
                                done=jnp.where(restart, zero, stepped.done), info={**merged.info, **transition})
        return merged, (_observed(self.env, merged.obs), merged.reward.astype(jnp.float32), terminated, truncated, {})

    def _step_same(self, state: State, actions: jax.Array):
        stepped = jax.vmap(self._auto_reset.step)(state, self._env_actions(actions))
        terminated, truncated = self._ends(state, stepped)
        ended = terminated | truncated
        final = _observed(self.env, stepped.info["final_obs"])
        final_obs = jnp.where(ended.reshape(ended.shape + (1,) * (final.ndim - 1)), final, jnp.zeros_like(final))
        info = {"final_obs": final_obs, "_final_obs": ended, "final_info": {}, "_final_info": ended}
        return stepped, (_observed(self.env, stepped.obs), stepped.reward.astype(jnp.float32), terminated, truncated,
                         info)

    # ---- Gymnasium's API ---------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None and not isinstance(seed, (int, np.integer)):
            raise TypeError(f"env {self.task!r}: the vector env takes one int seed (each env draws its own "
                            f"episodes from it), got {seed!r}")
        super().reset(seed=seed)
        if options:
            raise ValueError(f"env {self.task!r}: reset takes no options, got {sorted(options)}")
        self.state, obs = self._reset(_episode_seed(self.np_random))
        return obs, {}

    def step(self, actions: Any):
        if self.state is None:
            raise gymnasium.error.ResetNeeded(f"env {self.task!r}: call reset() before step()")
        shape = (self.num_envs,) if self.env.num_actions is not None else (self.num_envs, self.env.action_size)
        if tuple(np.shape(actions)) != shape:
            raise ValueError(f"env {self.task!r}: actions of shape {tuple(np.shape(actions))} do not fit the action "
                             f"space {self.action_space}; expected shape {shape}")
        self.state, (obs, rewards, terminated, truncated, info) = self._step(self.state, jnp.asarray(actions))
        return obs, rewards, terminated, truncated, info

    def __repr__(self) -> str:
        return f"JaxVectorEnv({self.task!r}, num_envs={self.num_envs}, autoreset_mode={self.autoreset_mode})"
