"""Small wrappers that each do one thing (Brax style).

The usual training stack, innermost first: the registry's `TimeLimit`, then
`AutoReset`, `EpisodeStats` and `VmapWrapper`; `wrap_for_training` builds it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs.core import Env, State, Wrapper

# Info entries that describe the transition just taken; an auto-reset keeps
# them instead of taking the fresh episode's values.
TRANSITION_INFO = ("truncation", "nan")


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
    state of a truncated episode. Each env keeps its own key in `info["rng"]`.
    """

    def reset(self, key: jax.Array) -> State:
        key, episode_key = jax.random.split(key)
        state = self.env.reset(episode_key)
        return state.replace(info={**state.info, "rng": key, "final_obs": state.obs})

    def step(self, state: State, action: jax.Array) -> State:
        stepped = self.env.step(state, action)
        rng, episode_key = jax.random.split(state.info["rng"])
        fresh = self.env.reset(episode_key)
        done = stepped.done.astype(bool)

        def pick(new, old):
            return jnp.where(jnp.reshape(done, done.shape + (1,) * (new.ndim - done.ndim)), new, old)

        carried = {k: v for k, v in fresh.info.items() if k not in TRANSITION_INFO}
        info = {
            **stepped.info,
            **jax.tree.map(pick, carried, {k: stepped.info[k] for k in carried}),
            "rng": rng,
            "final_obs": stepped.obs,
        }
        return stepped.replace(
            pipeline_state=jax.tree.map(pick, fresh.pipeline_state, stepped.pipeline_state),
            obs=pick(fresh.obs, stepped.obs),
            info=info,
        )


class EpisodeStats(Wrapper):
    """Tracks the running episode's return and length, and those of the last finished one.

    `info["episode_return"]`/`["episode_length"]` hold the running episode;
    `info["last_return"]`/`["last_length"]` the most recently finished one, and
    `info["episode_done"]` marks the step where it finished. Place it outside `AutoReset`.
    """

    def reset(self, key: jax.Array) -> State:
        state = self.env.reset(key)
        zero = jnp.zeros((), state.reward.dtype)
        zero_int = jnp.zeros((), jnp.int32)
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
        action = jnp.asarray(action)
        if action.shape[:1] != (self.num_envs,):
            raise TypeError(
                f"VmapWrapper over {self.num_envs} envs needs actions with leading dimension "
                f"{self.num_envs}; got shape {action.shape}"
            )
        return jax.vmap(self.env.step)(state, action)


def wrap_for_training(env: Env, num_envs: int) -> VmapWrapper:
    """`num_envs` auto-resetting copies of `env`, with episode statistics."""
    return VmapWrapper(EpisodeStats(AutoReset(env)), num_envs)
