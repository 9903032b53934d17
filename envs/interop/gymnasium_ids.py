"""The suite's tasks in Gymnasium's registry: `gymnasium.make("mjxsuite/Hopper-v5")` and
`gymnasium.make_vec("mjxsuite/Hopper-v5", num_envs=4096)` (see docs/gymnasium.md).

Gymnasium 1.x has no plugin entry point any more (0.26-0.29 read the `gymnasium.envs` entry
points; 1.0 removed that), so the installed package carries `mjxsuite_gymnasium.pth`, which
Python's `site` runs at start-up: it loads this file by its path (not `import envs`, which
imports JAX) and calls `install()`, which registers the ids right after Gymnasium's own, when
something imports `gymnasium`. A process that starts without `site` (python -S) or from a plain
checkout on PYTHONPATH registers them with `import envs.interop.gymnasium_ids`.

This file imports nothing of the suite and nothing heavy: only the ids and their entry points
(strings, loaded by Gymnasium when an env is made) go into the registry.
"""

from __future__ import annotations

import sys
import warnings

NAMESPACE = "mjxsuite"
ENTRY_POINT = "envs.interop.gymnasium:make_env"
VECTOR_ENTRY_POINT = "envs.interop.gymnasium:make_vector_env"

# Gymnasium id (within our namespace) -> (our registered name, max_episode_steps). The ten MuJoCo v5
# tasks and the two classic-control ones carry Gymnasium's own ids and time limits (tests check them
# against Gymnasium's registry and ours); the MJX-only tasks take v0, the
# DeepMind Control Suite's their envs.make name and v0 (Shimmy's dm_control/cheetah-run-v0 is mjxsuite/dmc-cheetah-run-v0).
IDS: dict[str, tuple[str, int]] = {
    "HalfCheetah-v5": ("half-cheetah", 1000),
    "Hopper-v5": ("hopper", 1000),
    "Walker2d-v5": ("walker2d", 1000),
    "Swimmer-v5": ("swimmer", 1000),
    "InvertedPendulum-v5": ("inverted-pendulum", 1000),
    "InvertedDoublePendulum-v5": ("inverted-double-pendulum", 1000),
    "Reacher-v5": ("reacher", 50),
    "Ant-v5": ("ant", 1000),
    "Humanoid-v5": ("humanoid", 1000),
    "Pusher-v5": ("pusher", 100),
    "CartPole-v1": ("cartpole", 500),
    "Acrobot-v1": ("acrobot", 500),
    "CartPoleMjx-v0": ("cartpole-mjx", 500),
    "AcrobotMjx-v0": ("acrobot-mjx", 500),
    "CartPoleSwingUpMjx-v0": ("cartpole-swingup-mjx", 1000),
    "CartPoleBalanceMjx-v0": ("cartpole-balance-mjx", 1000),
    "PendulumMjx-v0": ("pendulum-mjx", 200),
    "PendulumMjxDiscrete-v0": ("pendulum-mjx-discrete", 200),
    "dmc-acrobot-swingup-v0": ("dmc-acrobot-swingup", 1000),
    "dmc-acrobot-swingup-sparse-v0": ("dmc-acrobot-swingup-sparse", 1000),
    "dmc-ball-in-cup-catch-v0": ("dmc-ball-in-cup-catch", 1000),
    "dmc-cartpole-balance-v0": ("dmc-cartpole-balance", 1000),
    "dmc-cartpole-balance-sparse-v0": ("dmc-cartpole-balance-sparse", 1000),
    "dmc-cartpole-swingup-v0": ("dmc-cartpole-swingup", 1000),
    "dmc-cartpole-swingup-sparse-v0": ("dmc-cartpole-swingup-sparse", 1000),
    "dmc-cartpole-two-poles-v0": ("dmc-cartpole-two-poles", 1000),
    "dmc-cartpole-three-poles-v0": ("dmc-cartpole-three-poles", 1000),
    "dmc-cheetah-run-v0": ("dmc-cheetah-run", 1000),
    "dmc-finger-spin-v0": ("dmc-finger-spin", 1000),
    "dmc-finger-turn-easy-v0": ("dmc-finger-turn-easy", 1000),
    "dmc-finger-turn-hard-v0": ("dmc-finger-turn-hard", 1000),
    "dmc-fish-upright-v0": ("dmc-fish-upright", 1000),
    "dmc-fish-swim-v0": ("dmc-fish-swim", 1000),
    "dmc-hopper-hop-v0": ("dmc-hopper-hop", 1000),
    "dmc-hopper-stand-v0": ("dmc-hopper-stand", 1000),
    "dmc-humanoid-stand-v0": ("dmc-humanoid-stand", 1000),
    "dmc-humanoid-walk-v0": ("dmc-humanoid-walk", 1000),
    "dmc-humanoid-run-v0": ("dmc-humanoid-run", 1000),
    "dmc-humanoid-run-pure-state-v0": ("dmc-humanoid-run-pure-state", 1000),
    "dmc-lqr-lqr-2-1-v0": ("dmc-lqr-lqr-2-1", 1000),
    "dmc-lqr-lqr-6-2-v0": ("dmc-lqr-lqr-6-2", 1000),
    "dmc-manipulator-bring-ball-v0": ("dmc-manipulator-bring-ball", 1000),
    "dmc-manipulator-bring-peg-v0": ("dmc-manipulator-bring-peg", 1000),
    "dmc-manipulator-insert-ball-v0": ("dmc-manipulator-insert-ball", 1000),
    "dmc-pendulum-swingup-v0": ("dmc-pendulum-swingup", 1000),
    "dmc-point-mass-easy-v0": ("dmc-point-mass-easy", 1000),
    "dmc-point-mass-hard-v0": ("dmc-point-mass-hard", 1000),
    "dmc-quadruped-walk-v0": ("dmc-quadruped-walk", 1000),
    "dmc-quadruped-run-v0": ("dmc-quadruped-run", 1000),
    "dmc-quadruped-fetch-v0": ("dmc-quadruped-fetch", 1000),
    "dmc-reacher-easy-v0": ("dmc-reacher-easy", 1000),
    "dmc-reacher-hard-v0": ("dmc-reacher-hard", 1000),
    "dmc-swimmer-swimmer6-v0": ("dmc-swimmer-swimmer6", 1000),
    "dmc-swimmer-swimmer15-v0": ("dmc-swimmer-swimmer15", 1000),
    "dmc-walker-stand-v0": ("dmc-walker-stand", 1000),
    "dmc-walker-walk-v0": ("dmc-walker-walk", 1000),
    "dmc-walker-run-v0": ("dmc-walker-run", 1000),
}


