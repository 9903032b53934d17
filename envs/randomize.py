"""Domain randomisation for MJX tasks: each env of a batch steps with its own model values.

`envs.randomize(env, {"body_mass:pole": (0.05, 0.2), "dof_damping:slider": ("x", 0.8, 1.2)})`
names a field of `mjx.Model` and an element of the MJCF model (`field:element`, the
element by its XML name; a `dof_` field by its joint's name), and gives

- `(low, high)`: the value is drawn uniformly from [low, high);
- `("x", low, high)`: the compiled value is multiplied by a factor drawn from [low, high);
- a number: the value is set to it (every env the same).

A field with several values per element (`actuator_gear`, `geom_size`, `body_inertia`)
takes a range on its component 0 (a motor's gain, a sphere's radius) unless `[i]` picks
another (`geom_size:pole[1]`); a scale multiplies the whole row.

The drawn values live in the state: `info["randomized"]` holds the drawn number of each
entry (the value, or the factor of a scale), `info["model"]` the model fields that
differ from the task's, which `step` puts into the model it passes to `mjx.step`. Under
`vmap` those leaves are batched, so `mjx.step` steps each env with its own model. Auto-reset
draws new values with each new episode (`per="episode"`), or keeps an env's first draw for
all its episodes (`per="env"`).

What MuJoCo's `mj_setConst` derives from a changed field is derived again, as it would
(checked against C MuJoCo in tests/test_randomize.py): a body's inertia scales with its
mass (the body keeps its shape and gets denser or lighter, as a uniform rod's inertia does),
and `body_subtreemass`, `body_invweight0`, `dof_invweight0`, `dof_M0`, `actuator_acc0`,
`tendon_invweight0` and `tendon_length0` are computed from the env's model at `qpos0`
(`stat`, which mj_setConst leaves alone, stays the compiled one). A geom's collision bounds (`geom_rbound`, `geom_aabb`)
grow with its largest size ratio, so broad-phase culling never misses it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from typing import TYPE_CHECKING, Any, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from envs.core import Env, State, Wrapper
from envs.wrappers import TimeLimit

if TYPE_CHECKING:  # mujoco and envs.mjx_env (mujoco.mjx) are imported where they are used: `import envs` stays fast
    import mujoco

    from envs.mjx_env import MjxEnv, mjx

PER = ("episode", "env")

# The element type (a `mujoco.mjtObj` member's name) each field prefix indexes (a dof_ field is named
# by its joint). Names, not the members: importing mujoco (most of it loading GLFW for rendering) would
# slow the start of every analytic task's run (docs/bench-gpu.json, "startup-imports").
ELEMENT_TYPES = {
    "body": "mjOBJ_BODY", "jnt": "mjOBJ_JOINT", "dof": "mjOBJ_JOINT", "geom": "mjOBJ_GEOM", "site": "mjOBJ_SITE",
    "cam": "mjOBJ_CAMERA", "light": "mjOBJ_LIGHT", "mat": "mjOBJ_MATERIAL", "pair": "mjOBJ_PAIR",
    "eq": "mjOBJ_EQUALITY", "tendon": "mjOBJ_TENDON", "actuator": "mjOBJ_ACTUATOR",
}
# Computed by the compiler or mj_setConst from other fields: randomise those instead.
DERIVED = frozenset({
    "body_subtreemass", "body_invweight0", "dof_invweight0", "dof_M0", "actuator_acc0", "tendon_invweight0",
    "tendon_length0", "geom_rbound", "geom_aabb", "cam_pos0", "cam_poscom0", "cam_mat0", "light_pos0",
    "light_poscom0", "light_dir0",
})
# Inputs of what mj_setConst computes at qpos0 (mass matrix, Jacobians, transmissions):
# randomising one of them recomputes the derived fields in every reset.
SETCONST_INPUTS = frozenset({
    "body_pos", "body_quat", "body_ipos", "body_iquat", "body_mass", "body_inertia", "jnt_pos", "jnt_axis",
    "dof_armature", "actuator_gear",
})
# Fields MuJoCo needs positive (masses, inertias, sizes) or non-negative (friction, damping,
# armature, stiffness): a range reaching outside would train on physics no model can have.
POSITIVE_FIELDS = frozenset({"body_mass", "body_inertia", "geom_size"})
NON_NEGATIVE_FIELDS = frozenset({
    "geom_friction", "geom_margin", "geom_gap", "dof_damping", "dof_armature", "dof_frictionloss", "jnt_stiffness",
    "tendon_damping", "tendon_stiffness", "tendon_frictionloss", "tendon_armature",
})
_NAME = re.compile(r"^(?P<field>\w+):(?P<element>[^\[\]]+)(\[(?P<column>\d+)\])?$")


@dataclasses.dataclass(frozen=True)
class Variation:
    """One entry of the ranges, resolved against the model."""

    name: str  # as the user wrote it, e.g. "body_mass:pole"
    field: str  # an mjx.Model field
    rows: tuple[int, ...]  # the element's rows (a joint's dofs for a dof_ field)
    column: int | None  # the component set by a range; None: the field has one value per element
    low: float
    high: float
    scale: bool  # multiply the compiled value by the draw, instead of setting it

    def apply(self, values: jax.Array, draw: jax.Array) -> jax.Array:
        rows = np.asarray(self.rows)
        if self.scale:
            return values.at[rows].multiply(draw.astype(values.dtype))
        index = (rows,) if self.column is None else (rows, self.column)
        return values.at[index].set(draw.astype(values.dtype))


def randomisable_fields(model: mjx.Model) -> list[str]:
    """The mjx.Model fields that can differ between envs in this model: float arrays over
    elements it has, which MJX keeps as JAX arrays (it compiles NumPy fields into the program)."""
    return sorted(
        f.name for f in dataclasses.fields(model)
        if f.name.split("_")[0] in ELEMENT_TYPES and f.name not in DERIVED
        and isinstance(value := getattr(model, f.name), jax.Array) and jnp.issubdtype(value.dtype, jnp.floating)
        and value.shape[0] > 0
    )


def parse_ranges(task: MjxEnv, ranges: Mapping[str, Any]) -> tuple[Variation, ...]:
    """The ranges checked against `task`'s model; errors name the entry and the valid choices."""
    if not isinstance(ranges, Mapping) or not ranges:
        raise ValueError(f"randomize needs a non-empty mapping 'field:element' -> range; got {ranges!r}")
    return tuple(_parse_entry(task, name, spec) for name, spec in ranges.items())


