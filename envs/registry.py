"""Environments by name, with keyword overrides checked against what each env accepts."""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any, Callable

from envs.core import Env
from envs.ranges import COUNT, check_fields
from envs.wrappers import TimeLimit

_REGISTRY: dict[str, tuple[Callable[..., Env], int]] = {}


def register(name: str, factory: Callable[..., Env], episode_length: int = 1000) -> None:
    """Make `factory` available as `envs.make(name)`.

    `factory`'s keyword arguments become overrides; an argument whose default is a
    dataclass (e.g. physics constants) also accepts each of its fields by name.
    """
    if name in _REGISTRY:
        raise ValueError(f"an env named {name!r} is already registered ({_REGISTRY[name][0]!r})")
    _REGISTRY[name] = (factory, episode_length)


def names() -> list[str]:
    return sorted(_REGISTRY)


def options(name: str) -> dict[str, Any]:
    """Every override `make(name, ...)` accepts, with its default."""
    factory, episode_length = _lookup(name)
    found: dict[str, Any] = {"episode_length": episode_length}
    for param in inspect.signature(factory).parameters.values():
        if param.default is inspect.Parameter.empty:
            continue
        found[param.name] = param.default
        if dataclasses.is_dataclass(param.default):
            for field in dataclasses.fields(param.default):
                found[field.name] = getattr(param.default, field.name)
    return found


def make(name: str, **overrides: Any) -> Env:
    """Build a registered env, its episodes limited to `episode_length` steps (truncation)."""
    factory, _ = _lookup(name)
    valid = options(name)
    unknown = sorted(set(overrides) - set(valid))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for env {name!r}; valid options: {sorted(valid)}")
    episode_length = COUNT.check("episode_length", overrides.pop("episode_length", valid["episode_length"]))
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
    return TimeLimit(factory(**kwargs), episode_length)


def _lookup(name: str) -> tuple[Callable[..., Env], int]:
    if name not in _REGISTRY:
        raise ValueError(
            f"unknown env {name!r}; registered envs: {names()} (a task of your own registers when its "
            "module is imported: `mjxsuite ... --import MODULE`)"
        )
    return _REGISTRY[name]