def full_id(gymnasium_id: str) -> str:
    return f"{NAMESPACE}/{gymnasium_id}"


def register_envs() -> None:
    """Every id of `IDS` into Gymnasium's registry (ids already there are left alone)."""
    from gymnasium.envs.registration import register, registry

    for gymnasium_id, (task, steps) in IDS.items():
        if full_id(gymnasium_id) in registry:
            continue
        theirs = registry.get(gymnasium_id)  # Gymnasium's own task of that id, if it has one
        register(
            id=full_id(gymnasium_id),
            entry_point=ENTRY_POINT,
            vector_entry_point=VECTOR_ENTRY_POINT,
            max_episode_steps=steps,
            reward_threshold=theirs.reward_threshold if theirs is not None else None,
            kwargs={"task": task},
        )


class _AfterGymnasium:
    """A `sys.meta_path` finder that finds nothing itself: when `gymnasium.envs` (Gymnasium's own
    registrations) is about to load, it wraps that module's loader so that `register_envs` runs
    right after it, then leaves `sys.meta_path`."""

    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name != "gymnasium.envs":
            return None
        sys.meta_path.remove(cls)
        for finder in sys.meta_path:
            spec = getattr(finder, "find_spec", lambda *a: None)(name, path, target)
            if spec is not None:
                break
        else:
            return None
        loader = spec.loader
        exec_module = loader.exec_module

        def exec_then_register(module):
            exec_module(module)
            _register_quietly()

        loader.exec_module = exec_then_register
        return spec


def _register_quietly() -> None:
    # A failure here must not break `import gymnasium` for a user who never asked for our envs.
    try:
        register_envs()
    except Exception as err:  # noqa: BLE001
        warnings.warn(f"mjxsuite could not register its envs in Gymnasium's registry: {type(err).__name__}: {err}",
                      stacklevel=2)


def install() -> None:
    """Register now if Gymnasium is loaded, else as soon as it is (called by mjxsuite_gymnasium.pth)."""
    if "gymnasium.envs" in sys.modules:
        _register_quietly()
    elif _AfterGymnasium not in sys.meta_path:
        sys.meta_path.insert(0, _AfterGymnasium)


if __name__ == "envs.interop.gymnasium_ids":  # imported as a module of the suite, not by the .pth
    _register_quietly()