def _parse_entry(task: MjxEnv, name: str, spec: Any) -> Variation:
    model, mj_model = task.mjx_model, task.mj_model
    match = _NAME.match(str(name))
    if match is None:
        raise ValueError(f"randomize: {name!r} is not 'field:element' (e.g. 'body_mass:pole', 'geom_size:pole[1]')")
    field, element = match["field"], match["element"]
    valid = randomisable_fields(model)
    if field not in valid:
        if field in DERIVED:
            why = "is derived from other fields (by MuJoCo's compiler or mj_setConst); randomise those"
        elif isinstance(getattr(model, field, None), np.ndarray):
            why = "is a NumPy field of mjx.Model: MJX compiles its value into the program, so it cannot differ per env"
        else:
            why = "is not a float field of mjx.Model indexed by a named element"
        raise ValueError(f"randomize: {name!r}: {field!r} {why}; fields that can vary per env: {', '.join(valid)}")
    import mujoco

    prefix = field.split("_")[0]
    element_type = getattr(mujoco.mjtObj, ELEMENT_TYPES[prefix])
    element_id = mujoco.mj_name2id(mj_model, element_type, element)
    if element_id < 0:
        names = _element_names(mj_model, element_type)
        kind = "joint" if prefix == "dof" else ELEMENT_TYPES[prefix].removeprefix("mjOBJ_").lower()
        kinds = {"body": "bodies"}.get(kind, kind + "s")
        raise ValueError(f"randomize: {name!r}: the model has no {kind} named {element!r}; "
                         f"its {kinds}: {', '.join(names) or '(none with a name)'}")
    rows = _rows(mj_model, prefix, element_id)
    values = np.asarray(getattr(model, field))
    width = int(np.prod(values.shape[1:], dtype=int))
    if values.ndim > 2:
        raise ValueError(f"randomize: {name!r}: {field} has shape {values.shape[1:]} per element; "
                         "only fields with one value or one row per element can vary")
    column = None if values.ndim == 1 else int(match["column"] or 0)
    if column is not None and column >= width:
        raise ValueError(f"randomize: {name!r}: {field} has {width} components per element; [{column}] is out of range")
    if match["column"] is not None and values.ndim == 1:
        raise ValueError(f"randomize: {name!r}: {field} has one value per element; drop the [{match['column']}]")
    scale, low, high = _parse_range(name, spec)
    _check_domain(name, field, scale, low, high)
    if scale and match["column"] is None:
        column = None  # a scale multiplies the whole row
    elif scale:
        raise ValueError(f"randomize: {name!r}: a scale multiplies the whole row; drop the [{column}]")
    return Variation(str(name), field, rows, column, low, high, scale)


