"""MuJoCo's solver options (`opt`), an `envs.make` override of every MJX task.

`opt` maps `mujoco.MjOption` field names to values: `envs.make("cartpole-mjx", opt={"iterations": 4})`,
or `--env-opt opt.iterations=4` on the command line. Enum fields take MuJoCo's names, case-insensitive
(`solver="Newton"`, `integrator="implicitfast"`, `cone="elliptic"`) or their integer values. The
options are written into a copy of the task's `MjModel` before MJX's model and data are made, so
both implementations, `envs.randomize` and everything reading `env.mj_model` see them. They are
checked in `envs.make`, before anything compiles. (MuJoCo Warp's buffer sizes, the other MJX
overrides: `envs.mjx_warp`; the command line's text for them: `agents.env_options`.)
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from envs.ranges import COUNT, NON_NEGATIVE, NON_NEGATIVE_COUNT, POSITIVE, Range

if TYPE_CHECKING:  # mujoco is imported where it is used: importing it (most of it loading GLFW for rendering)
    import mujoco  # would slow the start of every analytic task's run (docs/bench-gpu.json, "startup-imports")

# MjOption's enum fields, the name of their MuJoCo enum and its members' prefix (names are matched without it).
ENUMS = {
    "integrator": ("mjtIntegrator", "mjINT_"),
    "cone": ("mjtCone", "mjCONE_"),
    "solver": ("mjtSolver", "mjSOL_"),
    "jacobian": ("mjtJacobian", "mjJAC_"),
}
# Numeric fields whose range is narrower than "a finite number" (the others: any finite value).
RANGES = {
    "timestep": POSITIVE, "iterations": COUNT, "ls_iterations": COUNT, "noslip_iterations": NON_NEGATIVE_COUNT,
    "ccd_iterations": COUNT, "sdf_iterations": COUNT, "sdf_initpoints": COUNT,
    "tolerance": NON_NEGATIVE, "ls_tolerance": NON_NEGATIVE, "noslip_tolerance": NON_NEGATIVE,
    "ccd_tolerance": NON_NEGATIVE, "sleep_tolerance": NON_NEGATIVE, "impratio": POSITIVE,
    "density": NON_NEGATIVE, "viscosity": NON_NEGATIVE,
    "disableflags": NON_NEGATIVE_COUNT, "enableflags": NON_NEGATIVE_COUNT, "disableactuator": NON_NEGATIVE_COUNT,
}


@functools.cache
def opt_defaults() -> dict[str, Any]:
    """Every MjOption field with MuJoCo's default (its type tells the kind of value)."""
    import mujoco

    option = mujoco.MjOption()
    return {name: getattr(option, name) for name in dir(option) if not name.startswith("_")}


def opt_fields() -> tuple[str, ...]:
    return tuple(sorted(opt_defaults()))


def _enum(field: str) -> tuple[Any, str]:
    """An enum field's MuJoCo enum and its members' prefix."""
    import mujoco

    name, prefix = ENUMS[field]
    return getattr(mujoco, name), prefix


def enum_names(field: str) -> list[str]:
    enum, prefix = _enum(field)
    return [name.removeprefix(prefix).lower() for name in dir(enum) if name.startswith(prefix)]


def check_opt(opt: Mapping[str, Any] | None, task: str = "task") -> dict[str, Any]:
    """`opt` as the values MjOption takes (enum names as their integers), after checking every field
    and value; ValueError names the option, the value and what is valid."""
    if opt is None:
        return {}
    if not isinstance(opt, Mapping):
        raise ValueError(f"{task}: opt must be a mapping of mujoco.MjOption fields to values, e.g. "
                         f"opt={{'iterations': 4}}; got {opt!r}")
    unknown = sorted(set(opt) - set(opt_fields()))
    if unknown:
        raise ValueError(f"{task}: unknown opt field(s) {unknown}; valid fields (mujoco.MjOption): {list(opt_fields())}")
    return {field: _check_value(field, value, task) for field, value in opt.items()}


def _check_value(field: str, value: Any, task: str) -> Any:
    default = opt_defaults()[field]
    where = f"{task}: opt.{field}"
    if field in ENUMS:
        enum, prefix = _enum(field)
        names = enum_names(field)
        if isinstance(value, str) and value.lower() in names:
            return int(getattr(enum, prefix + value.upper()))
        members = [int(e) for e in enum.__members__.values()]  # a pybind enum type is not iterable
        if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and int(value) in members:
            return int(value)
        raise ValueError(f"{where} must be one of {names} (case-insensitive) or its integer value, got {value!r}")
    if isinstance(default, np.ndarray):
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            array = None
        if array is None or array.shape != default.shape or not np.isfinite(array).all():
            raise ValueError(f"{where} must be {default.size} finite numbers (default {default.tolist()}), got {value!r}")
        return array
    valid = RANGES.get(field, Range())
    if isinstance(default, int):
        valid = dataclasses.replace(valid, integer=True)
    return valid.check(where, value)


def apply_opt(mj_model: mujoco.MjModel, opt: Mapping[str, Any]) -> mujoco.MjModel:
    """A copy of `mj_model` with the checked `opt` (from `check_opt`) written into its `opt`;
    `mj_model` itself (which other envs may share) is left as it is."""
    model = copy.copy(mj_model)  # MjModel's copy is a full copy
    for field, value in opt.items():
        if isinstance(value, np.ndarray):
            getattr(model.opt, field)[:] = value
        else:
            setattr(model.opt, field, value)
    return model

