"""Brax's own PPO and SAC trainers (`brax.training.agents.ppo.train`, `.sac.train`), called with
our configs (`agents.ppo.PPOConfig`, `agents.sac.SACConfig`, whose fields keep Brax's names and
meanings): the reference our agents are checked against (tests/test_ppo.py, tests/test_sac.py)
and timed against (`benchmarks.brax_agents`). Brax is imported inside the functions.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable

import jax
import jax.numpy as jnp

from agents import registry
from agents.ppo import PPOConfig
from agents.sac import SACConfig

# Brax's evaluator runs one episode per eval env, with the policy's mode (tanh of the mean):
# the same deterministic policy that our agents' `policy` acts with.
DETERMINISTIC_EVAL = True


NOT_BRAX_ARGUMENTS = ("policy_hidden", "value_hidden", "hidden", "solve_return",
                      "cnn_output_channels", "cnn_kernel_size", "cnn_stride")


def _is_ppo(config: PPOConfig | SACConfig) -> bool:
    return registry.name_of(config) == "ppo"


def trainer_kwargs(config: PPOConfig | SACConfig) -> dict:
    """The keyword arguments of Brax's `train` for `config` (the network widths as `network_factory`)."""
    kwargs = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name not in NOT_BRAX_ARGUMENTS}
    return {**kwargs, "network_factory": network_factory(config), "deterministic_eval": DETERMINISTIC_EVAL}


def network_factory(config: PPOConfig | SACConfig) -> Callable:
    """Brax's network factory with the config's layer widths."""
    if _is_ppo(config):
        from brax.training.agents.ppo import networks as ppo_networks

        return functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=config.policy_hidden,
                                 value_hidden_layer_sizes=config.value_hidden)
    from brax.training.agents.sac import networks as sac_networks

    return functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=config.hidden)


def trainer(config: PPOConfig | SACConfig) -> Callable:
    """Brax's `train` function for `config`."""
    if _is_ppo(config):
        from brax.training.agents.ppo import train as ppo

        return ppo.train
    from brax.training.agents.sac import train as sac

    return sac.train


def _networks(config: PPOConfig | SACConfig, observation_size: int, action_size: int):
    """The networks Brax's trainer builds for `config`, built the same way (normalizer included)."""
    from brax.training import types
    from brax.training.acme import running_statistics

    preprocess = running_statistics.normalize if config.normalize_observations else types.identity_observation_preprocessor
    return network_factory(config)(observation_size, action_size, preprocess_observations_fn=preprocess)


def params_template(config: PPOConfig | SACConfig, observation_size: int, action_size: int) -> Any:
    """The shapes of the parameters Brax's trainer returns (PPO: normalizer, policy, value; SAC:
    normalizer, policy), without running anything: what a checkpoint is read against."""
    from brax.training.acme import running_statistics, specs

    networks = _networks(config, observation_size, action_size)

    def init(key):
        normalizer = running_statistics.init_state(specs.Array((observation_size,), jnp.dtype("float32")))
        if _is_ppo(config):
            policy_key, value_key = jax.random.split(key)
            return normalizer, networks.policy_network.init(policy_key), networks.value_network.init(value_key)
        return normalizer, networks.policy_network.init(key)

    return jax.eval_shape(init, jax.random.PRNGKey(0))


def deterministic_policy(config: PPOConfig | SACConfig, observation_size: int, action_size: int) -> Callable:
    """`(params, obs, key) -> action in [-1, 1]`, jittable: the mode of Brax's policy, as its
    deterministic evaluation acts (the key is unused)."""
    networks = _networks(config, observation_size, action_size)
    if _is_ppo(config):
        from brax.training.agents.ppo import networks as ppo_networks

        make_inference = ppo_networks.make_inference_fn(networks)
    else:
        from brax.training.agents.sac import networks as sac_networks

        make_inference = sac_networks.make_inference_fn(networks)
    return lambda params, obs, key: make_inference(params, deterministic=True)(obs, key)[0]
