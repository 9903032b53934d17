"""Replay buffers as pure functions over a pytree state (a `flax.struct.dataclass`), so a buffer can
be a `lax.scan` carry, jitted and vmapped over seeds; the buffer objects hold static settings only.

Why the code looks the way it does (docs/bench-cpu.json, "uniform" and "prioritized"):
* XLA:CPU splits a loop fusion that reads >= 512 KiB of one operand across threads, counting a
  gather's or scatter's whole operand but only the bytes a `dynamic_slice` touches. So on the CPU
  rows are written one by one in a `fori_loop`, large leaves read by a loop of dynamic slices,
  sum-tree paths walked with scalar slices, and the descent gathers from a `tree_capacity` window.
* Parents are always recomputed from their children, never patched with deltas: the tree stays
  exact whatever the duplicate indices, and a parent is 0 iff both children are.
* Off the CPU each loop iteration launches kernels, and under `vmap` a loop whose trip count
  differs between seeds selects over the whole buffer each iteration; so `vectorized=True` reads
  with one gather, writes with one scatter and rebuilds the tree level by level, to the same values.
* Indices come from random bits the caller drew for many samples at once (`sample_from_bits`):
  XLA:CPU runs each `jax.random` call as a loop of tiny kernels.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp

# Leaves at least this large are read with dynamic slices (see module doc).
_SPLIT_BYTES = 1 << 19


@flax.struct.dataclass
class ReplayState:
    """State of the uniform ring buffer."""

    data: Any  # pytree of arrays, each with leading dim `capacity`
    insert_pos: jax.Array  # int32 scalar, next slot to write
    size: jax.Array  # int32 scalar, number of valid items (<= capacity)


@flax.struct.dataclass
class PrioritizedState:
    """`tree`: a heap-ordered sum tree of `priority**alpha` (root 1, node n's children 2n and 2n+1, leaves from
    `tree_capacity` on, 0 where unwritten); `min_tree` the same with `min` and `+inf`, normalising weights."""

    data: Any
    insert_pos: jax.Array
    size: jax.Array
    tree: jax.Array  # float32 (2 * tree_capacity,)
    max_priority: jax.Array  # float32 scalar: raw priority (before alpha) of new items
    min_tree: jax.Array  # float32 (2 * tree_capacity,)


# ---- ring-buffer helpers shared by both buffers ----
def _alloc(example_item: Any, capacity: int) -> Any:
    return jax.tree.map(lambda x: jnp.zeros((capacity,) + jnp.shape(x), jnp.result_type(x)), example_item)


def _batch_size(batch: Any, capacity: int) -> int:
    sizes = {leaf.shape[0] for leaf in jax.tree.leaves(batch)}
    if len(sizes) != 1:
        raise ValueError(f"batch leaves need one common leading dim, got {sizes}")
    (b,) = sizes
    if b > capacity:
        raise ValueError(f"add batch of {b} items exceeds capacity {capacity}")
    return b


def _write(data: Any, batch: Any, capacity: int, insert_pos: jax.Array, rows=None, count=None) -> Any:
    """Writes the k-th stored row to slot (insert_pos + k) % capacity: every row of `batch`, or with
    `rows` and `count` only `batch[rows[:count]]` (dropped items never touch the buffer)."""
    b = _batch_size(batch, capacity)

    def put_row(k, data):
        slot = (insert_pos + k) % capacity
        src = k if rows is None else rows[k]
        return jax.tree.map(lambda buf, x: jax.lax.dynamic_update_index_in_dim(
            buf, jax.lax.dynamic_index_in_dim(x, src, 0, False).astype(buf.dtype), slot, 0), data, batch)

    if count is not None:
        return jax.lax.fori_loop(0, count, put_row, data)
    return put_row(0, data) if b == 1 else jax.lax.fori_loop(0, b, put_row, data)


def _scatter_write(data: Any, batch: Any, capacity: int, insert_pos: jax.Array, mask=None) -> Any:
    """`_write` as one scatter per leaf: kept row k goes to slot (insert_pos + k) % capacity,
    the others to distinct out-of-bounds slots, which the scatter drops."""
    b = _batch_size(batch, capacity)
    rows = jnp.arange(b, dtype=jnp.int32)
    if mask is None:
        slots = (insert_pos + rows) % capacity
    else:
        mask = jnp.asarray(mask, bool).reshape(-1)
        kept_before = jnp.cumsum(mask, dtype=jnp.int32) - 1
        slots = jnp.where(mask, (insert_pos + kept_before) % capacity, capacity + rows)
    return jax.tree.map(lambda buf, x: buf.at[slots].set(x.astype(buf.dtype), mode="drop", unique_indices=True),
                        data, batch)


def _advance(capacity: int, insert_pos, size, count):
    """The insert position and size after `count` more items."""
    return ((insert_pos + count) % capacity).astype(jnp.int32), jnp.minimum(size + count, capacity).astype(jnp.int32)


def _store(data: Any, batch: Any, capacity: int, insert_pos: jax.Array, mask, vectorized: bool):
    """Writes `batch` (its rows where `mask` holds) from `insert_pos` on: `(data, rows stored)`."""
    count = _batch_size(batch, capacity)
    if mask is not None:
        count = jnp.asarray(mask, bool).sum(dtype=jnp.int32)
    if vectorized:
        return _scatter_write(data, batch, capacity, insert_pos, mask), count
    if mask is None:
        return _write(data, batch, capacity, insert_pos), count
    return _write(data, batch, capacity, insert_pos, _kept_rows(mask), count), count


def _kept_rows(mask: jax.Array) -> jax.Array:
    """Indices of the rows where `mask` is True, in order, then the others."""
    mask = jnp.asarray(mask, bool).reshape(-1)
    return jnp.zeros((1,), jnp.int32) if mask.shape[0] == 1 else jnp.argsort(~mask, stable=True).astype(jnp.int32)


def _read(data: Any, indices: jax.Array, vectorized: bool = False) -> Any:
    """`data[indices]` for every leaf; indices must be in bounds. `vectorized`: one gather per leaf."""
    leaves, treedef = jax.tree.flatten(data)
    split_bytes = float("inf") if vectorized else _SPLIT_BYTES
    big = [i for i, x in enumerate(leaves) if x.size * x.dtype.itemsize >= split_bytes]
    out = [None if i in big else x.at[indices].get(mode="promise_in_bounds") for i, x in enumerate(leaves)]
    if big:
        n = indices.shape[0]

        def get_row(k, rows):
            return [jax.lax.dynamic_update_index_in_dim(r, jax.lax.dynamic_index_in_dim(x, indices[k], 0, False), k, 0)
                    for r, x in zip(rows, (leaves[i] for i in big))]

        init = [jnp.zeros((n,) + leaves[i].shape[1:], leaves[i].dtype) for i in big]
        for i, rows in zip(big, jax.lax.fori_loop(0, n, get_row, init)):
            out[i] = rows
    return jax.tree.unflatten(treedef, out)


def uniform_from_bits(bits: jax.Array) -> jax.Array:
    """float32 uniform in [0, 1) from uint32 random bits: the top 24 bits, which a float32 holds exactly."""
    return (bits >> 8).astype(jnp.float32) * (1.0 / (1 << 24))


def _uniform_indices(bits: jax.Array, size: jax.Array) -> jax.Array:
    """Uniform int32 indices in [0, size) from uint32 random bits (modulo bias <= size / 2**32)."""
    n = jnp.maximum(size, 1).astype(jnp.uint32)
    return (bits % n).astype(jnp.int32)


@dataclasses.dataclass(frozen=True)
class _RingBuffer:
    capacity: int

    def __post_init__(self):
        if self.capacity < 1:
            raise ValueError("capacity must be >= 1")

    def can_sample(self, state, min_size: int = 1) -> jax.Array:
        return state.size >= min_size


# ---- uniform replay ----
@dataclasses.dataclass(frozen=True)
class UniformReplay(_RingBuffer):
    """Uniform FIFO ring buffer; `vectorized`: gather and scatter instead of loops (see the module doc)."""

    vectorized: bool = False

    def init(self, example_item: Any) -> ReplayState:
        """`example_item` is one transition (no batch dim); its dtypes are kept."""
        return ReplayState(data=_alloc(example_item, self.capacity), insert_pos=jnp.zeros((), jnp.int32),
                           size=jnp.zeros((), jnp.int32))

    def add(self, state: ReplayState, batch: Any, mask: jax.Array | None = None) -> ReplayState:
        """`batch` has a static leading dim B <= capacity; items where `mask` is False are not stored."""
        data, count = _store(state.data, batch, self.capacity, state.insert_pos, mask, self.vectorized)
        pos, size = _advance(self.capacity, state.insert_pos, state.size, count)
        return ReplayState(data=data, insert_pos=pos, size=size)

    def sample(self, state: ReplayState, key: jax.Array, batch_size: int):
        """Returns `(batch, indices)`, indices uniform with replacement in [0, size)."""
        return self.sample_from_bits(state, jax.random.bits(key, (batch_size,), jnp.uint32))

    def sample_from_bits(self, state: ReplayState, bits: jax.Array):
        """`sample` with one uint32 of random bits per item drawn by the caller."""
        idx = _uniform_indices(bits, state.size)
        return _read(state.data, idx, self.vectorized), idx


# ---- prioritized replay ----
@dataclasses.dataclass(frozen=True)
class PrioritizedReplay(_RingBuffer):
    """Proportional prioritized replay (Schaul et al. 2016) over a sum tree, sampled stratified (one
    point in each of `batch_size` equal strata). Importance weights are normalised over the whole
    buffer, not the batch: `w_i = (p_i**alpha / min_j p_j**alpha)**-beta`, in (0, 1]."""

    alpha: float = 0.6
    eps: float = 1e-6
    vectorized: bool = False  # gather, scatter and level-by-level tree rebuilds (see the module doc)

    @property
    def tree_capacity(self) -> int:
        return 1 << (self.capacity - 1).bit_length()

    @property
    def depth(self) -> int:
        return self.tree_capacity.bit_length() - 1

    def init(self, example_item: Any) -> PrioritizedState:
        t = self.tree_capacity
        return PrioritizedState(data=_alloc(example_item, self.capacity), insert_pos=jnp.zeros((), jnp.int32),
                                size=jnp.zeros((), jnp.int32), tree=jnp.zeros((2 * t,), jnp.float32),
                                max_priority=jnp.ones((), jnp.float32),
                                min_tree=jnp.full((2 * t,), jnp.inf, jnp.float32))

    def _set_leaves(self, tree, min_tree, indices, values, count=None):
        """Sets leaves one by one (of duplicates the last wins), rebuilding ancestors; `count`: how many to set."""

        def set_leaf(k, trees):
            tree, min_tree = trees
            node = indices[k] + self.tree_capacity
            tree = jax.lax.dynamic_update_index_in_dim(tree, values[k], node, 0)
            min_tree = jax.lax.dynamic_update_index_in_dim(min_tree, values[k], node, 0)

            def fix_parent(_, carry):
                node, tree, min_tree = carry
                node = node >> 1
                kids = jax.lax.dynamic_slice(tree, (2 * node,), (2,))
                mkids = jax.lax.dynamic_slice(min_tree, (2 * node,), (2,))
                tree = jax.lax.dynamic_update_index_in_dim(tree, kids[0] + kids[1], node, 0)
                min_tree = jax.lax.dynamic_update_index_in_dim(min_tree, jnp.minimum(mkids[0], mkids[1]), node, 0)
                return node, tree, min_tree

            _, tree, min_tree = jax.lax.fori_loop(0, self.depth, fix_parent, (node, tree, min_tree))
            return tree, min_tree

        if self.vectorized:
            return self._set_leaves_by_level(tree, min_tree, indices, values, count)
        if count is None:
            if indices.shape[0] == 1:
                return set_leaf(0, (tree, min_tree))
            count = indices.shape[0]
        return jax.lax.fori_loop(0, count, set_leaf, (tree, min_tree))

    def _set_leaves_by_level(self, tree, min_tree, indices, values, count=None):
        """`_set_leaves` without loops over items, to the same result: the leaves in one scatter (of
        duplicate indices the last wins), then each level's touched parents in one gather and scatter."""
        b = indices.shape[0]
        items = jnp.arange(b, dtype=jnp.int32)
        valid = items < (b if count is None else count)
        written_later = (indices[None, :] == indices[:, None]) & (items[None, :] > items[:, None]) & valid[None, :]
        wins = valid & ~written_later.any(axis=1)
        out_of_bounds = 2 * self.tree_capacity + items  # distinct, dropped by the scatters
        node = jnp.where(wins, indices + self.tree_capacity, out_of_bounds)
        tree = tree.at[node].set(values, mode="drop")
        min_tree = min_tree.at[node].set(values, mode="drop")
        for _ in range(self.depth):
            node = jnp.where(wins, node >> 1, out_of_bounds)
            left, right = 2 * node, 2 * node + 1
            kids = tree.at[left].get(mode="fill", fill_value=0), tree.at[right].get(mode="fill", fill_value=0)
            mkids = min_tree.at[left].get(mode="fill", fill_value=0), min_tree.at[right].get(mode="fill", fill_value=0)
            tree = tree.at[node].set(kids[0] + kids[1], mode="drop")
            min_tree = min_tree.at[node].set(jnp.minimum(mkids[0], mkids[1]), mode="drop")
        return tree, min_tree

    def add(self, state: PrioritizedState, batch: Any, mask: jax.Array | None = None) -> PrioritizedState:
        """New items get `max_priority` (leaf `max_priority**alpha`); items where `mask` is False are not stored."""
        b = _batch_size(batch, self.capacity)
        data, count = _store(state.data, batch, self.capacity, state.insert_pos, mask, self.vectorized)
        slots = (state.insert_pos + jnp.arange(b, dtype=jnp.int32)) % self.capacity
        leaf = jnp.broadcast_to(state.max_priority**self.alpha, (b,))
        tree, min_tree = self._set_leaves(state.tree, state.min_tree, slots, leaf, None if mask is None else count)
        pos, size = _advance(self.capacity, state.insert_pos, state.size, count)
        return state.replace(data=data, insert_pos=pos, size=size, tree=tree, min_tree=min_tree)

    def _descend(self, tree: jax.Array, query: jax.Array) -> jax.Array:
        """Leaf whose prefix-sum interval contains each query. Going right needs a positive right
        subtree, so a query pushed past the total by round-off still ends on a written leaf."""
        t = self.tree_capacity

        def step(level, carry):
            query, node = carry  # node: index within `level`
            # Nodes of level+1 start at 2**(level+1); a window of t nodes covers them.
            window = jax.lax.dynamic_slice(tree, (jnp.left_shift(2, level),), (t,))
            kids = window.reshape(-1, 2).at[node].get(mode="promise_in_bounds")
            left, right = kids[:, 0], kids[:, 1]
            go_right = (query >= left) & (right > 0)
            query = jnp.where(go_right, query - left, query)
            return query, 2 * node + go_right.astype(jnp.int32)

        node = jnp.zeros(query.shape, jnp.int32)
        if self.depth == 0:  # capacity 1: the root is the only leaf
            return node
        # Unrolled on accelerators: a loop's every iteration would launch its kernels anew.
        return jax.lax.fori_loop(0, self.depth, step, (query, node), unroll=self.vectorized)[1]

    def sample(self, state: PrioritizedState, key: jax.Array, batch_size: int, beta):
        """Returns `(batch, indices, weights)`; see the class doc for the weights."""
        return self.sample_from_bits(state, jax.random.bits(key, (batch_size,), jnp.uint32), beta)

    def sample_from_bits(self, state: PrioritizedState, bits: jax.Array, beta):
        """`sample` with one uint32 of random bits per item drawn by the caller."""
        batch_size = bits.shape[0]
        query = (jnp.arange(batch_size, dtype=jnp.float32) + uniform_from_bits(bits)) * (state.tree[1] / batch_size)
        idx = jnp.minimum(self._descend(state.tree, query), jnp.maximum(state.size - 1, 0))
        leaf = state.tree[self.tree_capacity :].at[idx].get(mode="promise_in_bounds")
        weights = (leaf / state.min_tree[1]) ** (-jnp.asarray(beta, jnp.float32))
        return _read(state.data, idx, self.vectorized), idx, weights

    def update_priorities(self, state: PrioritizedState, indices: jax.Array, priorities: jax.Array) -> PrioritizedState:
        """`priorities` are raw (e.g. |TD error|); stored as `(|p| + eps)**alpha`."""
        raw = (jnp.abs(priorities).astype(jnp.float32) + self.eps).reshape(-1)
        indices = jnp.asarray(indices, jnp.int32).reshape(-1)
        tree, min_tree = self._set_leaves(state.tree, state.min_tree, indices, raw**self.alpha)
        max_priority = jnp.maximum(state.max_priority, jnp.max(raw))
        return state.replace(tree=tree, min_tree=min_tree, max_priority=max_priority)
