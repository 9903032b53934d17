"""The Q-network's MLP as one Pallas kernel forward and one backward, for the GPU.

Why: with many agents vmapped on a GPU, every layer of every agent's small network is a
batched matmul whose activations (e.g. 2,048 agents x 128 rows x 120 units) go to memory
and back between kernels; on a GPU those matmuls and the ReLU/bias kernels around them
were over half of a DQN iteration with the default config and three quarters with
PureJaxRL's, in our program and in PureJaxRL's alike (docs/results.md, "DQN on the GPU").
Here no activation leaves the chip: in the forward kernel one program per block of rows
carries them through every layer and writes only the Q-values; in the backward kernel one
program per agent recomputes the activations block by block, adds up the gradients in
registers and writes them once.

The arithmetic is the network's: `x @ kernel + bias`, ReLU between layers, plain
products on the way back, at the float32 products' default GPU precision (TF32 on recent
NVIDIA GPUs, as XLA's matmuls; Q-values agree with XLA's to about 5e-4 relative on a GPU).
Sizes are padded to powers of two (Triton's tiles) with zeros, which add nothing to any sum and keep the padded units at exactly zero. On the CPU
`interpret=True` runs the same kernels through XLA (the tests compare them there).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as plgpu

ROWS_PER_BLOCK = 64  # rows per forward program and per backward loop step
# The widest layer (inputs, hidden units or actions, padded) for which the kernels are used: fused
# is faster than XLA for a 64-64 network on 64 rows, but XLA wins at PureJaxRL's 120-84 on 128 rows
# (padded to 128 wide the blocks no longer fit the registers), also against a variant whose backward
# programs each take a slab of the last hidden layer's units (docs/results.md, "DQN on the GPU").
# 256 wide overflowed shared memory.
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


def _padded_layers(layers):
    out = []
    for kernel, bias in layers:
        fan_in, fan_out = kernel.shape
        shape = (_pow2(fan_in), _pow2(fan_out))
        out.append((jnp.pad(kernel, ((0, shape[0] - fan_in), (0, shape[1] - fan_out))),
                    jnp.pad(bias, (0, shape[1] - fan_out))[None, :]))
    return out


def _padded_rows(x, width):
    rows = x.shape[0]
    block = min(ROWS_PER_BLOCK, _pow2(rows))
    total = _pow2(rows, block)
    return jnp.pad(x, ((0, total - rows), (0, width - x.shape[1]))), block


def _dot(a, b, trans_a=False, trans_b=False):
    return plgpu.dot(a, b, trans_a=trans_a, trans_b=trans_b)


def _forward_kernel(num_layers, x_ref, *refs):
    """One block of rows through every layer."""
    weights, q_ref = refs[: 2 * num_layers], refs[2 * num_layers]
    h = x_ref[...]
    for layer in range(num_layers):
        h = _dot(h, weights[2 * layer][...]) + weights[2 * layer + 1][...]
        if layer < num_layers - 1:
            h = jnp.maximum(h, 0.0)
    q_ref[...] = h


def _backward_kernel(num_layers, block, x_ref, *refs):
    weights = refs[: 2 * num_layers]
    dq_ref = refs[2 * num_layers]
    grad_refs, dx_ref = refs[2 * num_layers + 1 : 4 * num_layers + 1], refs[4 * num_layers + 1]

    def body(i, grads):
        rows = pl.ds(pl.multiple_of(i * block, block), block)
        inputs = [x_ref[rows, :]]  # each layer's input, recomputed
        for layer in range(num_layers - 1):
            h = _dot(inputs[-1], weights[2 * layer][...]) + weights[2 * layer + 1][...]
            inputs.append(jnp.maximum(h, 0.0))
        g = dq_ref[rows, :]  # gradient at the current layer's output
        grads = list(grads)
        for layer in reversed(range(num_layers)):
            grads[2 * layer] += _dot(inputs[layer], g, trans_a=True)
            grads[2 * layer + 1] += jnp.sum(g, axis=0, keepdims=True)
            g = _dot(g, weights[2 * layer][...], trans_b=True)
            if layer > 0:
                g = jnp.where(inputs[layer] > 0, g, 0.0)
        dx_ref[rows, :] = g
        return tuple(grads)

    # The gradients add up in registers and are written once.
    zeros = tuple(jnp.zeros(ref.shape, ref.dtype) for ref in grad_refs)
    grads = jax.lax.fori_loop(0, x_ref.shape[0] // block, body, zeros)
    for ref, grad in zip(grad_refs, grads):
        ref[...] = grad


def _num_warps(kernels) -> int:
    """4 warps for the widths the kernels are used at (`MAX_WIDTH`; the fastest in a sweep of
    2-8 on a GPU), 8 for wider ones."""
    return 4 if max(max(k.shape) for k in kernels) <= 64 else 8


def _compiler_params(num_warps):
    return plgpu.CompilerParams(num_warps=num_warps, num_stages=1)


@partial(jax.custom_vjp, nondiff_argnums=(2,))
def _mlp(layers, x, interpret):
    return _forward(layers, x, interpret)


def _padded(layers, x):
    """The kernels' operands: the rows of `x` and each (kernel, bias) padded with zeros (the
    pairs flattened), the rows per block, and the padded output width."""
    padded = _padded_layers(layers)
    xp, block = _padded_rows(x, padded[0][0].shape[0])
    return xp, [a for pair in padded for a in pair], block, padded[-1][0].shape[1]


def _forward(layers, x, interpret):
    xp, flat, block, width = _padded(layers, x)
    q = pl.pallas_call(  # one program per block of rows
        partial(_forward_kernel, len(layers)),
        out_shape=jax.ShapeDtypeStruct((xp.shape[0], width), x.dtype),
        grid=(xp.shape[0] // block,),
        in_specs=[pl.BlockSpec((block, xp.shape[1]), lambda i: (i, 0))]
        + [pl.BlockSpec(a.shape, lambda i: (0, 0)) for a in flat],
        out_specs=pl.BlockSpec((block, width), lambda i: (i, 0)),
        interpret=interpret, compiler_params=_compiler_params(_num_warps(flat[::2])),
    )(xp, *flat)
    return q[: x.shape[0], : layers[-1][0].shape[1]]


def _mlp_fwd(layers, x, interpret):
    return _forward(layers, x, interpret), (layers, x)


def _mlp_bwd(interpret, saved, dq):
    layers, x = saved
    xp, flat, block, width = _padded(layers, x)
    dqp = jnp.pad(dq, ((0, xp.shape[0] - dq.shape[0]), (0, width - dq.shape[1])))
    out = [jax.ShapeDtypeStruct(a.shape, a.dtype) for a in flat] + [jax.ShapeDtypeStruct(xp.shape, x.dtype)]
    *grads, dx = pl.pallas_call(partial(_backward_kernel, len(layers), block), out_shape=out, interpret=interpret,
                                compiler_params=_compiler_params(_num_warps(flat[::2])))(xp, *flat, dqp)
    layer_grads = [(dk[: k.shape[0], : k.shape[1]], db[0, : b.shape[0]])
                   for (k, b), dk, db in zip(layers, grads[::2], grads[1::2])]
    return layer_grads, dx[: x.shape[0], : x.shape[1]]


_mlp.defvjp(_mlp_fwd, _mlp_bwd)


def q_values(params, obs: jax.Array, interpret: bool = False) -> jax.Array:
    """A plain (non-dueling) `QNetwork`'s output for `obs` (one observation or a batch)."""
    batch = obs.reshape(-1, obs.shape[-1])
    q = _mlp(layers_of(params), batch, interpret)
    return q.reshape(obs.shape[:-1] + q.shape[-1:])
