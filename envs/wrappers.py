"""Small wrappers that each do one thing (Brax style).

The usual training stack, innermost first: the registry's `TimeLimit`, then
`BatchedAutoReset` (a batch of auto-resetting envs) and `EpisodeStats`;
`wrap_for_training` builds it. `VmapWrapper(AutoReset(env), n)` gives the same
states, but draws a fresh episode for every env on every step (see `BatchedAutoReset`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from envs.batching import folds_vmap
from envs.core import Env, State, Wrapper
from envs.episode_keys import episode_keys, next_episode_key
from envs.mjx_warp import either_overflow

# Info entries that describe the transition just taken; an auto-reset keeps
# them instead of taking the fresh episode's values (but for the reset's own overflow, added to the step's).
TRANSITION_INFO = ("truncation", "nan", "overflow")


class TimeLimit(Wrapper):
    """Ends an episode after `episode_length` steps and reports it as truncation.

    A step that terminates on its own is a termination even on the last step,
    as in Gymnasium (`info["truncation"]` stays 0).
    """

    def __init__(self, env: Env, episode_length: int):
        super().__init__(env)
        if episode_length < 1:
            raise ValueError(f"episode_length must be >= 1, got {episode_length}")
        self.episode_length = episode_length

    def reset(self, key: jax.Array) -> State:
        state = self.env.reset(key)
        return state.replace(info={**state.info, "steps": jnp.zeros((), jnp.int32)})

    def step(self, state: State, action: jax.Array) -> State:
        state = self.env.step(state, action)
        steps = state.info["steps"] + 1
        out_of_time = (steps >= self.episode_length) & (state.done == 0)
        truncation = out_of_time.astype(state.done.dtype)
        done = jnp.maximum(state.done, truncation)
        return state.replace(done=done, info={**state.info, "steps": steps, "truncation": truncation})


class AutoReset(Wrapper):
    """Starts a fresh, randomly drawn episode after `done`.

    The returned state carries the new episode's first observation in `obs`, and the
    observation the step actually produced in `info["final_obs"]` (equal to `obs`
    when the episode did not end), so learners can bootstrap from the true final
    state of a truncated episode. Each env keeps its own stream of episode keys in
    `info["rng"]`, a seed word and a counter that advances once per finished episode, so
    an env's episodes do not depend on how the resets are batched (`BatchedAutoReset`
    gives the same states). The stream is a cheap counter-based generator
    (`envs.episode_keys`), as every env draws a fresh episode on every step under `vmap`;
    the first episode is drawn from the key given to `reset`.
    """

    def reset(self, key: jax.Array) -> State:
        key, episode_key = jax.random.split(key)
        state = self.env.reset(episode_key)
        return state.replace(info={**state.info, "rng": episode_keys(key), **final_entries(self.env, state)})

    def step(self, state: State, action: jax.Array) -> State:
        return self.reset_if_done(self.env.step(state, action))

    def reset_if_done(self, stepped: State) -> State:
        """`stepped`, or a fresh episode in its place if it is done (`final_obs` keeps its observation)."""
        next_rng, episode_key = next_episode_key(stepped.info["rng"])
        fresh = self.env.reset(episode_key)
        done = stepped.done.astype(bool)

        def pick(new, old):
            return jnp.where(jnp.reshape(done, done.shape + (1,) * (new.ndim - done.ndim)), new, old)

        merged = _merge_fresh(stepped, fresh, next_rng, pick, kept_info(self.env))
        return merged.replace(info={**merged.info, **final_entries(self.env, stepped)})


def final_entries(env: Env, stepped: State) -> dict:
    """What an auto-reset keeps of the state a step produced: its observation as `final_obs`, and
    each info entry the env names in `final_info` as `final_<name>` (e.g. `envs.pixels.Pixels`'s
    `state_obs`, for a critic that bootstraps from the state rather than the pixels)."""
    return {"final_obs": stepped.obs, **{f"final_{name}": stepped.info[name] for name in getattr(env, "final_info", ())}}


def kept_info(env: Env) -> tuple[str, ...]:
    """Info entries an env keeps across its episodes (e.g. `envs.randomize(..., per="env")`'s
    model values): auto-reset leaves them as they are."""
    return tuple(getattr(env, "info_kept_across_episodes", ()))


def _merge_fresh(stepped: State, fresh: State, next_rng: tuple[jax.Array, jax.Array], merge,
                 kept: tuple[str, ...] = ()) -> State:
    """`stepped` with `fresh` episodes merged in by `merge(new, old)`: state, obs, the
    stream's next state and the info entries a fresh episode brings (not those that
    describe the finished transition, nor those in `kept`)."""
    carried = [k for k in fresh.info if k not in TRANSITION_INFO and k not in kept and k != "rng"]
    # The stream's seed word is merged with itself: XLA drops that select on a GPU, and on the
    # CPU the scatter ran faster than the seed passed around the `lax.switch` (MJX, 4,096 envs).
    info = {**stepped.info, **{k: jax.tree.map(merge, fresh.info[k], stepped.info[k]) for k in carried},
            "rng": jax.tree.map(merge, next_rng, stepped.info["rng"])}
    if "overflow" in fresh.info:  # a reset whose Warp work ran out is counted on the step that ended the episode
        step = stepped.info["overflow"]
        info["overflow"] = either_overflow(step, merge(fresh.info["overflow"], jnp.zeros_like(step)))
    return stepped.replace(
        pipeline_state=jax.tree.map(merge, fresh.pipeline_state, stepped.pipeline_state),
        obs=merge(fresh.obs, stepped.obs),
        info=info,
    )


class BatchedAutoReset(Wrapper):
    """`num_envs` copies of `env` side by side, each starting a fresh episode after `done`.

    The states are exactly those of `VmapWrapper(AutoReset(env), num_envs)`; only the
    work differs. Under `vmap` a per-env `lax.cond` becomes a select, so `AutoReset`
    draws and builds a fresh episode for every env on every step, which on a CPU
    costs more than the analytic CartPole's physics. With `reset_by_index` the batch
    decides instead, with one `lax.switch` per step:

    - no env ended: no reset work at all;
    - up to `max_resets` ended: only those are reset, picked by index
      (`jnp.nonzero`) and written back with a scatter;
    - more ended: every env, as `AutoReset` does.

    `reset_by_index` defaults to True on the CPU and False on accelerators, where
    the select over all envs is cheaper than a conditional (measured: see docs/results.md).
    `max_resets` defaults to a sixteenth of the batch; random play on CartPole
    ends about one episode in twenty per step. Inside a `vmap` over seeds the switch
    itself becomes a select (every branch runs), so keep the batch in this wrapper.

    Without `reset_by_index`, a batch of one steps its env unbatched, as `AutoReset` on
    scalars: XLA:GPU merges kernels that share inputs only over arrays of more than one
    element, so a `[1]`-shaped step ran as two more kernels than a scalar one, and a step
    of one env is that many kernel launches (measured: docs/results.md, "The GPU step").
    Not `under_vmap` (a batch that is itself vmapped, e.g. over seeds, where the arrays
    have more elements anyway and the scalar step made the DQN slower at 16 and 256 seeds:
    the same section), nor for envs whose `batch_of_one_as_scalars` is False (MJX's).

    An env whose reset is costly (`costly_reset = True`: `envs.pixels.Pixels` renders a frame,
    dm_control's cheetah settles for 200 physics steps; every MJX env under MuJoCo Warp, whose
    reset runs Warp's forward pass) resets by index on every backend, so a step resets the envs
    that ended rather than every env. `under_vmap` (the agents vmap their seeds), where a switch
    would run all three branches, the switch decides once for every env
    of every seed (`envs.batching.folds_vmap`): a step on which no episode ended anywhere does no
    reset work, and the states are the same.
    """

    def __init__(self, env: Env, num_envs: int, max_resets: int | None = None, reset_by_index: bool | None = None,
                 under_vmap: bool = False):
        super().__init__(env)
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs = num_envs
        self.max_resets = max(1, num_envs // 16) if max_resets is None else max_resets
        if not 1 <= self.max_resets <= num_envs:
            raise ValueError(f"max_resets must be in [1, num_envs={num_envs}], got {max_resets}")
        costly_reset = getattr(env, "costly_reset", False)
        if reset_by_index is None:
            reset_by_index = jax.default_backend() == "cpu" or costly_reset
        self.reset_by_index = reset_by_index
        self.reset_across_vmap = reset_by_index and costly_reset and under_vmap
        self.auto_reset = AutoReset(env)
        self.step_unbatched = num_envs == 1 and not (self.reset_by_index or under_vmap) and env.batch_of_one_as_scalars

    def reset(self, key: jax.Array) -> State:
        return jax.vmap(self.auto_reset.reset)(jax.random.split(key, self.num_envs))

    def step(self, state: State, action: jax.Array) -> State:
        action = _check_batched_action(action, self.num_envs)
        if self.step_unbatched:
            one = self.auto_reset.step(jax.tree.map(lambda x: x[0], state), action[0])
            return jax.tree.map(lambda x: x[None], one)
        stepped = jax.vmap(self.env.step)(state, action)
        stepped = stepped.replace(info={**stepped.info, **final_entries(self.env, stepped)})
        if not self.reset_by_index:
            return jax.vmap(self.auto_reset.reset_if_done)(stepped)
        return (folds_vmap(self._reset_ended) if self.reset_across_vmap else self._reset_ended)(stepped)

    def _reset_ended(self, stepped: State) -> State:
        """`stepped` (a batch of any size) with a fresh episode wherever one ended: no reset work
        where none did, by index where at most `max_resets` per `num_envs` did, else every env."""
        every = jax.vmap(self.auto_reset.reset_if_done)
        batch = stepped.done.shape[0]
        max_resets = self.max_resets * batch // self.num_envs
        ended = jnp.sum(stepped.done > 0)
        if max_resets >= batch:  # picking by index would save nothing
            return jax.lax.cond(ended > 0, every, lambda s: s, stepped)
        branch = (ended > 0).astype(jnp.int32) + (ended > max_resets).astype(jnp.int32)
        return jax.lax.switch(branch, [lambda s: s, functools.partial(self._reset_by_index, max_resets=max_resets),
                                       every], stepped)

    def _reset_by_index(self, stepped: State, max_resets: int) -> State:
        """Fresh episodes for the envs that ended (at most `max_resets` of them), by index."""
        batch = stepped.done.shape[0]
        # Unused slots hold the batch size: gathered clipped, dropped by the scatter.
        index = jnp.nonzero(stepped.done > 0, size=max_resets, fill_value=batch)[0]
        rng = jax.tree.map(lambda words: words[jnp.minimum(index, batch - 1)], stepped.info["rng"])
        next_rng, episode_key = jax.vmap(next_episode_key)(rng)
        fresh = jax.vmap(self.env.reset)(episode_key)

        def put(new, old):
            return old.at[index].set(new, mode="drop")

        return _merge_fresh(stepped, fresh, next_rng, put, kept_info(self.env))


class EpisodeStats(Wrapper):
    """Tracks the running episode's return and length, and those of the last finished one.

    `info["episode_return"]`/`["episode_length"]` hold the running episode;
    `info["last_return"]`/`["last_length"]` the most recently finished one, and
    `info["episode_done"]` marks the step where it finished. Place it outside the auto-reset
    (`AutoReset` or `BatchedAutoReset`); it works on one env or a batch.
    """

    def reset(self, key: jax.Array) -> State:
        state = self.env.reset(key)
        zero = jnp.zeros_like(state.reward)  # a scalar, or one per env outside a batched auto-reset
        zero_int = jnp.zeros(state.reward.shape, jnp.int32)
        stats = {
            "episode_return": zero,
            "episode_length": zero_int,
            "last_return": zero,
            "last_length": zero_int,
            "episode_done": zero,
        }
        return state.replace(info={**state.info, **stats})

    def step(self, state: State, action: jax.Array) -> State:
        info = state.info
        state = self.env.step(state, action)
        episode_return = info["episode_return"] + state.reward
        episode_length = info["episode_length"] + 1
        done = state.done.astype(bool)
        stats = {
            "episode_return": jnp.where(done, 0.0, episode_return).astype(episode_return.dtype),
            "episode_length": jnp.where(done, 0, episode_length),
            "last_return": jnp.where(done, episode_return, info["last_return"]),
            "last_length": jnp.where(done, episode_length, info["last_length"]),
            "episode_done": state.done,
        }
        return state.replace(info={**state.info, **stats})


class VmapWrapper(Wrapper):
    """Runs `num_envs` copies of an env side by side; `reset` takes one key."""

    def __init__(self, env: Env, num_envs: int):
        super().__init__(env)
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs = num_envs

    def reset(self, key: jax.Array) -> State:
        return jax.vmap(self.env.reset)(jax.random.split(key, self.num_envs))

    def step(self, state: State, action: jax.Array) -> State:
        return jax.vmap(self.env.step)(state, _check_batched_action(action, self.num_envs))


def _check_batched_action(action, num_envs: int) -> jax.Array:
    action = jnp.asarray(action)
    if action.shape[:1] != (num_envs,):
        raise TypeError(
            f"a batch of {num_envs} envs needs actions with leading dimension {num_envs}; got shape {action.shape}"
        )
    return action


def wrap_for_training(env: Env, num_envs: int, episode_stats: bool = True, under_vmap: bool = False) -> Env:
    """`num_envs` auto-resetting copies of `env`, with episode statistics unless
    `episode_stats=False` (a loop that reads none saves carrying five values per env);
    `under_vmap=True` for a batch that will itself be vmapped (`BatchedAutoReset`)."""
    batch = BatchedAutoReset(env, num_envs, under_vmap=under_vmap)
    return EpisodeStats(batch) if episode_stats else batch
