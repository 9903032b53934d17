"""Slow: DQN trained on randomised pole masses solves CartPole across the range (issue #18)."""

import json

import jax
import numpy as np
import pytest

from agents import DQNConfig, train_run
from agents.run import load_agent

RANGE = {"body_mass:pole": [0.05, 0.5]}  # 0.5x to 5x Gymnasium's 0.1 kg pole


@pytest.mark.slow
def test_randomized_pole_mass_solves_15_of_16_seeds_within_100k_steps(tmp_path):
    """16 seeds, at most 100k steps each (training stops once every seed's greedy evaluation,
    whose episodes each draw their own pole mass, reached 475); then each seed's best
    parameters are judged on 64 fresh episodes across the range."""
    result = train_run("cartpole-mjx", DQNConfig(total_steps=100_000), seeds=16, seed=2026, progress=False,
                       env_options={"randomize": RANGE}, out_dir=tmp_path, stop_when_solved=True)
    assert json.loads((tmp_path / "config.json").read_text())["env_options"]["randomize"] == RANGE
    _, _, dqn, params = load_agent(tmp_path)  # its env draws a pole mass per episode, as in training
    keys = jax.random.split(jax.random.PRNGKey(7), 16)
    means = np.asarray(jax.jit(jax.vmap(lambda p, k: dqn.evaluate(p, k, 64)))(params, keys).mean(axis=-1))
    print("steps trained", result.history[-1]["env_steps"], "greedy means over the range", means.round(1))
    assert (means >= 475).sum() >= 15, means
