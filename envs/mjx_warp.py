"""MuJoCo Warp under an MJX task (impl="warp"): its buffers, its batch of worlds, its overflow flags.

- `WarpBuffers`: the contact pool and constraint rows a task's worlds get (`nconmax`, `naconmax`,
  `njmax`, the `envs.make` overrides), sized from the model by default.
- `WarpWorlds`: one task's step under Warp. Warp keeps some buffers once for a whole batch; an
  env's state leaves them out, and every `vmap` over the step folds its axis into one world axis,
  so the step runs MJX once on all worlds with a pool sized for all of them.
- The overflow flags: a step on which Warp ran out of contacts or constraint rows is not physics;
  `WarpWorlds.overflow` gives `info["overflow"]`'s code (`OVERFLOW_CONTACTS`, `OVERFLOW_CONSTRAINTS`).

Nothing here imports mujoco or mujoco.mjx at the top: the command line catches `WarpUnavailable`
and reads `BUFFER_OPTIONS` without loading MJX (seconds of start-up for an analytic task).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import threading
from typing import TYPE_CHECKING, Any, Callable, Mapping

import jax
import jax.numpy as jnp

from envs.batching import all_batched, broadcast, folds_vmap
from envs.ranges import COUNT

if TYPE_CHECKING:
    import mujoco
    from mujoco import mjx

BUFFER_OPTIONS = ("nconmax", "naconmax", "njmax")

# MuJoCo Warp's per-world overflow bits (`OverflowType` in mujoco_warp's types.py), by the buffer whose
# override fixes them. Its other bits (solver iteration limits, the EPA horizon) say a result is less
# precise, not that contacts or constraints were dropped, and do not end an episode.
CONTACT_OVERFLOW = 4 | 8 | 16  # BROADPHASE, NARROWPHASE, CCD: the contact pool (nconmax / naconmax)
CONSTRAINT_OVERFLOW = 1 | 2  # NEFC, NJMAX_NNZ: the constraint rows of one world (njmax)
# info["overflow"] codes: which buffer ran out on a step (both: their sum).
OVERFLOW_CONTACTS, OVERFLOW_CONSTRAINTS = 1.0, 2.0


def either_overflow(first: jax.Array, second: jax.Array) -> jax.Array:
    """The code of two pieces of Warp work taken together: each buffer that ran out in either."""
    return jnp.maximum(first % 2, second % 2) + 2 * jnp.maximum(first // 2, second // 2)


def import_mjx():
    """`mujoco.mjx`, without the "Failed to import warp" line MJX prints when the optional
    warp-lang is absent (impl="jax" needs no Warp, so the line would only alarm the user)."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx
    return mjx


def runs_warp(env: Any) -> bool:
    """Whether `env`'s physics runs on MuJoCo Warp (impl="warp")."""
    return getattr(getattr(env, "unwrapped", env), "impl", None) == "warp"


class CompileRules:
    """What MuJoCo Warp's CUDA graphs ask of a run whose env it steps (`on_warp`), in one place;
    a run of any other env takes the defaults. The incidents behind each rule are in docs/mjx.md,
    "MuJoCo Warp and CUDA graphs".
    - `tracing()`: Warp runs compile their programs only once every program is traced (tracing
      loads Warp's modules onto the GPU), and nothing runs beside a compile; elsewhere programs
      compile on other threads while this one traces the next.
    - `evaluate_before_final_save`: elsewhere the final evaluation is dispatched before the final
      save, so the save's copy to the host runs while the devices evaluate; on Warp the save comes
      first, since a copy while the evaluation's first run captures a CUDA graph breaks the capture.
    - `host_copy_beside`: elsewhere a save's copy to the host is made on the writing thread; on
      Warp on the run's thread, between kernels."""

    def __init__(self, on_warp: bool):
        self.on_warp = on_warp
        self.evaluate_before_final_save = self.host_copy_beside = not on_warp

    @contextlib.contextmanager
    def tracing(self):
        """The event the background compiles wait for (`agents.run._in_background`'s `after`):
        set once this block has traced every program. None off Warp: nothing waits."""
        traced = threading.Event()
        try:
            yield traced if self.on_warp else None
        finally:
            traced.set()


