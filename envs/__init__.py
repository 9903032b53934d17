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
from envs.registry import make, names, options, register, spec
from envs.wrappers import AutoReset, BatchedAutoReset, EpisodeStats, TimeLimit, VmapWrapper, wrap_for_training

# The built-in tasks, one row each: the name `envs.make` takes, the task class as "module:Class", the
# episode length (Gymnasium's max_episode_steps for its tasks), and the other public names of the
# task's module (its params, rules, ...). The registrations, the lazy imports and `__all__` all
# derive from this table: adding a task is one row.
TASKS = (
    # analytic (the Gymnasium / gymnax equations)
    ("cartpole", "envs.tasks.cartpole:CartPole", 500, ("CartPolePhysics", "CartPoleRules", "CartPoleState")),
    ("acrobot", "envs.tasks.acrobot:Acrobot", 500, ("AcrobotPhysics", "AcrobotRules")),
    # MJX: classic control as MJCF models
    ("acrobot-mjx", "envs.tasks.acrobot_mjx:AcrobotMjx", 500, ()),
    ("cartpole-mjx", "envs.tasks.cartpole_mjx:CartPoleMjx", 500, ()),
    ("cartpole-swingup-mjx", "envs.tasks.cartpole_swingup_mjx:CartPoleSwingUpMjx", 1000, ("SwingUpRules",)),
    ("cartpole-balance-mjx", "envs.tasks.cartpole_balance_mjx:CartPoleBalanceMjx", 1000, ("BalanceRules",)),
    ("pendulum-mjx", "envs.tasks.pendulum_mjx:PendulumMjx", 200, ("PendulumParams", "DISCRETE_TORQUE_BINS")),
    ("pendulum-mjx-discrete", "envs.tasks.pendulum_mjx:PendulumMjxDiscrete", 200, ()),
    # MJX: Gymnasium's MuJoCo v5 tasks
    ("half-cheetah", "envs.tasks.half_cheetah:HalfCheetah", 1000, ("HalfCheetahParams",)),
    ("hopper", "envs.tasks.walkers:Hopper", 1000, ("HopperParams",)),
    ("walker2d", "envs.tasks.walkers:Walker2d", 1000, ("Walker2dParams",)),
    ("swimmer", "envs.tasks.swimmer:Swimmer", 1000, ("SwimmerParams",)),
    ("inverted-pendulum", "envs.tasks.inverted_pendulums:InvertedPendulum", 1000, ("InvertedPendulumParams",)),
    ("inverted-double-pendulum", "envs.tasks.inverted_pendulums:InvertedDoublePendulum", 1000,
     ("InvertedDoublePendulumParams",)),
    ("reacher", "envs.tasks.reacher:Reacher", 50, ("ReacherParams",)),
    ("ant", "envs.tasks.ant:Ant", 1000, ("AntParams",)),
    ("humanoid", "envs.tasks.humanoid:Humanoid", 1000, ("HumanoidParams",)),
    ("pusher", "envs.tasks.pusher:Pusher", 100, ("PusherParams",)),
    # MJX: the DeepMind Control Suite's tasks (dm_control 1.0.50's MJCF and rules; envs.interop.dm_control proves them)
    ("dmc-acrobot-swingup", "envs.tasks.dmc_acrobot:DmcAcrobotSwingUp", 1000, ("DmcAcrobot",)),
    ("dmc-acrobot-swingup-sparse", "envs.tasks.dmc_acrobot:DmcAcrobotSwingUpSparse", 1000, ()),
    ("dmc-ball-in-cup-catch", "envs.tasks.dmc_ball_in_cup:DmcBallInCupCatch", 1000, ()),
    ("dmc-cartpole-balance", "envs.tasks.dmc_cartpole:DmcCartPoleBalance", 1000, ("DmcCartPole",)),
    ("dmc-cartpole-balance-sparse", "envs.tasks.dmc_cartpole:DmcCartPoleBalanceSparse", 1000, ()),
    ("dmc-cartpole-swingup", "envs.tasks.dmc_cartpole:DmcCartPoleSwingUp", 1000, ()),
    ("dmc-cartpole-swingup-sparse", "envs.tasks.dmc_cartpole:DmcCartPoleSwingUpSparse", 1000, ()),
    ("dmc-cartpole-two-poles", "envs.tasks.dmc_cartpole:DmcCartPoleTwoPoles", 1000, ()),
    ("dmc-cartpole-three-poles", "envs.tasks.dmc_cartpole:DmcCartPoleThreePoles", 1000, ()),
    ("dmc-cheetah-run", "envs.tasks.dmc_cheetah:DmcCheetahRun", 1000, ()),
    ("dmc-finger-spin", "envs.tasks.dmc_finger:DmcFingerSpin", 1000, ("DmcFinger",)),
    ("dmc-finger-turn-easy", "envs.tasks.dmc_finger:DmcFingerTurnEasy", 1000, ("DmcFingerTurn",)),
    ("dmc-finger-turn-hard", "envs.tasks.dmc_finger:DmcFingerTurnHard", 1000, ()),
    ("dmc-fish-upright", "envs.tasks.dmc_fish:DmcFishUpright", 1000, ("DmcFish",)),
    ("dmc-fish-swim", "envs.tasks.dmc_fish:DmcFishSwim", 1000, ()),
    ("dmc-hopper-hop", "envs.tasks.dmc_hopper:DmcHopperHop", 1000, ("DmcHopper",)),
    ("dmc-hopper-stand", "envs.tasks.dmc_hopper:DmcHopperStand", 1000, ()),
    ("dmc-humanoid-stand", "envs.tasks.dmc_humanoid:DmcHumanoidStand", 1000, ("DmcHumanoid",)),
    ("dmc-humanoid-walk", "envs.tasks.dmc_humanoid:DmcHumanoidWalk", 1000, ()),
    ("dmc-humanoid-run", "envs.tasks.dmc_humanoid:DmcHumanoidRun", 1000, ()),
    ("dmc-humanoid-run-pure-state", "envs.tasks.dmc_humanoid:DmcHumanoidRunPureState", 1000, ()),
    ("dmc-lqr-lqr-2-1", "envs.tasks.dmc_lqr:DmcLqrLqr21", 1000, ("DmcLqr",)),
    ("dmc-lqr-lqr-6-2", "envs.tasks.dmc_lqr:DmcLqrLqr62", 1000, ()),
    ("dmc-manipulator-bring-ball", "envs.tasks.dmc_manipulator:DmcManipulatorBringBall", 1000, ("DmcManipulator",)),
    ("dmc-manipulator-bring-peg", "envs.tasks.dmc_manipulator:DmcManipulatorBringPeg", 1000, ()),
    ("dmc-manipulator-insert-ball", "envs.tasks.dmc_manipulator:DmcManipulatorInsertBall", 1000, ()),
    ("dmc-pendulum-swingup", "envs.tasks.dmc_pendulum:DmcPendulumSwingUp", 1000, ()),
    ("dmc-point-mass-easy", "envs.tasks.dmc_point_mass:DmcPointMassEasy", 1000, ()),
    ("dmc-point-mass-hard", "envs.tasks.dmc_point_mass:DmcPointMassHard", 1000, ()),
    ("dmc-quadruped-walk", "envs.tasks.dmc_quadruped:DmcQuadrupedWalk", 1000, ("DmcQuadruped",)),
    ("dmc-quadruped-run", "envs.tasks.dmc_quadruped:DmcQuadrupedRun", 1000, ()),
    ("dmc-quadruped-fetch", "envs.tasks.dmc_quadruped:DmcQuadrupedFetch", 1000, ()),
    ("dmc-reacher-easy", "envs.tasks.dmc_reacher:DmcReacherEasy", 1000, ("DmcReacher",)),
    ("dmc-reacher-hard", "envs.tasks.dmc_reacher:DmcReacherHard", 1000, ()),
    ("dmc-swimmer-swimmer6", "envs.tasks.dmc_swimmer:DmcSwimmerSwimmer6", 1000, ("DmcSwimmer",)),
    ("dmc-swimmer-swimmer15", "envs.tasks.dmc_swimmer:DmcSwimmerSwimmer15", 1000, ()),
    ("dmc-walker-stand", "envs.tasks.dmc_walker:DmcWalkerStand", 1000, ("DmcWalker",)),
    ("dmc-walker-walk", "envs.tasks.dmc_walker:DmcWalkerWalk", 1000, ()),
    ("dmc-walker-run", "envs.tasks.dmc_walker:DmcWalkerRun", 1000, ()),
)

