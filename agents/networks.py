"""The Q-network: an MLP with an optional dueling head (Flax linen, params as a plain pytree)."""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax


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
