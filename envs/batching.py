"""`folds_vmap`: a function of a batch (a leading axis) that every `vmap` over it widens rather than
repeats. Under `vmap`, its axis is folded into the batch's, and the function runs once on the
whole: MuJoCo Warp steps all worlds of all seeds as one batch (`envs.mjx_warp.WarpWorlds`), and an
auto-reset decides once for every env of every seed whether any episode ended
(`envs.wrappers.BatchedAutoReset`), where a `vmap` of a `lax.switch` would run all its branches.

`one_after_another`: the `vmap` of a function, run as a `lax.map` (the CPU's way around jaxlib's batched
linear algebra)."""

from __future__ import annotations

from typing import Any, Callable

import jax
import jax.numpy as jnp


def folds_vmap(batch_fn: Callable[[Any], Any]) -> Callable[[Any], Any]:
    """`batch_fn` (a pytree whose every leaf has a leading batch axis -> the same), such that a
    `vmap` over it calls `batch_fn` once with the vmapped axis folded into the batch axis."""

    @jax.custom_batching.custom_vmap
    def run(tree):
        return batch_fn(tree)

    @run.def_vmap
    def run_vmapped(axis_size, in_batched, tree):
        tree = broadcast(tree, in_batched[0], axis_size)  # (axis, batch, ...)
        batch = jax.tree.leaves(tree)[0].shape[1]
        out = run(jax.tree.map(lambda x: x.reshape((axis_size * batch,) + x.shape[2:]), tree))
        return jax.tree.map(lambda x: x.reshape((axis_size, batch) + x.shape[1:]), out), all_batched(out)

    return run


def broadcast(tree, batched, axis_size: int):
    """Every leaf of `tree` with the leading `axis_size` axis (unbatched leaves repeated)."""
    return jax.tree.map(lambda x, b: x if b else jnp.broadcast_to(x, (axis_size,) + jnp.shape(x)), tree, batched)


def all_batched(tree):
    return jax.tree.map(lambda _: True, tree)


def one_after_another(fn: Callable) -> Callable:
    """`fn` over a leading axis of all its arguments, as `vmap` but one element after another (`lax.map`): where
    on the CPU jaxlib 0.10's batched linear algebra (QR, Cholesky) waits on XLA's thread pool from inside it, so a
    program running two such calls at once may wait forever."""
    return lambda *args: jax.lax.map(lambda one: fn(*one), args)