def _parse_range(name: str, spec: Any) -> tuple[bool, float, float]:
    """(scale?, low, high) from (low, high), ("x", low, high) or a number."""
    scale = isinstance(spec, (tuple, list)) and len(spec) == 3 and spec[0] == "x"
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        bounds = (spec, spec)
    elif isinstance(spec, (tuple, list)) and len(spec) == 2 + scale:
        bounds = spec[1:] if scale else spec
    else:
        bounds = None
    try:
        low, high = (float(b) for b in bounds)
    except (TypeError, ValueError):
        low = high = math.nan
    if not (math.isfinite(low) and math.isfinite(high) and low <= high):
        raise ValueError(f"randomize: {name!r}: expected (low, high), ('x', low, high) or a number with "
                         f"finite low <= high; got {spec!r}")
    return scale, low, high


def _check_domain(name: str, field: str, scale: bool, low: float, high: float) -> None:
    """Refuse a range that reaches values `field` cannot take (a scale: factors that would)."""
    if field in POSITIVE_FIELDS:
        valid, bad, what = "positive", low <= 0, "> 0"
    elif field in NON_NEGATIVE_FIELDS:
        valid, bad, what = "non-negative", low < 0, ">= 0"
    else:
        return
    if bad:
        values = f"scale factors x{low:g}:{high:g}" if scale else (f"{low:g}" if low == high else f"{low:g}:{high:g}")
        example = f"{name}=x0.5:1.5" if field in POSITIVE_FIELDS else f"{name}=0:{max(high, 1.0):g}"
        raise ValueError(f"randomize: {name!r}: {field} must be {valid}, and {values} reaches {low:g}; "
                         f"keep the low end {what}, e.g. {example}")


def _element_names(mj_model: mujoco.MjModel, kind: mujoco.mjtObj) -> list[str]:
    import mujoco

    count = {mujoco.mjtObj.mjOBJ_BODY: mj_model.nbody, mujoco.mjtObj.mjOBJ_JOINT: mj_model.njnt,
             mujoco.mjtObj.mjOBJ_GEOM: mj_model.ngeom, mujoco.mjtObj.mjOBJ_SITE: mj_model.nsite,
             mujoco.mjtObj.mjOBJ_CAMERA: mj_model.ncam, mujoco.mjtObj.mjOBJ_LIGHT: mj_model.nlight,
             mujoco.mjtObj.mjOBJ_MATERIAL: mj_model.nmat, mujoco.mjtObj.mjOBJ_PAIR: mj_model.npair,
             mujoco.mjtObj.mjOBJ_EQUALITY: mj_model.neq, mujoco.mjtObj.mjOBJ_TENDON: mj_model.ntendon,
             mujoco.mjtObj.mjOBJ_ACTUATOR: mj_model.nu}[kind]
    return [n for n in (mujoco.mj_id2name(mj_model, kind, i) for i in range(count)) if n]


def _rows(mj_model: mujoco.MjModel, prefix: str, element_id: int) -> tuple[int, ...]:
    import mujoco

    if prefix != "dof":
        return (element_id,)
    dofs = {mujoco.mjtJoint.mjJNT_FREE: 6, mujoco.mjtJoint.mjJNT_BALL: 3}.get(mj_model.jnt_type[element_id], 1)
    start = int(mj_model.jnt_dofadr[element_id])
    return tuple(range(start, start + dofs))


