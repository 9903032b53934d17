"""The Q-network's MLP as one Pallas kernel forward and one backward, for the GPU.

With many agents vmapped on a GPU, each layer's activations going to memory and back between
kernels were over half of a DQN iteration (docs/results.md, "DQN on the GPU"). Here none leaves the
chip: the forward kernel carries each block of rows through every layer; the backward kernel, one
program per agent, recomputes them block by block and adds up the gradients in registers. Sizes are
padded with zeros to powers of two (Triton's tiles), which keeps the padded units at exactly zero;
the products run at XLA's default GPU precision. On the CPU `interpret=True` runs the same kernels.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as plgpu

ROWS_PER_BLOCK = 64  # rows per forward program and per backward loop step
# The widest layer (padded) the kernels take: wider blocks overflow the registers and XLA wins (docs/results.md).
MAX_WIDTH = 64


def _pow2(n: int, minimum: int = 16) -> int:
    return max(minimum, 1 << (n - 1).bit_length())


def fits(observation_size: int, hidden, num_actions: int) -> bool:
    """Whether a network of these sizes is narrow enough for the kernels (`MAX_WIDTH`)."""
    return max(_pow2(n) for n in (observation_size, *hidden, num_actions)) <= MAX_WIDTH


def layers_of(params) -> list[tuple[jax.Array, jax.Array]]:
    """A Flax `QNetwork`'s (kernel, bias) pairs, input layer first."""
    dense = params["params"]
    return [(dense[f"Dense_{i}"]["kernel"], dense[f"Dense_{i}"]["bias"]) for i in range(len(dense))]


def _padded(layers, x):
    """The kernels' operands padded with zeros: the rows of `x` and the (kernel, bias) pairs flattened;
    then the rows per block and the padded output width."""
    flat = []
    for kernel, bias in layers:
        fan_in, fan_out = kernel.shape
        shape = (_pow2(fan_in), _pow2(fan_out))
        flat += [jnp.pad(kernel, ((0, shape[0] - fan_in), (0, shape[1] - fan_out))),
                 jnp.pad(bias, (0, shape[1] - fan_out))[None, :]]
    rows = x.shape[0]
    block = min(ROWS_PER_BLOCK, _pow2(rows))
    xp = jnp.pad(x, ((0, _pow2(rows, block) - rows), (0, flat[0].shape[0] - x.shape[1])))
    return xp, flat, block, flat[-2].shape[1]


def _forward_kernel(num_layers, x_ref, *refs):
    """One block of rows through every layer."""
    weights, q_ref = refs[: 2 * num_layers], refs[2 * num_layers]
    h = x_ref[...]
    for layer in range(num_layers):
        h = plgpu.dot(h, weights[2 * layer][...]) + weights[2 * layer + 1][...]
        if layer < num_layers - 1:
            h = jnp.maximum(h, 0.0)
    q_ref[...] = h


def _backward_kernel(num_layers, block, x_ref, *refs):
    weights, dq_ref = refs[: 2 * num_layers], refs[2 * num_layers]
    grad_refs, dx_ref = refs[2 * num_layers + 1 : 4 * num_layers + 1], refs[4 * num_layers + 1]

    def body(i, grads):
        rows = pl.ds(pl.multiple_of(i * block, block), block)
        inputs = [x_ref[rows, :]]  # each layer's input, recomputed
        for layer in range(num_layers - 1):
            h = plgpu.dot(inputs[-1], weights[2 * layer][...]) + weights[2 * layer + 1][...]
            inputs.append(jnp.maximum(h, 0.0))
        g = dq_ref[rows, :]  # gradient at the current layer's output
        grads = list(grads)
        for layer in reversed(range(num_layers)):
            grads[2 * layer] += plgpu.dot(inputs[layer], g, trans_a=True)
            grads[2 * layer + 1] += jnp.sum(g, axis=0, keepdims=True)
            g = plgpu.dot(g, weights[2 * layer][...], trans_b=True)
            if layer > 0:
                g = jnp.where(inputs[layer] > 0, g, 0.0)
        dx_ref[rows, :] = g
        return tuple(grads)

    # The gradients add up in registers and are written once.
    zeros = tuple(jnp.zeros(ref.shape, ref.dtype) for ref in grad_refs)
    grads = jax.lax.fori_loop(0, x_ref.shape[0] // block, body, zeros)
    for ref, grad in zip(grad_refs, grads):
        ref[...] = grad


def _compiler_params(kernels):
    """4 warps for the widths the kernels are used at (`MAX_WIDTH`; the fastest on a GPU), 8 for wider ones."""
    return plgpu.CompilerParams(num_warps=4 if max(max(k.shape) for k in kernels) <= MAX_WIDTH else 8, num_stages=1)


@partial(jax.custom_vjp, nondiff_argnums=(2,))
def _mlp(layers, x, interpret):
    xp, flat, block, width = _padded(layers, x)
    q = pl.pallas_call(  # one program per block of rows
        partial(_forward_kernel, len(layers)),
        out_shape=jax.ShapeDtypeStruct((xp.shape[0], width), x.dtype),
        grid=(xp.shape[0] // block,),
        in_specs=[pl.BlockSpec((block, xp.shape[1]), lambda i: (i, 0))]
        + [pl.BlockSpec(a.shape, lambda i: (0, 0)) for a in flat],
        out_specs=pl.BlockSpec((block, width), lambda i: (i, 0)),
        interpret=interpret, compiler_params=_compiler_params(flat[::2]),
    )(xp, *flat)
    return q[: x.shape[0], : layers[-1][0].shape[1]]


def _mlp_fwd(layers, x, interpret):
    return _mlp(layers, x, interpret), (layers, x)


def _mlp_bwd(interpret, saved, dq):
    layers, x = saved
    xp, flat, block, width = _padded(layers, x)
    dqp = jnp.pad(dq, ((0, xp.shape[0] - dq.shape[0]), (0, width - dq.shape[1])))
    out = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in flat] + [jax.ShapeDtypeStruct(xp.shape, x.dtype)]
    *grads, dx = pl.pallas_call(partial(_backward_kernel, len(layers), block), out_shape=out, interpret=interpret,
                                compiler_params=_compiler_params(flat[::2]))(xp, *flat, dqp)
    layer_grads = [(dk[: k.shape[0], : k.shape[1]], db[0, : b.shape[0]])
                   for (k, b), dk, db in zip(layers, grads[::2], grads[1::2])]
    return layer_grads, dx[: x.shape[0], : x.shape[1]]


_mlp.defvjp(_mlp_fwd, _mlp_bwd)


def q_values(params, obs: jax.Array, interpret: bool = False) -> jax.Array:
    """A plain (non-dueling) `QNetwork`'s output for `obs` (one observation or a batch)."""
    batch = obs.reshape(-1, obs.shape[-1])
    q = _mlp(layers_of(params), batch, interpret)
    return q.reshape(obs.shape[:-1] + q.shape[-1:])