# Public names of the API imported on first use too: their modules load mujoco.mjx (which loads
# MuJoCo Warp and Warp: seconds of imports) or serve Brax.
_LAZY_API = {
    "MjxEnv": "envs.mjx_env",
    "GymnasiumMujocoEnv": "envs.tasks.gymnasium_mujoco",
    "DmControlEnv": "envs.tasks.dm_control_suite",
    "BraxEnv": "envs.interop.brax",
    "to_brax": "envs.interop.brax",
    "returns_on_dm_control": "envs.interop.dm_control",  # a policy judged on dm_control's own env
    "load_dm_control": "envs.interop.dm_control",  # dm_control's own env, on the installed mujoco
    "DmControlCamera": "envs.interop.dm_control",  # the judge's pictures of a pixel env, from dm_control's renderer
    "to_dm_env": "envs.interop.dm_control",  # a dmc-* task behind dm_control's dm_env interface
}

# Every task's names are imported on first use (PEP 562 `__getattr__` below), so `envs.make("cartpole")`
# and DQN on the analytic tasks start without MJX; `from envs import HalfCheetah` works as any import.
_LAZY = dict(_LAZY_API)
for _name, _factory, _length, _more in TASKS:
    _module, _, _class = _factory.partition(":")
    _LAZY.update(dict.fromkeys((_class, *_more), _module))
    register(_name, _factory, episode_length=_length)  # imported by its first `make` or `options`
del _name, _factory, _length, _more, _module, _class


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


def to_gymnasium(name: str | Env, num_envs: int | None = None, **kwargs):
    """A registered env (by name) or an env instance as a `gymnasium.Env`, or with `num_envs` a
    `gymnasium.vector.VectorEnv` (see `envs.interop.gymnasium`). Gymnasium is optional, so it is
    imported only here."""
    from envs.interop.gymnasium import to_gymnasium as bridge

    return bridge(name, num_envs, **kwargs)


__all__ = sorted(["Env", "State", "Wrapper", "Randomize", "randomize", "make", "names", "options", "register", "spec",
                  "AutoReset", "BatchedAutoReset", "EpisodeStats", "TimeLimit", "VmapWrapper", "wrap_for_training",
                  "to_gymnasium", *_LAZY])
