"""Rollouts of a policy in auto-resetting copies of an env, in one jitted scan: the arrays that
evaluation, `mjxsuite rollout` and the Rerun recordings (envs/recording.py) are made from. Free
of Rerun, so evaluating needs only JAX."""

from __future__ import annotations

import functools
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from envs.core import Env
from envs.wrappers import wrap_for_training


def has_scene(env: Env) -> bool:
    return hasattr(env, "scene_model") and hasattr(env, "scene_qpos")



class Rollout(NamedTuple):
    """One rollout of `num_envs` auto-resetting envs; leading axes (steps, envs).

    Row t holds the observation the policy saw, the action it took, and the reward and
    episode end that action produced; `scene_qpos` is the pose shown at row t.
    """

    obs: Any
    action: Any
    reward: Any
    done: Any
    episode_return: Any  # return of the episode that ended at this row (where done)
    episode_length: Any
    scene_qpos: Any  # (steps, scene_envs, nq), or None for an env without a scene


PolicyFn = Callable[[Any, jax.Array, jax.Array], jax.Array]  # (params, obs batch, key) -> actions


def random_policy(env: Env) -> PolicyFn:
    """Uniform random actions; ignores its params."""
    if env.num_actions is not None:
        return lambda params, obs, key: jax.random.randint(key, obs.shape[:1], 0, env.num_actions)
    return lambda params, obs, key: jax.random.uniform(key, obs.shape[:1] + (env.action_size,), minval=-1.0, maxval=1.0)


def rollout_program(env: Env, policy_fn: PolicyFn, num_envs: int = 1, steps: int = 500, scene_envs: int = 1):
    """The traceable `(key, params) -> Rollout` behind `collect_rollout`, for callers that
    compile it themselves (`mjxsuite rollout` keeps it in its cache of traced programs)."""
    if steps < 1 or num_envs < 1:
        raise ValueError(f"need steps >= 1 and num_envs >= 1, got steps={steps}, num_envs={num_envs}")
    batch = wrap_for_training(env, num_envs)
    scene_envs = min(scene_envs, num_envs)
    scene_qpos = jax.vmap(env.scene_qpos) if has_scene(env) and scene_envs > 0 else None

    def step(carry, _):
        state, key, params = carry
        key, act_key = jax.random.split(key)
        action = policy_fn(params, state.obs, act_key)
        if env.num_actions is not None:
            action = action.astype(jnp.int32)
        nxt = batch.step(state, action)
        qpos = None
        if scene_qpos is not None:
            qpos = scene_qpos(jax.tree.map(lambda x: x[:scene_envs], state.pipeline_state))
        row = Rollout(state.obs, action, nxt.reward, nxt.info["episode_done"], nxt.info["last_return"],
                      nxt.info["last_length"], qpos)
        return (nxt, key, params), row

    def collect(key, params):
        reset_key, loop_key = jax.random.split(key)
        _, rollout = jax.lax.scan(step, (batch.reset(reset_key), loop_key, params), None, steps)
        return rollout

    return collect


@functools.lru_cache(maxsize=32)
def _collector(env: Env, policy_fn: PolicyFn, num_envs: int, steps: int, scene_envs: int):
    """`rollout_program` jitted, cached so repeated rollouts compile once."""
    return jax.jit(rollout_program(env, policy_fn, num_envs, steps, scene_envs))


def collect_rollout(env: Env, policy_fn: PolicyFn, key: jax.Array, num_envs: int = 1, steps: int = 500,
                    params: Any = None, scene_envs: int = 1) -> Rollout:
    """`steps` steps of `num_envs` auto-resetting copies of `env` (a registered env, time limit
    included) under `policy_fn(params, obs, key)`, in one jitted scan; arrays stay on the device.
    Poses for the 3D scene are kept for the first `scene_envs` envs."""
    return _collector(env, policy_fn, num_envs, steps, scene_envs)(key, params)


def trim_to_episodes(rollout: Rollout, episodes: int) -> Rollout:
    """Cut a rollout just after every env has finished `episodes` episodes (if it got that far)."""
    finished = jnp.cumsum(rollout.done > 0, axis=0).min(axis=1) >= episodes
    cut = int(jnp.where(finished.any(), jnp.argmax(finished) + 1, finished.shape[0]))
    return jax.tree.map(lambda x: x[:cut], rollout)
