"""mjxsuite environments: a functional env API, analytic and MJX-backed tasks, and wrappers.

The API sits at the top of the package (`core`, `registry`, `wrappers`, `episode_keys`,
`assets`, `mjx_env`, `randomize`, `recording`); the tasks live in `envs.tasks` (one file each, their
MJCF in `assets/`), the Brax and Gymnasium adapters in `envs.interop`. Those two import
the API modules, never this package: only this file gathers the public names and
registers the built-in tasks. See ARCHITECTURE.md."""

import importlib
import importlib.util

from envs.core import Env, State, Wrapper
from envs.randomize import Randomize, randomize
from envs.registry import make, names, options, register
from envs.tasks.acrobot import Acrobot, AcrobotPhysics, AcrobotRules
from envs.tasks.cartpole import CartPole, CartPolePhysics, CartPoleRules, CartPoleState
from envs.wrappers import AutoReset, BatchedAutoReset, EpisodeStats, TimeLimit, VmapWrapper, wrap_for_training

# Public names imported on first use (PEP 562 `__getattr__` below): their modules load mujoco.mjx,
# which loads MuJoCo Warp and Warp (seconds of imports), or serve Brax. `envs.make("cartpole")` and DQN on
# the analytic tasks then start without them; `from envs import HalfCheetah` works as before.
_LAZY_MODULES = {
    "envs.mjx_env": ("MjxEnv",),
    "envs.interop.brax": ("BraxEnv", "to_brax"),
    "envs.tasks.acrobot_mjx": ("AcrobotMjx",),
    "envs.tasks.cartpole_mjx": ("CartPoleMjx",),
    "envs.tasks.cartpole_swingup_mjx": ("CartPoleSwingUpMjx", "SwingUpRules"),
    "envs.tasks.ant": ("Ant", "AntParams"),
    "envs.tasks.half_cheetah": ("HalfCheetah", "HalfCheetahParams"),
    "envs.tasks.humanoid": ("Humanoid", "HumanoidParams"),
    "envs.tasks.inverted_pendulums": ("InvertedDoublePendulum", "InvertedDoublePendulumParams",
                                      "InvertedPendulum", "InvertedPendulumParams"),
    "envs.tasks.pusher": ("Pusher", "PusherParams"),
    "envs.tasks.reacher": ("Reacher", "ReacherParams"),
    "envs.tasks.pendulum_mjx": ("DISCRETE_TORQUE_BINS", "PendulumMjx", "PendulumMjxDiscrete", "PendulumParams"),
    "envs.tasks.swimmer": ("Swimmer", "SwimmerParams"),
    "envs.tasks.walkers": ("Hopper", "HopperParams", "Walker2d", "Walker2dParams"),
}
_LAZY = {name: module for module, names_ in _LAZY_MODULES.items() for name in names_}


def __getattr__(name: str):
    """A public name of `_LAZY`, or a submodule such as `envs.mjx_env`, imported now."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value  # found directly from now on
        return value
    if importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


def _lazy_task(name: str) -> str:
    """A task class of `_LAZY` as `register` takes it by name ("module:attr"), imported on first use."""
    return f"{_LAZY[name]}:{name}"


def to_gymnasium(name: str | Env, num_envs: int | None = None, **kwargs):
    """A registered env (by name) or an env instance as a `gymnasium.Env`, or with `num_envs` a
    `gymnasium.vector.VectorEnv` (see `envs.interop.gymnasium`). Gymnasium is optional, so it is
    imported only here."""
    from envs.interop.gymnasium import to_gymnasium as bridge

    return bridge(name, num_envs, **kwargs)


register("cartpole", CartPole, episode_length=500)
register("acrobot", Acrobot, episode_length=500)
# The MJX tasks by "module:attr", imported by their first `make` or `options`.
register("acrobot-mjx", _lazy_task("AcrobotMjx"), episode_length=500)
register("cartpole-mjx", _lazy_task("CartPoleMjx"), episode_length=500)
register("cartpole-swingup-mjx", _lazy_task("CartPoleSwingUpMjx"), episode_length=1000)
register("pendulum-mjx", _lazy_task("PendulumMjx"), episode_length=200)
register("pendulum-mjx-discrete", _lazy_task("PendulumMjxDiscrete"), episode_length=200)
# Gymnasium's MuJoCo v5 tasks, truncated at their max_episode_steps as registered by Gymnasium.
register("half-cheetah", _lazy_task("HalfCheetah"), episode_length=1000)
register("hopper", _lazy_task("Hopper"), episode_length=1000)
register("walker2d", _lazy_task("Walker2d"), episode_length=1000)
register("swimmer", _lazy_task("Swimmer"), episode_length=1000)
register("inverted-pendulum", _lazy_task("InvertedPendulum"), episode_length=1000)
register("inverted-double-pendulum", _lazy_task("InvertedDoublePendulum"), episode_length=1000)
register("reacher", _lazy_task("Reacher"), episode_length=50)
register("ant", _lazy_task("Ant"), episode_length=1000)
register("humanoid", _lazy_task("Humanoid"), episode_length=1000)
register("pusher", _lazy_task("Pusher"), episode_length=100)

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
    "Reacher", "ReacherParams", "Ant", "AntParams", "Humanoid", "HumanoidParams", "Pusher", "PusherParams",
]
