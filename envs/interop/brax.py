"""Training the suite's envs with Brax's own trainers (`brax.training.agents.ppo`, `.sac`).

Our `State` has Brax's field layout and our envs have `observation_size`,
`action_size` and `backend`, so Brax's wrappers and trainers drive a task as it
is. The one thing to undo is the time limit: `envs.make` wraps every task in our
`TimeLimit`, and Brax's trainer adds its own `EpisodeWrapper`. Both count steps in
`info["steps"]`, so stacked they would count every step twice and end episodes
at half their length. `to_brax` hands the time limit over to Brax:

    from brax.training.agents.sac import train as sac
    env = envs.to_brax("pendulum-mjx")
    make_policy, params, metrics = sac.train(env, episode_length=env.episode_length, ...)

Two things `to_brax` also does, because Brax 0.14.2 needs them:
- Brax's SAC only accepts `isinstance(env, brax.envs.Env)`; that class is an ABC,
  so `BraxEnv` is registered as a virtual subclass.
- Brax's trainers call `jax.device_put_replicated`, which JAX 0.10 removed
  (google/brax#671). When it is missing, an equivalent built from public JAX APIs
  is put back.

One behaviour of Brax's wrappers worth knowing: its `AutoResetWrapper` restarts
each of the `num_envs` envs from the *same* first state every episode (ours draws
a fresh one). PPO's `num_resets_per_eval` redraws them between evaluations.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs.core import Env, State, Wrapper
from envs.registry import make
from envs.wrappers import TimeLimit


class BraxEnv(Wrapper):
    """A single (unbatched) task with no time limit of its own, for Brax's trainers.

    `reset`/`step` are the task's own. `episode_length` is the limit the task had
    in our registry; pass it to the trainer (`ppo.train(env, episode_length=...)`).
    """

    def __init__(self, env: Env, episode_length: int):
        super().__init__(env)
        self.episode_length = int(episode_length)

    def reset(self, key: jax.Array) -> State:
        return _with_overflow_metrics(self.env.reset(key))

    def step(self, state: State, action: jax.Array) -> State:
        return _with_overflow_metrics(self.env.step(state, action))

    def __repr__(self) -> str:
        return f"BraxEnv({self.env!r}, episode_length={self.episode_length})"


def _with_overflow_metrics(state: State) -> State:
    """The state with MuJoCo Warp's overflow flags of its step (`info["overflow"]`, an MJX
    task's) as two 0/1 metrics. Brax's evaluator sums each metric over an episode, and an
    overflow ends its episode, so `eval/episode_overflow_contacts` is the share of evaluation
    episodes that a contact-pool overflow ended."""
    if "overflow" not in state.info:
        return state
    code = state.info["overflow"]  # envs.mjx_env: 1 contact pool, 2 constraint rows, 3 both
    flags = {"overflow_contacts": code % 2 == 1, "overflow_constraints": code >= 2}
    return state.replace(metrics={**state.metrics, **{name: flag.astype(state.reward.dtype)
                                                       for name, flag in flags.items()}})


def _device_put_replicated(tree: Any, devices: Sequence[jax.Device]) -> Any:
    """What JAX's removed `device_put_replicated` did: one copy of each leaf per device,
    stacked along a new leading axis that is sharded over `devices` (as pmap expects)."""
    mesh = jax.sharding.Mesh(np.array(devices), ("replica",))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("replica"))
    return jax.tree.map(lambda leaf: jax.device_put(jnp.stack([leaf] * len(devices)), sharding), tree)


def _meet_brax_needs() -> None:
    """See the module docstring. brax is imported here, not at the top, to keep `import envs` light."""
    from brax.envs.base import Env as BraxBaseEnv

    BraxBaseEnv.register(BraxEnv)
    with warnings.catch_warnings():  # JAX 0.8-0.9 still have it, with a DeprecationWarning
        warnings.simplefilter("ignore", DeprecationWarning)
        present = hasattr(jax, "device_put_replicated")
    if not present:
        jax.device_put_replicated = _device_put_replicated


def to_brax(name_or_env: str | Env, **overrides: Any) -> BraxEnv:
    """A registered env (by name, with `envs.make` overrides) or an env instance, ready
    for `brax.training.agents.ppo.train` / `sac.train`.

    An env from `envs.make` loses its `TimeLimit` (its length becomes
    `BraxEnv.episode_length`); a bare task needs `episode_length=...`. Envs already
    wrapped for training (auto-reset, stats, vmap) are refused: Brax adds its own.
    Brax's PPO and SAC act with continuous (tanh-Gaussian) policies, so discrete
    tasks are refused too.
    """
    if isinstance(name_or_env, str):
        env = make(name_or_env, **overrides)
        label = name_or_env
    else:
        env, label = name_or_env, repr(name_or_env)
        unknown = sorted(set(overrides) - {"episode_length"})
        if unknown:
            raise ValueError(
                f"to_brax({label}): options {unknown} only apply to a registered name "
                "(envs.make does them); for an env instance only episode_length is accepted"
            )

    episode_length = overrides.get("episode_length")
    if isinstance(env, TimeLimit):  # from envs.make: Brax takes over its episode length
        if episode_length is None:
            episode_length = env.episode_length
        env = env.env

    # Our wrappers limit time, auto-reset, batch or keep episode statistics: Brax's trainer
    # adds its own (`brax.envs.wrappers.training.wrap`), and the two would clash.
    layer = env
    while isinstance(layer, Wrapper):
        if type(layer).__module__ == TimeLimit.__module__:  # any of envs.wrappers
            raise ValueError(
                f"to_brax({label}): the env is already wrapped in {type(layer).__name__}; Brax's "
                "trainer adds its own time limit, auto-reset and vmap. Pass the env from "
                "envs.make(name) or the bare task."
            )
        layer = layer.env

    if episode_length is None:
        raise ValueError(
            f"to_brax({label}): the env has no time limit; pass episode_length=... "
            "(Brax's trainer needs it)"
        )

    if env.action_size is None:
        raise ValueError(
            f"to_brax({label}): the env is discrete ({env.num_actions} actions), but Brax's PPO "
            "and SAC act with continuous policies. Use a continuous task "
            "(e.g. 'pendulum-mjx' rather than 'pendulum-mjx-discrete') or the suite's DQN."
        )
    _meet_brax_needs()
    return BraxEnv(env, episode_length)
