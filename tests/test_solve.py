"""Slow: the default DQN solves CartPole-v1 (greedy mean >= 475 over 64 fresh episodes) on both backends."""

import jax
import numpy as np
import pytest

import envs
from agents import DQN, DQNConfig, train


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cartpole", "cartpole-mjx"])
def test_default_config_solves_15_of_16_seeds(name):
    config = DQNConfig(total_steps=50_000)
    env = envs.make(name)
    keys = jax.random.split(jax.random.PRNGKey(2026), 16)
    # One seed after another (`lax.map`), as `mjxsuite train` runs seeds on a CPU: XLA:CPU runs one
    # network's plain matmuls faster than a batch of them (agents.device_options.default_seed_axis).
    best_params, metrics = jax.jit(lambda keys: jax.lax.map(lambda k: train(config, env, k), keys))(keys)
    fresh = jax.random.split(jax.random.PRNGKey(7), 16)
    returns = jax.jit(jax.vmap(lambda p, k: DQN(config, env).evaluate(p, k, 64)))(best_params, fresh)
    means = np.asarray(returns.mean(axis=-1))
    print(name, "greedy means", means.round(1), "solve steps", np.asarray(metrics["solve_step"]))
    assert (means >= 475).sum() >= 15, means
