"""mjxsuite agents: DQN (uniform and prioritized replay), PPO and SAC, each a pure
`train(config, env, key)` driven chunk by chunk by one run lifecycle (`train_run`), and
`load_policy` for any run directory."""

import importlib

from agents.dqn import DQN, DQNConfig, train
from agents.run import load_policy, train_run

# PPO and SAC are imported on first use (PEP 562 `__getattr__` below), so DQN's command line
# starts without their modules; `from agents import PPOConfig` works as before.
_LAZY = {"PPO": "agents.ppo", "PPOConfig": "agents.ppo", "SAC": "agents.sac", "SACConfig": "agents.sac"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # found directly from now on
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = ["DQN", "DQNConfig", "PPO", "PPOConfig", "SAC", "SACConfig", "load_policy", "train", "train_run"]
