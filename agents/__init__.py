"""mjxsuite agents: DQN with uniform and prioritized replay, Brax's PPO and SAC behind the same
driver steps, and `load_policy` for any run directory."""

from agents.brax_agents import PPOConfig, SACConfig
from agents.brax_run import train_brax
from agents.dqn import DQN, DQNConfig, train
from agents.run import load_policy, train_run

__all__ = ["DQN", "DQNConfig", "PPOConfig", "SACConfig", "load_policy", "train", "train_brax", "train_run"]
