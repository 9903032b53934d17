"""What Gymnasium's registry builds for our ids (`envs.interop.gymnasium_ids`):

- `make_env` (the ids' `entry_point`): one env, `gymnasium.make("mjxsuite/Hopper-v5")`, the
  numpy-on-the-host `envs.to_gymnasium` adapter; Gymnasium's `make` adds its `TimeLimit`;
- `make_vector_env` (the `vector_entry_point`): `gymnasium.make_vec("mjxsuite/Hopper-v5",
  num_envs=N)`, a `JaxVectorEnv`: all N envs stepped by one jitted call, JAX arrays in and out,
  which stay on the device (Gymnasium's `JaxToTorch` / `JaxToNumpy` convert them through DLPack).

Gymnasium's keyword arguments keep their names (`ctrl_cost_weight`, `reset_noise_scale`, ...: our
tasks' options are v5's constructor arguments), `max_episode_steps` is the time limit, and the
suite's own options pass the same way (`impl="warp"`, `opt={...}`).

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
"""

from __future__ import annotations

from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from envs.core import Env, State
from envs.interop.gymnasium import GymnasiumEnv, _episode_seed
from envs.registry import make
from envs.wrappers import TRANSITION_INFO, AutoReset

# The single env's own time limit: Gymnasium's `make` wraps it in its TimeLimit (max_episode_steps),
# which must be the one that truncates, also when it is longer than the task's default.
_NO_LIMIT = 2**31 - 1


def _suite_options(task: str, max_episode_steps: int | None, kwargs: dict[str, Any]) -> dict[str, Any]:
    overrides = dict(kwargs)
    if "episode_length" in overrides:
        raise ValueError(f"env {task!r} through Gymnasium: pass max_episode_steps=..., not episode_length "
                         f"(got episode_length={overrides['episode_length']!r})")
    if max_episode_steps is not None:
        overrides["episode_length"] = max_episode_steps
    return overrides


def observation_space(task: str, env: Env) -> spaces.Box:
    """Gymnasium's observation space of the task, as float32: CartPole-v1's and Acrobot-v1's bounds
    (from our rules, equal to Gymnasium's at the defaults), unbounded for every other task."""
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
    """The ids' `entry_point` (`gymnasium.make`)."""
    return RegisteredEnv(task, render_mode=render_mode, **kwargs)


def make_vector_env(task: str, num_envs: int, max_episode_steps: int | None = None,
                    autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, **kwargs: Any) -> JaxVectorEnv:
    """The ids' `vector_entry_point` (`gymnasium.make_vec`)."""
    return JaxVectorEnv(task, num_envs, max_episode_steps=max_episode_steps, autoreset_mode=autoreset_mode, **kwargs)


def _autoreset_mode(task: str, mode: AutoresetMode | str) -> AutoresetMode:
    supported = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
    try:
        mode = AutoresetMode(mode)
    except ValueError:
        mode = None
    if mode not in supported:
        raise ValueError(f"env {task!r}: autoreset_mode={mode!r} is not supported; pass "
                         f"gymnasium.vector.AutoresetMode.NEXT_STEP (the default) or AutoresetMode.SAME_STEP")
    return mode


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
        return state, state.obs.astype(jnp.float32)

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
        return merged, (merged.obs.astype(jnp.float32), merged.reward.astype(jnp.float32), terminated, truncated, {})

    def _step_same(self, state: State, actions: jax.Array):
        stepped = jax.vmap(self._auto_reset.step)(state, self._env_actions(actions))
        terminated, truncated = self._ends(state, stepped)
        ended = terminated | truncated
        final_obs = jnp.where(ended[:, None], stepped.info["final_obs"].astype(jnp.float32), 0.0)
        info = {"final_obs": final_obs, "_final_obs": ended, "final_info": {}, "_final_info": ended}
        return stepped, (stepped.obs.astype(jnp.float32), stepped.reward.astype(jnp.float32), terminated, truncated,
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
            import gymnasium

            raise gymnasium.error.ResetNeeded(f"env {self.task!r}: call reset() before step()")
        shape = (self.num_envs,) if self.env.num_actions is not None else (self.num_envs, self.env.action_size)
        if tuple(np.shape(actions)) != shape:
            raise ValueError(f"env {self.task!r}: actions of shape {tuple(np.shape(actions))} do not fit the action "
                             f"space {self.action_space}; expected shape {shape}")
        self.state, (obs, rewards, terminated, truncated, info) = self._step(self.state, jnp.asarray(actions))
        return obs, rewards, terminated, truncated, info

    def __repr__(self) -> str:
        return f"JaxVectorEnv({self.task!r}, num_envs={self.num_envs}, autoreset_mode={self.autoreset_mode})"