class Randomize(Wrapper):
    """An MJX task whose every env draws its own model values (see the module docstring).

    Wraps the task itself (`envs.randomize` puts it inside the registry's `TimeLimit`).
    Raises `ValueError` for an unknown field or element, or a field that cannot vary per env.
    """

    def __init__(self, env: MjxEnv, ranges: Mapping[str, Any], per: str = "episode"):
        from envs.mjx_env import MjxEnv  # here, not at the top: importing envs must not load MJX (start-up time)

        if not isinstance(env, MjxEnv):
            raise ValueError(f"randomize varies the model of an MJX task (an envs.MjxEnv); got {env!r}. Analytic "
                             "envs vary their physics by vmap over their physics dataclass instead")
        if per not in PER:
            raise ValueError(f"randomize: per={per!r}; choose one of {PER}")
        if env.impl != "jax":
            raise ValueError(f"randomize: task {env.name} steps with impl={env.impl!r}; per-env model values "
                             "run with impl='jax' only (per-env Warp models would need MJX's batch_sizes)")
        super().__init__(env)
        self.variations = parse_ranges(env, ranges)
        self.per = per
        # With per="env", auto-reset keeps these info entries (the env's draw) for every episode.
        # (A fresh episode's `reset` still runs with a fresh draw: only a task with
        # `reset_computes_derived` would see it, in its first observation.)
        self.info_kept_across_episodes = ("randomized", "model") if per == "env" else ()
        self._recompute_constants = any(v.field in SETCONST_INPUTS for v in self.variations)

    def draw(self, key: jax.Array) -> dict[str, jax.Array]:
        """One env's draw: the number each entry draws (a value, or a factor for a scale)."""
        dtype = self.env.mjx_model.opt.timestep.dtype
        keys = jax.random.split(key, len(self.variations))
        return {v.name: jax.random.uniform(k, (), dtype, v.low, v.high) for v, k in zip(self.variations, keys)}

    def model_fields(self, drawn: Mapping[str, jax.Array]) -> dict[str, Any]:
        """The mjx.Model fields `drawn` changes, the derived ones included."""
        base = self.env.mjx_model
        fields: dict[str, jax.Array] = {}
        for v in self.variations:
            fields[v.field] = v.apply(fields.get(v.field, getattr(base, v.field)), drawn[v.name])
        if "body_mass" in fields:
            fields["body_inertia"] = self._inertia_with_mass(base, fields)
        if "geom_size" in fields:
            fields.update(_collision_bounds(base, fields["geom_size"]))
        if self._recompute_constants:
            fields.update(set_const(base.replace(**fields), self.env._initial_data, self.env.mj_model))
        return fields

    def _inertia_with_mass(self, base: mjx.Model, fields: dict) -> jax.Array:
        """Inertia scaled with mass for bodies whose inertia is not randomised itself."""
        explicit = {row for v in self.variations if v.field == "body_inertia" for row in v.rows}
        keep = np.array([i in explicit for i in range(base.body_mass.shape[0])])
        ratio = jnp.where(base.body_mass > 0, fields["body_mass"] / jnp.where(base.body_mass > 0, base.body_mass, 1), 1)
        inertia = fields.get("body_inertia", base.body_inertia)
        return jnp.where(keep[:, None], inertia, inertia * ratio[:, None])

    def reset(self, key: jax.Array) -> State:
        draw_key, episode_key = jax.random.split(key)
        drawn = self.draw(draw_key)
        fields = self.model_fields(drawn)
        state = self.env.reset_with_model(episode_key, self.env.mjx_model.replace(**fields))
        return state.replace(info={**state.info, "randomized": drawn, "model": fields})

    def step(self, state: State, action: jax.Array) -> State:
        return self.env.step_with_model(state, action, self.env.mjx_model.replace(**state.info["model"]))

    def __repr__(self) -> str:
        ranges = {v.name: (("x", v.low, v.high) if v.scale else (v.low, v.high)) for v in self.variations}
        return f"Randomize({self.env!r}, {ranges}, per={self.per!r})"


def _collision_bounds(base: mjx.Model, size: jax.Array) -> dict[str, jax.Array]:
    """`geom_rbound` and the half-sizes of `geom_aabb` grown by each geom's largest size
    ratio: the new geom then fits inside its bounds (exact for a uniform scale)."""
    ratio = jnp.where(base.geom_size > 0, size / jnp.where(base.geom_size > 0, base.geom_size, 1), 1).max(axis=1)
    aabb = base.geom_aabb.at[:, 3:].multiply(ratio[:, None])
    return {"geom_rbound": base.geom_rbound * ratio, "geom_aabb": aabb}


