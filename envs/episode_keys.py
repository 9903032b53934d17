"""The cheap key stream from which auto-reset envs draw their episodes.

Under `vmap` every auto-resetting env draws a fresh episode on every step (a select
keeps it only where the episode ended), so the generator behind those draws runs
once per env per step. JAX's threefry costs four 20-round blocks there (one split,
two for four uniforms). These keys use pcg4d instead (Jarzynski and Olano, "Hash
Functions for GPU Rendering", JCGT 9(3), 2020): the paper's own 4-in/4-out hash, a
bijection of four 32-bit words with 12 multiplies, applied here to (key word 0, key
word 1, counter, purpose). One call gives a split into two keys, or four random
words. It made the batched CartPole step cheaper on a GPU (docs/results.md, "The GPU step").

The keys are ordinary JAX typed keys (`jax.extend.random.define_prng_impl`), so an
env's `reset` draws from them with `jax.random.uniform`, `split`, `normal`... as
from any key. A user's own keys stay threefry: only the per-episode stream of
`AutoReset` uses this generator.

An env's stream is two `uint32` scalars, (seed, counter), both drawn at random when the
env is first reset: episode k after that is drawn from the key of `jax.random.split` of
the pcg4d key (seed, counter + k), and a finished episode only adds one to the counter.
The seed word never changes and the counter's update reads nothing else, so on a GPU XLA
writes the new counter over the old one in place, where a stream whose two words each
hashed both made it copy them between loop buffers on every step (docs/results.md, "The
GPU step"). Two scalars rather than one `uint32[2]`, so that a batch's streams are two
`[N]` arrays, which XLA fuses with the rest of a step instead of hashing once per column.
Envs (or restarts) share a stream only if both their random seed words and their counter
ranges coincide.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.random import define_prng_impl

# The fourth input word keeps the streams of one key apart (pcg4d is a bijection,
# so different inputs never give the same four output words). NumPy scalars, so that
# importing the suite does not start a JAX backend.
_SEED, _BITS, _SPLIT, _FOLD_IN = (np.uint32(purpose) for purpose in (0x5EED, 0xB175, 0x5B17, 0xF01D))


def pcg4d(x, y, z, w):
    """pcg4d on four uint32 arrays (wrapping arithmetic), as in the paper's listing."""
    x, y, z, w = (v * jnp.uint32(1664525) + jnp.uint32(1013904223) for v in (x, y, z, w))
    x, y, z, w = _mix(x, y, z, w)
    x, y, z, w = (v ^ (v >> 16) for v in (x, y, z, w))
    return _mix(x, y, z, w)


def _mix(x, y, z, w):
    x = x + y * w
    y = y + z * x
    z = z + x * y
    w = w + y * z
    return x, y, z, w


def _words(key: jax.Array, purpose: jax.Array, count: int) -> jax.Array:
    """`count` uint32 words: pcg4d(key, i, purpose) for blocks i = 0, 1, ..."""
    blocks = -(-count // 4)
    # One block (every reset and split here) hashes scalars: a length-1 counter axis would
    # give a batch's words an [N, 1] shape that keeps XLA from fusing them with [N] state.
    counter = jnp.arange(blocks, dtype=jnp.uint32) if blocks > 1 else jnp.uint32(0)
    block = pcg4d(key[0], key[1], counter, purpose)
    return jnp.stack(block, axis=-1).reshape(-1)[:count]


def _seed(seed: jax.Array) -> jax.Array:
    low = seed.astype(jnp.uint32)
    high = (seed >> 32).astype(jnp.uint32) if seed.dtype.itemsize == 8 else jnp.zeros_like(low)
    return jnp.stack(pcg4d(low, high, jnp.uint32(0), _SEED)[:2])


def _split(key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    return _words(key, _SPLIT, 2 * math.prod(shape)).reshape(*shape, 2)


def _fold_in(key: jax.Array, data: jax.Array) -> jax.Array:
    return jnp.stack(pcg4d(key[0], key[1], data.astype(jnp.uint32), _FOLD_IN)[:2])


def _random_bits(key: jax.Array, bit_width: int, shape: tuple[int, ...]) -> jax.Array:
    count = math.prod(shape)
    dtype = jnp.dtype(f"uint{bit_width}")
    if bit_width == 64:  # two words each (only reachable with jax_enable_x64)
        pairs = _words(key, _BITS, 2 * count).reshape(count, 2).astype(dtype)
        return ((pairs[:, 0] << 32) | pairs[:, 1]).reshape(shape)
    return _words(key, _BITS, count).astype(dtype).reshape(shape)  # 8 and 16 bits: the low bits


PCG4D = define_prng_impl(
    key_shape=(2,), seed=_seed, split=_split, random_bits=_random_bits, fold_in=_fold_in,
    name="pcg4d", tag="pcg",
)


def episode_keys(key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """A new stream, (seed, counter): two random `uint32` scalars drawn from any key."""
    words = jax.random.bits(key, (2,), jnp.uint32)
    return words[0], words[1]


def next_episode_key(stream: tuple[jax.Array, jax.Array]) -> tuple[tuple[jax.Array, jax.Array], jax.Array]:
    """(the stream with its counter advanced, a typed key for one episode's `reset`): the
    second key of `jax.random.split` of the pcg4d key (seed, counter), from one pcg4d call
    (a test checks it)."""
    seed, counter = stream
    words = pcg4d(seed, counter, jnp.uint32(0), _SPLIT)
    return (seed, counter + jnp.uint32(1)), jax.random.wrap_key_data(jnp.stack(words[2:], axis=-1), impl=PCG4D)
