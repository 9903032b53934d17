"""The policies of saved runs and their rollouts, Rerun-free: what `mjxsuite eval` and `rollout`
collect (agents/recording.py writes them to Rerun)."""

from __future__ import annotations

import os
from typing import Any

import jax

import envs
from agents import export_cache
from agents.dqn import DQN, greedy
from envs import rollouts


def greedy_policy(dqn: DQN) -> rollouts.PolicyFn:
    """`(params, obs, key) -> argmax_a Q(obs, a)`, jittable, for `envs.rollouts.collect_rollout`."""
    return lambda params, obs, key: greedy(dqn.q_values(params, obs))[0]


def load_greedy(out_dir: str | os.PathLike, seed_index: int | None = None):
    """The env and jittable greedy policy saved by `mjxsuite train --out DIR`: `(env_name, env, policy, params)`.

    With several trained seeds it takes the one with the best greedy evaluation unless `seed_index` picks one.
    A PPO/SAC run's policy is the mode of Brax's policy, acting in [-1, 1] as our envs take it.
    """
    from agents import checkpoint
    from agents.run import load_agent, pick_seed

    if checkpoint.load_config(out_dir).agent != "dqn":
        from agents import brax_agents, brax_run

        env_name, env, config, params = brax_run.load_agent(out_dir)
        return env_name, env, brax_agents.deterministic_policy(config, env.observation_size, env.action_size), params

    env_name, env, dqn, params = load_agent(out_dir)
    return env_name, env, greedy_policy(dqn), pick_seed(out_dir, params, seed_index)


def collect_rollout_cached(env: envs.Env, env_name: str, env_options: dict | None, policy_fn: rollouts.PolicyFn,
                           policy: Any, key: jax.Array, num_envs: int, steps: int, params: Any = None,
                           scene_envs: int = 1) -> rollouts.Rollout:
    """`envs.rollouts.collect_rollout`, its traced program kept in the export cache when that
    is on (`mjxsuite rollout`), so a second rollout of the same env and policy traces nothing.
    `policy` names `policy_fn` in the cache key: "random", or the DQN config of a greedy policy."""
    program = rollouts.rollout_program(env, policy_fn, num_envs, steps, scene_envs)
    sizes = {"num_envs": num_envs, "steps": steps, "scene_envs": scene_envs}
    compiled = export_cache.compile_env_program("rollout", program, (key, params), env, env_name, env_options,
                                                extra={"policy": policy, **sizes})
    return compiled(key, params)
