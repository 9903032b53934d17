"""mjxsuite environments: a functional env API, analytic and MJX-backed tasks, and wrappers.

The API sits at the top of the package (`core`, `registry`, `wrappers`, `episode_keys`,
`assets`, `mjx_env`, `randomize`, `recording`); the tasks live in `envs.tasks` (one file each, their
MJCF in `assets/`), the Brax and Gymnasium adapters in `envs.interop`. Those two import
the API modules, never this package: only this file gathers the public names and
registers the built-in tasks. See ARCHITECTURE.md."""

import functools

from envs.core import Env, State, Wrapper
from envs.interop.brax import BraxEnv, to_brax
from envs.mjx_env import MjxEnv
from envs.randomize import Randomize, randomize
from envs.registry import make, names, options, register
from envs.tasks.acrobot import Acrobot, AcrobotPhysics, AcrobotRules
from envs.tasks.acrobot_mjx import AcrobotMjx
from envs.tasks.cartpole import CartPole, CartPolePhysics, CartPoleRules, CartPoleState
from envs.tasks.cartpole_mjx import CartPoleMjx
from envs.tasks.cartpole_swingup_mjx import CartPoleSwingUpMjx, SwingUpRules
from envs.tasks.ant import Ant, AntParams
from envs.tasks.half_cheetah import HalfCheetah, HalfCheetahParams
from envs.tasks.inverted_pendulums import (
    InvertedDoublePendulum, InvertedDoublePendulumParams, InvertedPendulum, InvertedPendulumParams,
)
from envs.tasks.reacher import Reacher, ReacherParams
from envs.tasks.pendulum_mjx import DISCRETE_TORQUE_BINS, PendulumMjx, PendulumParams
from envs.tasks.swimmer import Swimmer, SwimmerParams
from envs.tasks.walkers import Hopper, HopperParams, Walker2d, Walker2dParams
from envs.wrappers import AutoReset, BatchedAutoReset, EpisodeStats, TimeLimit, VmapWrapper, wrap_for_training


def to_gymnasium(name: str | Env, num_envs: int | None = None, **kwargs):
    """A registered env (by name) or an env instance as a `gymnasium.Env`, or with `num_envs` a
    `gymnasium.vector.VectorEnv` (see `envs.interop.gymnasium`). Gymnasium is optional, so it is
    imported only here."""
    from envs.interop.gymnasium import to_gymnasium as bridge

    return bridge(name, num_envs, **kwargs)


register("cartpole", CartPole, episode_length=500)
register("acrobot", Acrobot, episode_length=500)
register("acrobot-mjx", AcrobotMjx, episode_length=500)
register("cartpole-mjx", CartPoleMjx, episode_length=500)
register("cartpole-swingup-mjx", CartPoleSwingUpMjx, episode_length=1000)
register("pendulum-mjx", PendulumMjx, episode_length=200)
register("pendulum-mjx-discrete", functools.partial(PendulumMjx, action_bins=DISCRETE_TORQUE_BINS), episode_length=200)
# Gymnasium's MuJoCo v5 tasks, truncated at their max_episode_steps as registered by Gymnasium.
register("half-cheetah", HalfCheetah, episode_length=1000)
register("hopper", Hopper, episode_length=1000)
register("walker2d", Walker2d, episode_length=1000)
register("swimmer", Swimmer, episode_length=1000)
register("inverted-pendulum", InvertedPendulum, episode_length=1000)
register("inverted-double-pendulum", InvertedDoublePendulum, episode_length=1000)
register("reacher", Reacher, episode_length=50)
register("ant", Ant, episode_length=1000)

__all__ = [
    "Acrobot", "AcrobotMjx", "AcrobotPhysics", "AcrobotRules",
    "AutoReset", "BatchedAutoReset", "CartPole", "CartPoleMjx", "CartPolePhysics", "CartPoleRules", "CartPoleState", "Env",
    "EpisodeStats", "MjxEnv", "State", "TimeLimit", "VmapWrapper", "Wrapper",
    "make", "names", "options", "register", "to_gymnasium", "wrap_for_training",
    "PendulumMjx", "PendulumParams",
    "CartPoleSwingUpMjx", "SwingUpRules", "BraxEnv", "to_brax", "Randomize", "randomize",
    "HalfCheetah", "HalfCheetahParams", "Hopper", "HopperParams", "Walker2d", "Walker2dParams",
    "Swimmer", "SwimmerParams",
    "InvertedPendulum", "InvertedPendulumParams", "InvertedDoublePendulum", "InvertedDoublePendulumParams",
    "Reacher", "ReacherParams", "Ant", "AntParams",
]
