"""The Q-network: an MLP with an optional dueling head (Flax linen, params as a plain pytree); and the products
whose gradients XLA:CPU computes slowly, written so that it computes them fast."""

from __future__ import annotations

import functools
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp


@jax.custom_vjp
def _matmul(x: jax.Array, kernel: jax.Array) -> jax.Array:
    return x @ kernel


def _matmul_fwd(x, kernel):
    return x @ kernel, (x, kernel)


def _matmul_bwd(saved, grad):
    """The usual gradients, the kernel's from an explicitly transposed input: folded into the dot, the
    transpose makes XLA:CPU contract over the batch axis on its slow generic path; the barrier stops that."""
    x, kernel = saved
    x_rows_t = jax.lax.optimization_barrier(x.reshape(-1, x.shape[-1]).T)
    return grad @ kernel.T, x_rows_t @ grad.reshape(-1, grad.shape[-1])


_matmul.defvjp(_matmul_fwd, _matmul_bwd)


def _dense_dot_general(x, kernel, dimension_numbers, precision=None, preferred_element_type=None):
    """`nn.Dense`'s product (x's last axis with the kernel's first) through `_matmul`."""
    if dimension_numbers != (((x.ndim - 1,), (0,)), ((), ())):
        raise ValueError(f"_dense_dot_general only computes x @ kernel; got dimension numbers {dimension_numbers}")
    return _matmul(x, kernel)


NHWC = ("NHWC", "HWIO", "NHWC")  # XLA:CPU's canonical convolution: the only one its fast (Eigen) path runs


def _conv(x, kernel, strides, padding="VALID", lhs_dilation=(1, 1), rhs_dilation=(1, 1)):
    return jax.lax.conv_general_dilated(x, kernel, strides, padding, lhs_dilation, rhs_dilation, dimension_numbers=NHWC)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _valid_conv(x: jax.Array, kernel: jax.Array, strides: tuple[int, int]) -> jax.Array:
    return _conv(x, kernel, strides)


def _valid_conv_fwd(x, kernel, strides):
    return _conv(x, kernel, strides), (x, kernel)


def _valid_conv_bwd(strides, saved, grad):
    """The usual gradients as canonical convolutions, transposed explicitly: XLA:CPU canonicalizes only the
    convolutions of a program's top level, so those of JAX's own gradients in a loop run its slow generic path."""
    x, kernel = saved
    size = kernel.shape[:2]  # the kernel's: the input's channels as a batch, its batch as features
    kernel_grad = _conv(x.transpose(3, 1, 2, 0), grad.transpose(1, 2, 0, 3), (1, 1), rhs_dilation=strides)
    pads = [(k - 1, k - 1 + (n - k) % s) for k, n, s in zip(size, x.shape[1:3], strides, strict=True)]
    x_grad = _conv(grad, jnp.flip(kernel, (0, 1)).swapaxes(2, 3), (1, 1), pads, lhs_dilation=strides)
    return x_grad, kernel_grad[:, :size[0], :size[1]].transpose(1, 2, 0, 3)


_valid_conv.defvjp(_valid_conv_fwd, _valid_conv_bwd)


def canonical_conv(lhs, rhs, window_strides, padding, lhs_dilation=None, rhs_dilation=None, dimension_numbers=None,
                   feature_group_count=1, **kwargs):
    """`nn.Conv`'s `conv_general_dilated` through `_valid_conv` (for XLA:CPU in loops)."""
    unpadded = padding == "VALID" or [tuple(pad) for pad in padding] == [(0, 0)] * 2
    plain = set((*(lhs_dilation or ()), *(rhs_dilation or ()), feature_group_count)) <= {1}
    if not (unpadded and plain and dimension_numbers == jax.lax.conv_dimension_numbers(lhs.shape, rhs.shape, NHWC)):
        raise ValueError(f"canonical_conv only convolves unpadded NHWC images with HWIO kernels; got padding "
                         f"{padding}, dilations {lhs_dilation} {rhs_dilation}, groups {feature_group_count}")
    return _valid_conv(lhs, rhs, tuple(window_strides))


def _through_canonical_conv(call, args, kwargs, context):
    """An `nn.intercept_methods` interceptor: each bound `nn.Conv`'s call through `canonical_conv`."""
    conv = context.module
    if context.method_name != "__call__" or type(conv) is not nn.Conv or conv.conv_general_dilated is not None \
            or not conv.has_variable("params", "kernel"):
        return call(*args, **kwargs)
    return conv.clone(parent=None, conv_general_dilated=canonical_conv).apply(conv.variables, *args, **kwargs)


def canonical_convs():
    """Within it, the convolutions of networks built elsewhere (Brax's) go through `canonical_conv`."""
    return nn.intercept_methods(_through_canonical_conv)


class QNetwork(nn.Module):
    num_actions: int
    hidden: Sequence[int] = (64, 64)
    dueling: bool = False
    transposed_kernel_gradient: bool = True  # `_matmul` (for XLA:CPU); False: the plain product

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        def dense(features):
            return nn.Dense(features, dot_general=_dense_dot_general if self.transposed_kernel_gradient else None)

        x = obs
        for width in self.hidden:
            x = nn.relu(dense(width)(x))
        if not self.dueling:
            return dense(self.num_actions)(x)
        # Dueling head (Wang et al. 2016): Q = V + A - mean(A).
        value = dense(1)(x)
        advantage = dense(self.num_actions)(x)
        return value + advantage - advantage.mean(axis=-1, keepdims=True)
