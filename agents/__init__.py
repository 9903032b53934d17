"""mjxsuite agents: DQN (uniform and prioritized replay), PPO, SAC and TD3, each a pure
`train(config, env, key)` driven chunk by chunk by one run lifecycle (`train_run`), and
`load_policy` for any run directory."""

import importlib

# Every name is imported on first use (PEP 562): `import agents.signals`, the `mjxsuite` command's
# first line, loads no JAX.
_LAZY = {"DQN": "agents.dqn", "DQNConfig": "agents.dqn", "train": "agents.dqn", "load_policy": "agents.run",
         "train_run": "agents.run", "PPO": "agents.ppo", "PPOConfig": "agents.ppo", "SAC": "agents.sac",
         "SACConfig": "agents.sac", "TD3": "agents.td3", "TD3Config": "agents.td3"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # found directly from now on
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__all__ = sorted(_LAZY)
