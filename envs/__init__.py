"""mjxsuite environments: a functional env API, analytic and MJX-backed tasks, and wrappers."""

from envs.cartpole import CartPole, CartPolePhysics, CartPoleRules
from envs.cartpole_mjx import CartPoleMjx
from envs.core import Env, State, Wrapper
from envs.mjx_env import MjxEnv
from envs.registry import make, names, options, register
from envs.wrappers import AutoReset, EpisodeStats, TimeLimit, VmapWrapper, wrap_for_training

register("cartpole", CartPole, episode_length=500)
register("cartpole-mjx", CartPoleMjx, episode_length=500)

__all__ = [
    "AutoReset", "CartPole", "CartPoleMjx", "CartPolePhysics", "CartPoleRules", "Env",
    "EpisodeStats", "MjxEnv", "State", "TimeLimit", "VmapWrapper", "Wrapper",
    "make", "names", "options", "register", "wrap_for_training",
]