class WarpUnavailable(RuntimeError):
    """impl='warp' was asked for on a machine that cannot run MuJoCo Warp (`require_warp`)."""


def require_warp() -> None:
    """Raise a clear error unless MJX can step with MuJoCo Warp here: it needs warp-lang
    (the `mjxsuite[warp]` extra) and an NVIDIA GPU that JAX uses (CUDA)."""
    import_mjx()
    from mujoco.mjx import warp as mjx_warp

    missing = []
    if not mjx_warp.WARP_INSTALLED:
        missing.append("warp-lang is not installed (pip install 'mjxsuite[warp]')")
    platforms = sorted({device.platform for device in jax.devices()})
    if "gpu" not in platforms or not _jax_has_cuda():
        missing.append(f"JAX sees no CUDA GPU (devices: {', '.join(platforms)})")
    if missing:
        raise WarpUnavailable("impl='warp' steps MJX with MuJoCo Warp, which needs an NVIDIA GPU and warp-lang: "
                              + "; ".join(missing) + ". Use impl='jax' (the default, any device) here.")
    quiet_warp()


def quiet_warp() -> None:
    """Warp's log at warnings and errors, where it is at Warp's default (info): that prints a line
    for every kernel module it loads or compiles, dozens before a run's first step. A log level
    set by the user is kept."""
    import warp

    if getattr(warp.config, "log_level", None) == getattr(warp, "LOG_INFO", 20):
        warp.config.log_level = warp.LOG_WARNING


def _jax_has_cuda() -> bool:
    try:
        return bool(jax.devices("cuda"))
    except RuntimeError:  # no CUDA backend in this JAX
        return False


# ---- the buffers ---------------------------------------------------------------------------------
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
    mjx = import_mjx()
    try:
        data = mjx.make_data(mjx.put_model(mj_model, impl="jax"))
        return max(1, int(data.contact.dist.shape[0])), max(1, int(data._impl.efc_J.shape[0]))
    except NotImplementedError:
        data = mjx.make_data(mj_model, impl="warp")  # one world: its pool is one world's contacts
        return int(data._impl.naconmax), int(data._impl.njmax)


def put_model_and_data(mj_model: mujoco.MjModel, mjx_model: mjx.Model,
                       buffers: WarpBuffers) -> tuple[mjx.Model, mjx.Data]:
    """The Warp model (its overflow warnings off) and one world's initial data at `buffers`' sizes."""
    mjx = import_mjx()
    # Warp prints a line per overflowing kernel launch (thousands a second); the env flags the
    # step instead (info["overflow"]) and the training driver says once which buffer to raise.
    mjx_model = mjx_model.replace(opt=mjx_model.opt.replace(_impl=mjx_model.opt._impl.replace(warn_overflow=0)))
    # MJX builds Warp data from the MuJoCo model itself (it refuses an mjx.Model there).
    data = mjx.make_data(mj_model, impl="warp", naconmax=buffers.pool(1), njmax=buffers.njmax)
    return mjx_model, data


# ---- the batch of worlds -------------------------------------------------------------------------
def shared_buffers(data: mjx.Data) -> dict[str, jax.Array]:
    """The arrays of Warp `data` that all worlds of a batch share (MJX's `DATA_NON_VMAP`)."""
    import_mjx()
    from mujoco.mjx.warp.types import DATA_NON_VMAP

    return {name: value for name in sorted(DATA_NON_VMAP) if isinstance(value := getattr(data._impl, name), jax.Array)}


