"""Environments by name, with keyword overrides checked against what each env accepts."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import sys
from typing import Any, Callable, NamedTuple

from envs.core import Env
from envs.mjx_options import check_opt
from envs.mjx_warp import check_buffer_sizes
from envs.pixels import PIXEL_OPTIONS, Pixels, check_pixel_options, with_default_camera
from envs.randomize import PER, Randomize
from envs.ranges import COUNT, check_fields
from envs.wrappers import TimeLimit

# Overrides every MJX task takes besides its own (see `make`): `opt` (MuJoCo's solver options,
# `envs.mjx_options`), MuJoCo Warp's buffer sizes (None: derived from the model), `randomize` and the
# camera observation (`envs.pixels`: observation="pixels", camera, width, height, depth, frame_stack, ...).
MJX_OPTIONS = {"impl": "jax", "opt": None, "nconmax": None, "naconmax": None, "njmax": None,
               "randomize": None, "randomize_per": PER[0], **PIXEL_OPTIONS}

# name -> (factory, or its "module:attr" until first use; episode_length)
_REGISTRY: dict[str, tuple[Callable[..., Env] | str, int]] = {}


def register(name: str, factory: Callable[..., Env] | str, episode_length: int = 1000) -> None:
    """Make `factory` available as `envs.make(name)`.

    `factory`'s keyword arguments become overrides; an argument whose default is a
    dataclass (e.g. physics constants) also accepts each of its fields by name.
    `factory` may also be named as "module:attr", imported when the env is first looked up:
    the built-in MJX tasks register so, and importing `envs` never loads MJX (seconds of start-up).
    """
    if isinstance(factory, str) and ":" not in factory:
        raise ValueError(f"register({name!r}, {factory!r}): a factory given by name is written 'module:attr'")
    if name in _REGISTRY:
        raise ValueError(f"an env named {name!r} is already registered ({_REGISTRY[name][0]!r})")
    _REGISTRY[name] = (factory, episode_length)


def names() -> list[str]:
    return sorted(_REGISTRY)


def options(name: str) -> dict[str, Any]:
    """Every override `make(name, ...)` accepts, with its default."""
    factory, episode_length = _lookup(name)
    found: dict[str, Any] = {"episode_length": episode_length}
    if _makes_mjx_env(factory):  # a task may set its own camera defaults (the DeepMind Control Suite's 84x84)
        found.update(MJX_OPTIONS, **pixel_defaults(factory))
    for param in inspect.signature(factory).parameters.values():
        if param.default is inspect.Parameter.empty:
            continue
        found[param.name] = param.default
        if dataclasses.is_dataclass(param.default):
            for field in dataclasses.fields(param.default):
                found[field.name] = getattr(param.default, field.name)
    return found


def make(name: str, **overrides: Any) -> Env:
    """Build a registered env, its episodes limited to `episode_length` steps (truncation).

    An MJX task also takes `impl` ("jax", or "warp" for MuJoCo Warp on an NVIDIA GPU), `opt`
    (`mujoco.MjOption` fields, e.g. `opt={"iterations": 4, "solver": "CG"}`), `nconmax`,
    `naconmax` and `njmax` (MuJoCo Warp's buffers, see `envs.mjx_warp.WarpBuffers`) and
    `randomize` (ranges of model values, see `envs.randomize`) with `randomize_per`, and
    `observation="pixels"` with `camera`, `width`, `height`, `depth`, `frame_stack`, `action_repeat` and
    `shadows` (camera images as the observation, see `envs.pixels`)."""
    return _built(*_checked(name, overrides))


def _built(factory: Callable[..., Env], kwargs: dict, mjx_options: dict, episode_length: int) -> Env:
    """The env that `_checked`'s pieces describe: the task, configured and wrapped (`make`)."""
    env = factory(**kwargs)
    if mjx_options:
        env = env.configured(impl=mjx_options["impl"], opt=mjx_options["opt"], nconmax=mjx_options["nconmax"],
                             naconmax=mjx_options["naconmax"], njmax=mjx_options["njmax"])
        pixels = mjx_options["observation"] == "pixels"
        if pixels:
            env = with_default_camera(env.filmed())
        if mjx_options["randomize"]:
            env = Randomize(env, mjx_options["randomize"], mjx_options["randomize_per"])
        if pixels:
            env = Pixels(env, **{k: mjx_options[k] for k in PIXEL_OPTIONS if k != "observation"})
    return TimeLimit(env, episode_length)


class Spec(NamedTuple):
    """What choosing an agent needs to know of an env before it is made (`spec`)."""

    num_actions: int | None  # discrete actions: how many
    action_size: int | None  # continuous actions: how many values
    pixels: bool  # camera images as the observation (observation="pixels")


def spec(name: str, **overrides: Any) -> Spec:
    """What `make(name, **overrides)` would build, its overrides checked as `make` checks them. An
    MJX task is built without its device state (`envs.mjx_env.SPEC_ONLY`): no MJX, no MuJoCo Warp,
    no JAX backend, seconds that the parent of per-GPU processes (`agents.processes`) would spend
    before it starts them. Any other env is made, and so is a task with `randomize` or camera
    images: their wrappers check the ranges and the camera against the model on the device."""
    checked = factory, kwargs, mjx_options, _ = _checked(name, overrides)
    if not mjx_options or mjx_options["randomize"] or mjx_options["observation"] == "pixels":
        env = _built(*checked)
        return Spec(env.num_actions, env.action_size, getattr(env, "observation_shape", None) is not None)
    from envs.mjx_env import SPEC_ONLY

    token = SPEC_ONLY.set(True)
    try:
        task = factory(**kwargs)
    finally:
        SPEC_ONLY.reset(token)
    return Spec(task.num_actions, task.action_size, pixels=False)


def _checked(name: str, overrides: dict[str, Any]) -> tuple[Callable[..., Env], dict, dict, int]:
    """`make`'s overrides checked, before anything is built: the factory, its keyword arguments, the
    MJX options (empty for a task that is not an MjxEnv) and the episode length."""
    overrides = dict(overrides)
    factory, _ = _lookup(name)
    valid = options(name)
    unknown = sorted(set(overrides) - set(valid))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for env {name!r}; valid options: {sorted(valid)}")
    given_length = overrides.pop("episode_length", None)
    mjx_options = {k: overrides.pop(k, valid[k]) for k in MJX_OPTIONS if k in valid}
    kwargs: dict[str, Any] = {}
    for param in inspect.signature(factory).parameters.values():
        if param.name in overrides:
            kwargs[param.name] = overrides.pop(param.name)
        elif dataclasses.is_dataclass(param.default):
            fields = {f.name for f in dataclasses.fields(param.default)}
            changes = {k: overrides.pop(k) for k in list(overrides) if k in fields}
            if changes:
                kwargs[param.name] = dataclasses.replace(param.default, **changes)
    for value in kwargs.values():  # out-of-range physics or rules are refused here, before anything compiles
        check_fields(value, getattr(value, "RANGES", {}))
    if mjx_options:
        check_opt(mjx_options["opt"], f"env {name!r}")
        check_buffer_sizes(mjx_options, f"env {name!r}")
        check_pixel_options({k: mjx_options[k] for k in PIXEL_OPTIONS}, name, {k: valid[k] for k in PIXEL_OPTIONS})
    # A task's episode lasts its own seconds: an env step of `action_repeat=k` is k task steps, so
    # the default limit is the task's over k (a given `episode_length` counts env steps).
    repeat = mjx_options["action_repeat"] if mjx_options and mjx_options["observation"] == "pixels" else 1
    episode_length = COUNT.check("episode_length",
                                 max(1, valid["episode_length"] // repeat) if given_length is None else given_length)
    return factory, kwargs, mjx_options, episode_length


def is_mjx_task(env: Env) -> bool:
    """Whether `env`, unwrapped, is an MJX task (an `envs.MjxEnv`), without importing MJX."""
    mjx_env = _loaded_mjx_env()
    return mjx_env is not None and isinstance(env.unwrapped, mjx_env)


def makes_mjx_task(name: str) -> bool:
    """Whether `make(name)` builds an MJX task, known without building it: making an MJX task puts
    its model on a device, which starts JAX's backend (`agents.processes` asks before it may)."""
    return _makes_mjx_env(_lookup(name)[0])


def pixel_defaults(factory: Callable[..., Env]) -> dict[str, Any]:
    """The camera options a task class sets over `PIXEL_OPTIONS`' (its `pixel_defaults`)."""
    defaults = getattr(getattr(factory, "func", factory), "pixel_defaults", {})
    unknown = set(defaults) - set(PIXEL_OPTIONS)
    if unknown:
        raise ValueError(f"{factory}: pixel_defaults names {sorted(unknown)}; camera options are {sorted(PIXEL_OPTIONS)}")
    return dict(defaults)


def _makes_mjx_env(factory: Callable[..., Env]) -> bool:
    """Whether `factory` is an MjxEnv subclass (or a functools.partial of one)."""
    mjx_env = _loaded_mjx_env()
    factory = getattr(factory, "func", factory)
    return mjx_env is not None and inspect.isclass(factory) and issubclass(factory, mjx_env)


def _loaded_mjx_env() -> type | None:
    """`envs.MjxEnv` once envs.mjx_env is imported, else None: no MJX task exists before, and
    importing it just to ask would load mujoco.mjx (seconds of start-up) for an analytic task."""
    return getattr(sys.modules.get("envs.mjx_env"), "MjxEnv", None)


def _lookup(name: str) -> tuple[Callable[..., Env], int]:
    if name not in _REGISTRY:
        raise ValueError(
            f"unknown env {name!r}; registered envs: {names()} (a task of your own registers when its "
            "module is imported: `mjxsuite ... --import MODULE`)"
        )
    factory, episode_length = _REGISTRY[name]
    if isinstance(factory, str):  # registered by name: import it now, once
        module, _, attr = factory.partition(":")
        factory = getattr(importlib.import_module(module), attr)
        _REGISTRY[name] = (factory, episode_length)
    return factory, episode_length
