"""The functional environment API shared by every env in the suite.

`State` keeps Brax's field layout so Brax's wrappers and trainers can drive our
envs; `Env` is the interface (`reset(key)`, `step(state, action)`) and
`Wrapper` forwards everything it does not override.

The contract, shaped for a GPU step as well as for learners:

- What may not change: the analytic CartPole equals Gymnasium's; Brax's wrappers and
  trainers drive every env; after an auto-reset `info["final_obs"]` holds the observation
  the step produced (learners bootstrap from it); every new episode is drawn afresh from
  the env's own key stream, independent of other envs and episodes.
- Per env, a batch carries only values its next step reads, each a scalar (so `[N]` for
  a batch): the physics state (`pipeline_state`: a `CartPoleState` of four scalars, or an
  `mjx.Data`), the key stream (`info["rng"]`: two `uint32` words, a seed that never changes
  and a counter that a finished episode advances), the time limit's step counter, and the
  episode statistics of `EpisodeStats` (left out by `wrap_for_training(...,
  episode_stats=False)`). On a GPU, XLA then computes a whole auto-resetting step in one
  kernel with one thread per env, writing each value over its old one; an `[N, k]` array
  instead makes each of its k columns recompute the env's physics and reset draw, and a
  key stream whose two words each hashed both was copied between loop buffers every step.
- A batch of one env that is not itself vmapped steps as scalars on a GPU (`BatchedAutoReset`),
  where XLA merges the kernels of a step into fewer launches than over `[1]` arrays; its
  state keeps the `[1]` axis.
- `obs`, `reward`, `done` and `info["final_obs"]` are outputs: nothing inside a step reads
  them, so a jitted loop that does not read them either leaves them out.
"""

from __future__ import annotations

import abc
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct


@struct.dataclass
class State:
    """One environment state. All fields are arrays, so a State is a pytree.

    `done` is terminated OR truncated; `info["truncation"]` is 1.0 when the
    episode ended only because of the time limit, and `info["nan"]` is 1.0 when
    it ended because the physics became non-finite. `obs` after an auto-reset is
    the first observation of the new episode; the last observation of the
    finished one is kept in `info["final_obs"]` (see `wrappers.AutoReset`).
    """

    pipeline_state: Any
    obs: jax.Array
    reward: jax.Array
    done: jax.Array
    metrics: dict[str, jax.Array] = struct.field(default_factory=dict)
    info: dict[str, Any] = struct.field(default_factory=dict)


class Env(abc.ABC):
    """A pure-functional environment: no Python side effects in reset/step.

    Discrete envs set `num_actions` (actions are integer indices); continuous
    envs set `action_size` (actions are float vectors in [-1, 1]).
    """

    observation_size: int
    num_actions: int | None = None
    action_size: int | None = None
    backend: str = "jax"  # Brax's wrappers read this attribute.
    # Whether `BatchedAutoReset` may step a batch of one as one env of scalars on a GPU (fewer
    # kernels for XLA to launch there); MJX's unbatched step is the slower one (`MjxEnv`).
    batch_of_one_as_scalars: bool = True

    @abc.abstractmethod
    def reset(self, key: jax.Array) -> State:
        """A fresh episode's first state, drawn with `key`."""

    @abc.abstractmethod
    def step(self, state: State, action: jax.Array) -> State:
        """Advance one step. Unknown `info` entries must be carried through."""

    @property
    def unwrapped(self) -> Env:
        return self

    # Gymnasium's action space of a continuous env, elementwise (numpy, shape (action_size,)).
    # The env itself takes actions in [-1, 1]; `to_env_action` maps them to these bounds, which is
    # what a policy hands to Gymnasium's own env of the same task (`agents.load_policy`,
    # `envs.to_gymnasium`). MjxEnv uses the actuators' ctrlrange.
    @property
    def action_low(self) -> np.ndarray:
        return -np.ones(self.action_size or 0, np.float32)

    @property
    def action_high(self) -> np.ndarray:
        return np.ones(self.action_size or 0, np.float32)

    def to_env_action(self, unit_action: Any) -> Any:
        """A continuous action in [-1, 1] as the same action in [action_low, action_high]."""
        low, high = self.action_low, self.action_high
        return 0.5 * (high + low) + np.clip(unit_action, -1.0, 1.0) * 0.5 * (high - low)

    def from_env_action(self, action: Any) -> Any:
        """An action in [action_low, action_high] as the env's own action in [-1, 1]."""
        low, high = self.action_low, self.action_high
        return (np.asarray(action) - 0.5 * (high + low)) / (0.5 * (high - low))

    def check_action(self, action: Any) -> jax.Array:
        """Reject a wrongly shaped or typed action while tracing, with a clear message."""
        action = jnp.asarray(action)
        name = type(self.unwrapped).__name__
        if self.num_actions is not None:
            if action.shape != () or not jnp.issubdtype(action.dtype, jnp.integer):
                raise TypeError(
                    f"{name} takes one integer action index in [0, {self.num_actions}); "
                    f"got an array of shape {action.shape} and dtype {action.dtype}. "
                    "Use jax.vmap (or envs.wrappers.VmapWrapper) for a batch of envs."
                )
        else:
            if action.shape != (self.action_size,) or not jnp.issubdtype(action.dtype, jnp.floating):
                raise TypeError(
                    f"{name} takes a float action of shape ({self.action_size},); "
                    f"got shape {action.shape} and dtype {action.dtype}."
                )
        return action


class Wrapper(Env):
    """Forwards reset, step and every attribute to the wrapped env."""

    def __init__(self, env: Env):
        self.env = env

    def reset(self, key: jax.Array) -> State:
        return self.env.reset(key)

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step(state, action)

    @property
    def unwrapped(self) -> Env:
        return self.env.unwrapped

    def __getattr__(self, name: str) -> Any:
        if name == "env":  # not yet set: avoid infinite recursion during unpickling
            raise AttributeError(name)
        return getattr(self.env, name)

    # Class attributes of Env would shadow __getattr__; forward them explicitly.
    observation_size = property(lambda self: self.env.observation_size)
    num_actions = property(lambda self: self.env.num_actions)
    action_size = property(lambda self: self.env.action_size)
    backend = property(lambda self: self.env.backend)
    batch_of_one_as_scalars = property(lambda self: self.env.batch_of_one_as_scalars)
    action_low = property(lambda self: self.env.action_low)
    action_high = property(lambda self: self.env.action_high)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.env!r})"
