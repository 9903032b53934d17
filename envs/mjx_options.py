"""MuJoCo's solver options (`opt`) and MuJoCo Warp's buffer sizes, as `envs.make` overrides of an MJX task.

`opt` maps `mujoco.MjOption` field names to values: `envs.make("cartpole-mjx", opt={"iterations": 4})`,
or `--env-opt opt.iterations=4` on the command line. Enum fields take MuJoCo's names, case-insensitive
(`solver="Newton"`, `integrator="implicitfast"`, `cone="elliptic"`) or their integer values. The
options are written into a copy of the task's `MjModel` before MJX's model and data are made, so
both implementations, `envs.randomize` and everything reading `env.mj_model` see them.

`nconmax`, `naconmax` and `njmax` size MuJoCo Warp's contact and constraint buffers (impl="warp");
see `WarpBuffers`. Everything here is checked in `envs.make`, before anything compiles.
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
        if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and int(value) in [int(e) for e in enum]:
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


def parse_opt_field(field: str, text: str, task: str = "task") -> Any:
    """One `opt` field from the command line (`--env-opt opt.FIELD=TEXT`): an enum by name, a vector
    as comma-separated numbers, an integer or a float by the field's type."""
    if field not in opt_defaults():
        raise ValueError(f"{task}: unknown opt field {field!r}; valid fields (mujoco.MjOption): {list(opt_fields())}")
    default = opt_defaults()[field]
    try:
        if field in ENUMS:
            return int(text) if text.lstrip("-").isdigit() else text
        if isinstance(default, np.ndarray):
            return [float(part) for part in text.replace(",", " ").split()]
        return int(text) if isinstance(default, int) else float(text)
    except ValueError:
        raise ValueError(f"{task}: bad value {text!r} for opt.{field} (default {_shown(default)})") from None


def _shown(value: Any) -> Any:
    return value.tolist() if isinstance(value, np.ndarray) else value


# ---- MuJoCo Warp's buffers ---------------------------------------------------------------------------
BUFFER_OPTIONS = ("nconmax", "naconmax", "njmax")


class WarpUnavailable(RuntimeError):
    """impl='warp' was asked for on a machine that cannot run MuJoCo Warp (raised by
    `envs.mjx_env.require_warp`; defined here so the CLI catches it without importing mujoco.mjx)."""


@dataclasses.dataclass(frozen=True)
class WarpBuffers:
    """MuJoCo Warp's contact and constraint buffers for one task.

    - `nconmax`: contacts per env. MJX keeps one contact pool for all worlds of a batch; its size
      (`naconmax`) is `nconmax` times the number of envs the step runs on, found when the step is
      traced (every `vmap`, nested or not), so one env serves a batch of any size.
    - `naconmax`: the whole pool, whatever the batch (MJX's own meaning); overrides `nconmax`.
    - `njmax`: constraint rows (contacts' friction directions, joint limits, equalities) per env.

    The defaults (`for_model`) are what MJX's JAX implementation allocates for the same model: it
    keeps a slot for every contact and every constraint row the model can ever have, so a
    batch at these sizes does not overflow unless Warp finds more contacts for a geom pair than
    the JAX implementation's bound (meshes). MuJoCo Warp's own defaults (48 contacts for the whole
    batch, 64 rows) overflow on half_cheetah.xml at the first step of 4,096 envs.
    """

    nconmax: int
    njmax: int
    naconmax: int | None = None

    @classmethod
    def for_model(cls, mj_model: mujoco.MjModel, nconmax: int | None = None, naconmax: int | None = None,
                  njmax: int | None = None) -> WarpBuffers:
        if nconmax is None or njmax is None:
            default_ncon, default_nefc = contact_and_constraint_bounds(mj_model)
            nconmax = default_ncon if nconmax is None else nconmax
            njmax = default_nefc if njmax is None else njmax
        return cls(nconmax=nconmax, njmax=njmax, naconmax=naconmax)

    def pool(self, worlds: int) -> int:
        """The contact pool for a batch of `worlds` envs (at least 1 slot: Warp needs an array)."""
        return max(1, self.naconmax if self.naconmax is not None else self.nconmax * worlds)


def check_buffer_sizes(sizes: Mapping[str, Any], task: str = "task") -> dict[str, int | None]:
    """`nconmax`, `naconmax`, `njmax` as given to envs.make (None: derived from the model)."""
    checked = {}
    for name in BUFFER_OPTIONS:
        value = sizes.get(name)
        if value is not None:
            COUNT.check(f"{task}: {name}", value)
        checked[name] = value
    return checked


def contact_and_constraint_bounds(mj_model: mujoco.MjModel) -> tuple[int, int]:
    """The most contacts and constraint rows one world of `mj_model` can have, as MJX's JAX
    implementation allocates them (every candidate geom pair's most contacts, every row). For a
    model the JAX implementation cannot run: MuJoCo Warp's own guesses for one world."""
    from envs.mjx_env import mjx  # here, not at the top: mujoco.mjx takes seconds to import (start-up time)

    try:
        data = mjx.make_data(mjx.put_model(mj_model, impl="jax"))
        return max(1, int(data.contact.dist.shape[0])), max(1, int(data._impl.efc_J.shape[0]))
    except NotImplementedError:
        data = mjx.make_data(mj_model, impl="warp")  # one world: its pool is one world's contacts
        return int(data._impl.naconmax), int(data._impl.njmax)
