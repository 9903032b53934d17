"""mjxsuite agents: DQN with uniform and prioritized replay, and its training driver."""

from agents.dqn import DQN, DQNConfig, train
from agents.run import load_policy, train_run

__all__ = ["DQN", "DQNConfig", "load_policy", "train", "train_run"]
