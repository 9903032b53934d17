"""mjxsuite environments: a functional env API, analytic and MJX-backed tasks, and wrappers."""

import functools

from envs.acrobot import Acrobot, AcrobotPhysics, AcrobotRules
from envs.acrobot_mjx import AcrobotMjx
from envs.brax_interop import BraxEnv, to_brax
from envs.cartpole import CartPole, CartPolePhysics, CartPoleRules
from envs.cartpole_mjx import CartPoleMjx
from envs.cartpole_swingup_mjx import CartPoleSwingUpMjx, SwingUpRules
from envs.core import Env, State, Wrapper
from envs.mjx_env import MjxEnv
from envs.pendulum_mjx import DISCRETE_TORQUE_BINS, PendulumMjx, PendulumParams
from envs.registry import make, names, options, register
from envs.wrappers import AutoReset, BatchedAutoReset, EpisodeStats, TimeLimit, VmapWrapper, wrap_for_training


def to_gymnasium(name: str, num_envs: int | None = None, **kwargs):
    """A registered env as a `gymnasium.Env`, or with `num_envs` a `gymnasium.vector.VectorEnv`
    (see `envs.gym_interop`). Gymnasium is optional, so it is imported only here."""
    from envs.gym_interop import to_gymnasium as bridge

    return bridge(name, num_envs, **kwargs)


register("cartpole", CartPole, episode_length=500)
register("acrobot", Acrobot, episode_length=500)
register("acrobot-mjx", AcrobotMjx, episode_length=500)
register("cartpole-mjx", CartPoleMjx, episode_length=500)
register("cartpole-swingup-mjx", CartPoleSwingUpMjx, episode_length=1000)
register("pendulum-mjx", PendulumMjx, episode_length=200)
register("pendulum-mjx-discrete", functools.partial(PendulumMjx, action_bins=DISCRETE_TORQUE_BINS), episode_length=200)

__all__ = [
    "Acrobot", "AcrobotMjx", "AcrobotPhysics", "AcrobotRules",
    "AutoReset", "BatchedAutoReset", "CartPole", "CartPoleMjx", "CartPolePhysics", "CartPoleRules", "Env",
    "EpisodeStats", "MjxEnv", "State", "TimeLimit", "VmapWrapper", "Wrapper",
    "make", "names", "options", "register", "to_gymnasium", "wrap_for_training",
    "PendulumMjx", "PendulumParams",
    "CartPoleSwingUpMjx", "SwingUpRules", "BraxEnv", "to_brax",
]