class WarpWorlds:
    """One MJX task's physics under MuJoCo Warp, for a single env's state inside any batching.

    Warp keeps some buffers once for all worlds of a batch: the contact pool (leading dim
    `naconmax`), `nacon`, `ncollision` and constant index tables (MJX's `DATA_NON_VMAP`; `vmap`
    passes them through without a batch axis). They carry nothing from one step to the next
    (collision detection refills them), so an env's state leaves them out (`without_shared`) and
    `run` hands MJX fresh ones. Every leaf of a state then has the batch axis, and auto-reset, a
    vmapped seed axis, a while loop with a batched condition, sharding and checkpoints treat it
    like any other state.

    The pool must hold the contacts of every world the step runs on, and that number is only
    known where `vmap` batches the step (once per env, again per seed, ...). So `run` is a
    `custom_vmap` function: each vmap over it folds its axis into one world axis, and the step at
    the bottom runs MJX once on all worlds (MJX's Warp step takes a leading world axis) with a pool
    of `nconmax` contacts per world.
    """

    def __init__(self, mjx_model: mjx.Model, data: mjx.Data, buffers: WarpBuffers, task: str = "task"):
        self.mjx_model, self.buffers, self.task = mjx_model, buffers, task
        self.shared = shared_buffers(data)

    def run(self, physics: Callable[[mjx.Model, mjx.Data], mjx.Data], model: mjx.Model,
            data: mjx.Data) -> mjx.Data:
        """`physics(model, data)` (the substeps, or mjx.forward) on one env's state."""
        if model is not self.mjx_model:
            raise ValueError(f"task {self.task}: impl='warp' steps the task's own model; per-env model values "
                             "(envs.randomize) run with impl='jax'")

        # every leaf has a leading world axis; a vmap over it folds its axis into the worlds'
        step_worlds = folds_vmap(lambda data: self._step_worlds(physics, data))

        @jax.custom_batching.custom_vmap
        def step_one(data):
            return jax.tree.map(lambda x: x[0], step_worlds(jax.tree.map(lambda x: x[None], data)))

        @step_one.def_vmap
        def step_one_batched(axis_size, in_batched, data):
            out = step_worlds(broadcast(data, in_batched[0], axis_size))
            return out, all_batched(out)

        return step_one(data)

    def _step_worlds(self, physics, data: mjx.Data) -> mjx.Data:
        """`physics` on the worlds along `data`'s leading axis, with a contact pool for all of them;
        the result in the state's form (no shared buffers, the state's sizes)."""
        worlds = data.qpos.shape[0]
        pool = self.buffers.pool(worlds)
        template_pool = self.buffers.pool(1)
        shared = {name: jnp.broadcast_to(buffer[:1], (pool,) + buffer.shape[1:])  # every slot starts alike
                  if name.startswith("contact__") and buffer.shape[:1] == (template_pool,) else buffer
                  for name, buffer in self.shared.items()}
        impl = data._impl.replace(**shared, naconmax=pool, naccdmax=pool,
                                  overflow=jnp.zeros_like(data._impl.overflow))  # Warp's flags stick until cleared
        out = physics(self.mjx_model, data.replace(_impl=impl))
        return out.replace(_impl=out._impl.replace(**dict.fromkeys(shared), naconmax=data._impl.naconmax,
                                                   naccdmax=data._impl.naccdmax))

    def without_shared(self, data: mjx.Data) -> mjx.Data:
        """`data` in a state's form: the buffers the batch shares left out."""
        return data.replace(_impl=data._impl.replace(**dict.fromkeys(self.shared)))

    @staticmethod
    def overflow(data: mjx.Data) -> jax.Array:
        """info["overflow"]'s code for the step that gave `data`: which buffer ran out (0: none)."""
        bits = data._impl.overflow
        return (OVERFLOW_CONTACTS * ((bits & CONTACT_OVERFLOW) != 0)
                + OVERFLOW_CONSTRAINTS * ((bits & CONSTRAINT_OVERFLOW) != 0)).astype(jnp.float32)

