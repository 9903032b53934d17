"""mjxsuite agents: DQN with uniform and prioritized replay, Brax's PPO and SAC behind the same
driver steps, and `load_policy` for any run directory."""

import importlib

from agents.dqn import DQN, DQNConfig, train
from agents.run import load_policy, train_run

# Brax's agents are imported on first use (PEP 562 `__getattr__` below), so DQN's command line
# starts without their modules; `from agents import PPOConfig` works as before.
_LAZY = {"PPOConfig": "agents.brax_agents", "SACConfig": "agents.brax_agents", "train_brax": "agents.brax_run"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # found directly from now on
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = ["DQN", "DQNConfig", "PPOConfig", "SACConfig", "load_policy", "train", "train_brax", "train_run"]
