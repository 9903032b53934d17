"""The agents by name ("dqn", "ppo", "sac", "td3"), as config.json records them: their config and agent
classes, loaded on first use (DQN's command line starts without Brax). Every agent has DQN's pure
interface (`agents.dqn.DQN`; docs/agents.md), so `agents.run` drives any of them the same way."""

from __future__ import annotations

import dataclasses
import importlib
import itertools
from typing import Any

import jax
import jax.numpy as jnp

from envs import Env

# name -> (module, config class, agent class)
AGENTS = {"dqn": ("agents.dqn", "DQNConfig", "DQN"), "ppo": ("agents.ppo", "PPOConfig", "PPO"),
          "sac": ("agents.sac", "SACConfig", "SAC"), "td3": ("agents.td3", "TD3Config", "TD3")}


def module(name: str):
    if name not in AGENTS:
        raise ValueError(f"unknown agent {name!r}; choose one of {', '.join(AGENTS)}")
    return importlib.import_module(AGENTS[name][0])


def config_class(name: str) -> type:
    return getattr(module(name), AGENTS[name][1])


def name_of(config: Any) -> str:
    """The agent a config belongs to."""
    for name, (module_name, config_name, _) in AGENTS.items():
        if type(config).__name__ == config_name and type(config).__module__ == module_name:
            return name
    raise TypeError(f"{type(config).__name__} is not the config of an agent ({', '.join(AGENTS)})")


# The agents with a network for camera images (PPO: Brax's vision networks; TD3: DrQ-v2's encoder): no agent
# trains a discrete task from pixels.
PIXEL_AGENTS = ("ppo", "td3")


def misfit(agent: str, env_name: str, num_actions: int | None, action_size: int | None, pixels: bool) -> str | None:
    """Why `agent` cannot train `env_name` (discrete where `num_actions` is given; camera images where
    `pixels`), naming what can; None where it can. For the command line and the Python API alike."""
    discrete = num_actions is not None
    if pixels and discrete:
        return (f"{env_name} with observation=pixels: no agent trains camera images with discrete actions "
                f"(DQN has no network for camera images, and PPO and TD3, which have one, act on continuous "
                f"actions only); train {env_name} from its state with --agent dqn (drop observation=pixels), or "
                "camera images of a continuous task with --agent ppo or td3 (e.g. --env cartpole-balance-mjx)")
    fits = ("dqn",) if discrete else ("ppo", "sac", "td3")
    if agent not in fits:
        kind = f"discrete ({num_actions} actions)" if discrete else f"continuous ({action_size} action values)"
        return (f"--agent {agent} cannot train {env_name}, which is {kind}; choose --agent {' or '.join(fits)}"
                + ("" if discrete else " (or a discrete variant of the task with dqn)"))
    if pixels and agent not in PIXEL_AGENTS:
        return (f"--agent {agent} has no network for camera images (--env-opt observation=pixels); train them "
                "with --agent ppo or td3, or drop observation=pixels")
    return None


def make(config: Any, env: Env, platform: str | None = None, agents: int = 1) -> Any:
    """The agent `config` configures, for `env` (`platform`, `agents`: as `agents.dqn.DQN` takes them)."""
    name = name_of(config)
    return getattr(module(name), AGENTS[name][2])(config, env, platform=platform, agents=agents)


def sweepable(name: str) -> tuple[str, ...]:
    """The config fields a sweep of this agent may vary within one program (none: no sweeps)."""
    return tuple(getattr(module(name), "SWEEPABLE", ()))


# One setting under two agents' names: DQN's gamma is Brax's (PPO's, SAC's, TD3's) discounting.
SAME_FIELD = {"gamma": "discounting", "discounting": "gamma"}


def sweep_configs(base: Any, sweep: dict[str, list[float]] | None) -> list[Any]:
    """Every combination of `sweep`'s values over `base`, the last field varying fastest (ValueError: unsweepable)."""
    if not sweep:
        return [base]
    name = name_of(base)
    valid = sweepable(name)
    fields = {f.name for f in dataclasses.fields(base)}
    foreign = [field for field in sweep if field not in fields]
    if foreign:  # another agent's field (DQN's gamma is PPO's and SAC's discounting)
        hints = [f"{field} is {SAME_FIELD[field]} here" for field in foreign if SAME_FIELD.get(field) in fields]
        raise ValueError(f"{type(base).__name__} has no field {', '.join(foreign)}"
                         + (f" ({'; '.join(hints)})" if hints else "")
                         + f"; sweepable fields of --agent {name}: {', '.join(valid) or 'none'}")
    fixed = [field for field in sweep if field not in valid]
    if fixed:
        if not valid:
            raise ValueError(f"{name} runs cannot be swept in one program; run one per config")
        raise ValueError(f"cannot sweep {', '.join(fixed)}: one compiled program has one set of array shapes and "
                         f"loops, so only the fields used as plain numbers can vary: {', '.join(valid)}. Run "
                         "one sweep per value of the others")
    empty = [field for field, values in sweep.items() if not values]
    if empty:
        raise ValueError(f"sweep of {', '.join(empty)} has no values")
    return [dataclasses.replace(base, **dict(zip(sweep, values))) for values in itertools.product(*sweep.values())]


def per_agent(configs: list[Any], seeds: int) -> Any:
    """The agent's `Hyperparams`, one entry per agent: each config's values for its `seeds` agents."""
    stacked = module(name_of(configs[0])).Hyperparams.stacked(configs)
    return jax.tree.map(lambda values: jnp.repeat(values, seeds), stacked)
