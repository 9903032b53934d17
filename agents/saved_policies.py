"""The policies of saved runs and their rollouts, Rerun-free: what `mjxsuite eval` and `rollout`
collect (envs/recording.py writes them to Rerun; agents/training_log.py logs training)."""

from __future__ import annotations

import os
from typing import Any

import jax

import envs
from agents import traced_programs
from envs import rollouts


def load_greedy(out_dir: str | os.PathLike, seed_index: int | None = None, env: envs.Env | None = None):
    """`(env_name, env, policy, params)` of a run directory: its deterministic `policy(params, obs, key)`, the
    best seed's parameters unless `seed_index` picks one; `env`: default the saved env (`checkpoint.saved_env`)."""
    from agents.run import load_agent, pick_seed

    env_name, env, agent, params = load_agent(out_dir, env)
    return env_name, env, lambda params, obs, key: agent.policy(params, obs), pick_seed(out_dir, params, seed_index)


def collect_rollout_cached(env: envs.Env, env_name: str, env_options: dict | None, policy_fn: rollouts.PolicyFn,
                           policy: Any, key: jax.Array, num_envs: int, steps: int, params: Any = None,
                           scene_envs: int = 1) -> rollouts.Rollout:
    """`envs.rollouts.collect_rollout` through the export cache (`mjxsuite rollout`). `policy` names
    `policy_fn` in the cache key: "random", or the config of a trained policy."""
    program = rollouts.rollout_program(env, policy_fn, num_envs, steps, scene_envs)
    sizes = {"num_envs": num_envs, "steps": steps, "scene_envs": scene_envs}
    compiled = traced_programs.compile_env_program("rollout", program, (key, params), env, env_name, env_options,
                                                extra={"policy": policy, **sizes})
    return compiled(key, params)