def set_const(model: mjx.Model, data: mjx.Data, mj_model: mujoco.MjModel) -> dict[str, Any]:
    """What MuJoCo's `mj_setConst` derives from masses, inertias, geometry and transmissions,
    computed in JAX from `model` at `qpos0` (engine_setconst.c: setFixed, set0, setStat)."""
    import mujoco

    from envs.mjx_env import mjx  # here, not at the top: importing envs must not load MJX (start-up time)

    nv = mj_model.nv
    subtreemass = model.body_mass
    for body in range(mj_model.nbody - 1, 0, -1):  # children come after their parents
        subtreemass = subtreemass.at[mj_model.body_parentid[body]].add(subtreemass[body])
    data = data.replace(qpos=model.qpos0)
    data = mjx.kinematics(model, data)
    data = mjx.com_pos(model, data)
    data = mjx.crb(model, data)
    data = mjx.tendon(model, data)
    data = mjx.transmission(model, data)
    inertia = mjx.full_m(model, data)
    inverse = jnp.linalg.inv(inertia) if nv else inertia

    body_invweight0 = [jnp.zeros(2, inertia.dtype)]
    for body in range(1, mj_model.nbody):
        if mj_model.body_weldid[body] == 0:  # static
            body_invweight0.append(jnp.zeros(2, inertia.dtype))
        elif mj_model.body_simple[body] == 2:  # sliders only: no rotation, diagonal inertia
            body_invweight0.append(jnp.stack([1 / jnp.maximum(mujoco.mjMINVAL, model.body_mass[body]), 0.0]))
        else:
            jacp, jacr = mjx.jac(model, data, data.xipos[body], body)
            jacobian = jnp.concatenate([jacp.T, jacr.T])  # (6, nv)
            a = jacobian @ inverse @ jacobian.T
            body_invweight0.append(jnp.stack([jnp.trace(a[:3, :3]) / 3, jnp.trace(a[3:, 3:]) / 3]))

    dof_invweight0 = jnp.zeros(nv, inertia.dtype)
    for joint in range(mj_model.njnt):
        first, body = int(mj_model.jnt_dofadr[joint]), mj_model.jnt_bodyid[joint]
        kind = mj_model.jnt_type[joint]
        if mj_model.body_simple[body] == 2:
            dof_invweight0 = dof_invweight0.at[first].set(1 / jnp.maximum(mujoco.mjMINVAL, model.body_mass[body]))
        elif kind == mujoco.mjtJoint.mjJNT_FREE:
            diagonal = jnp.diag(inverse)[first:first + 6]
            dof_invweight0 = dof_invweight0.at[first:first + 3].set(diagonal[:3].mean())
            dof_invweight0 = dof_invweight0.at[first + 3:first + 6].set(diagonal[3:].mean())
        elif kind == mujoco.mjtJoint.mjJNT_BALL:
            dof_invweight0 = dof_invweight0.at[first:first + 3].set(jnp.diag(inverse)[first:first + 3].mean())
        else:
            dof_invweight0 = dof_invweight0.at[first].set(inverse[first, first])

    moment = data._impl.actuator_moment  # (nu, nv); Randomize runs impl="jax" only
    fields = {
        "body_subtreemass": subtreemass,
        "body_invweight0": jnp.stack(body_invweight0),
        "dof_invweight0": dof_invweight0,
        "dof_M0": jnp.diag(inertia),  # armature + cdof . (crb cdof): the CRB diagonal
        "actuator_acc0": jnp.linalg.norm(moment @ inverse, axis=-1),
    }  # mj_setConst leaves `stat` (meaninertia, meanmass...) as the compiler set it; so do we
    if mj_model.ntendon:
        ten_j = data._impl.ten_J
        fields["tendon_invweight0"] = jnp.einsum("ti,ij,tj->t", ten_j, inverse, ten_j)
        fields["tendon_length0"] = data.ten_length
    return fields


def randomize(env: Env, ranges: Mapping[str, Any], per: str = "episode") -> Env:
    """`env` (an MJX task, as `envs.make` returns it) with each env's model values drawn
    from `ranges` (see this module's docstring): at every reset (`per="episode"`) or once
    per env (`per="env"`)."""
    from envs.mjx_env import MjxEnv  # here, not at the top: importing envs must not load MJX (start-up time)

    if isinstance(env, TimeLimit) and isinstance(env.env, MjxEnv):
        return TimeLimit(Randomize(env.env, ranges, per), env.episode_length)
    return Randomize(env, ranges, per)
