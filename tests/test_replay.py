"""Tests for agents/replay.py: ring-buffer contents, sampling distributions,
sum-tree invariants, and jit/vmap/scan compatibility."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents.replay import PrioritizedReplay, ReplayState, UniformReplay


def _item():
    return dict(
        obs=jnp.zeros((3,), jnp.float32),
        action=jnp.zeros((), jnp.int32),
        reward=jnp.zeros((), jnp.float32),
        terminated=jnp.zeros((), jnp.bool_),
    )


def _batch(ids):
    """Transitions whose every field encodes its id, so contents are checkable."""
    ids = np.asarray(ids)
    return dict(
        obs=jnp.asarray(np.stack([ids, ids + 0.5, -ids], -1), jnp.float32),
        action=jnp.asarray(ids, jnp.int32),
        reward=jnp.asarray(ids * 2.0, jnp.float32),
        terminated=jnp.asarray(ids % 2 == 1),
    )


def _fill(buf, ids, chunk=1):
    state = buf.init(_item())
    add = jax.jit(buf.add)
    for s in range(0, len(ids), chunk):
        state = add(state, _batch(ids[s : s + chunk]))
    return state


def _sample_many(buf, state, n_batches, batch_size=32, beta=None, seed=0):
    """n_batches independent samples (vmapped over keys) in one jitted call."""
    keys = jax.random.split(jax.random.key(seed), n_batches)
    if beta is None:
        fn = lambda k: buf.sample(state, k, batch_size)
    else:
        fn = lambda k: buf.sample(state, k, batch_size, beta)
    return jax.jit(jax.vmap(fn))(keys)


def _assert_rows_match_ids(batch, ids):
    expected = _batch(np.asarray(ids).reshape(-1))
    for name in expected:
        np.testing.assert_array_equal(
            np.asarray(batch[name]).reshape(expected[name].shape), expected[name], name
        )


def _chi2_ok(counts, probs):
    """Loose chi-square check: statistic within df + 6 * sqrt(2 df)."""
    n = counts.sum()
    expected = n * probs
    stat = ((counts - expected) ** 2 / expected).sum()
    df = len(counts) - 1
    return stat < df + 6 * np.sqrt(2 * df), stat


# --------------------------------------------------------------------------- #
# Uniform
# --------------------------------------------------------------------------- #


def test_uniform_init_keeps_dtypes_and_shapes():
    buf = UniformReplay(17)
    state = buf.init(_item())
    assert isinstance(state, ReplayState)
    assert state.data["obs"].shape == (17, 3) and state.data["obs"].dtype == jnp.float32
    assert state.data["action"].dtype == jnp.int32
    assert state.data["terminated"].dtype == jnp.bool_
    assert int(state.size) == 0 and int(state.insert_pos) == 0
    assert not bool(buf.can_sample(state, 1))


def test_uniform_sampling_only_written_slots_and_uniform():
    buf = UniformReplay(100)
    size = 37
    state = _fill(buf, np.arange(size), chunk=5)
    assert int(state.size) == size
    assert bool(buf.can_sample(state, size)) and not bool(buf.can_sample(state, size + 1))
    batch, idx = _sample_many(buf, state, 1000)  # 32k draws
    idx = np.asarray(idx)
    assert idx.min() >= 0 and idx.max() < size
    _assert_rows_match_ids(batch, idx)  # slot i holds the item with id i
    counts = np.bincount(idx.reshape(-1), minlength=size)
    assert (counts > 0).all()
    ok, stat = _chi2_ok(counts, np.full(size, 1.0 / size))
    assert ok, stat


def test_uniform_wraparound_one_by_one():
    cap, extra = 7, 5
    buf = UniformReplay(cap)
    ids = np.arange(cap + extra)
    state = _fill(buf, ids, chunk=1)
    assert int(state.size) == cap
    assert int(state.insert_pos) == (cap + extra) % cap
    # slot j holds the newest id congruent to j: the oldest ids were overwritten
    expected = np.array([max(i for i in ids if i % cap == j) for j in range(cap)])
    _assert_rows_match_ids(state.data, expected)


@pytest.mark.parametrize("cap,chunks", [(10, [4, 4, 4, 4, 3]), (10, [3, 10, 7, 1, 9]), (8, [8, 8, 5])])
def test_uniform_wraparound_batches_match_reference(cap, chunks):
    buf = UniformReplay(cap)
    state = buf.init(_item())
    ref = np.full(cap, -1)
    n = 0
    for c in chunks:
        ids = np.arange(n, n + c)
        state = jax.jit(buf.add)(state, _batch(ids))
        ref[(n + np.arange(c)) % cap] = ids
        n += c
        assert int(state.size) == min(n, cap)
        assert int(state.insert_pos) == n % cap
    _assert_rows_match_ids(state.data, ref)


def test_uniform_add_rejects_batch_larger_than_capacity():
    buf = UniformReplay(4)
    with pytest.raises(ValueError):
        buf.add(buf.init(_item()), _batch(np.arange(5)))


def test_uniform_large_leaves_read_correctly():
    # Leaves >= 512 KiB take the dynamic-slice read path.
    cap = 50_000
    buf = UniformReplay(cap)
    state = _fill(buf, np.arange(cap), chunk=10_000)
    batch, idx = _sample_many(buf, state, 20)
    _assert_rows_match_ids(batch, np.asarray(idx))


# --------------------------------------------------------------------------- #
# Prioritized
# --------------------------------------------------------------------------- #


def _leaf_values(buf, state):
    t = buf.tree_capacity
    return np.asarray(state.tree[t : t + buf.capacity])


def _assert_tree_consistent(buf, state):
    tree = np.asarray(state.tree, np.float64)
    mtree = np.asarray(state.min_tree)
    t = buf.tree_capacity
    for node in range(1, t):
        np.testing.assert_allclose(tree[node], tree[2 * node] + tree[2 * node + 1], rtol=1e-5)
        assert mtree[node] == min(mtree[2 * node], mtree[2 * node + 1])
    size = int(state.size)
    leaves = tree[t : t + size]
    np.testing.assert_allclose(tree[1], leaves.sum(), rtol=1e-5)
    assert mtree[1] == np.float32(leaves.min()) if size else np.isinf(mtree[1])
    assert (tree[t + size :] == 0).all()


def _set_priorities(buf, state, prios):
    idx = jnp.arange(len(prios), dtype=jnp.int32)
    return jax.jit(buf.update_priorities)(state, idx, jnp.asarray(prios, jnp.float32))


def _check_frequencies(idx, probs, n_sigma=5.0):
    n = idx.size
    counts = np.bincount(idx.reshape(-1), minlength=len(probs))
    expected = n * probs
    sigma = np.sqrt(n * probs * (1 - probs))
    assert (np.abs(counts - expected) <= n_sigma * sigma + 1).all(), (counts, expected)


def test_prioritized_new_items_get_max_priority():
    buf = PrioritizedReplay(13, alpha=0.7)
    state = _fill(buf, np.arange(4))
    np.testing.assert_allclose(_leaf_values(buf, state)[:4], 1.0)  # initial max priority
    state = _set_priorities(buf, state, [0.5, 7.0, 2.0, 0.1])
    np.testing.assert_allclose(float(state.max_priority), 7.0 + buf.eps, rtol=1e-6)
    state = jax.jit(buf.add)(state, _batch([4, 5]))
    leaves = _leaf_values(buf, state)
    np.testing.assert_allclose(leaves[4:6], (7.0 + buf.eps) ** 0.7, rtol=1e-6)
    np.testing.assert_allclose(leaves[:4], (np.array([0.5, 7.0, 2.0, 0.1]) + buf.eps) ** 0.7, rtol=1e-6)
    assert (leaves[6:] == 0).all()
    # lowering priorities never lowers max_priority
    state = _set_priorities(buf, state, [0.2] * 6)
    np.testing.assert_allclose(float(state.max_priority), 7.0 + buf.eps, rtol=1e-6)
    _assert_tree_consistent(buf, state)


def test_prioritized_frequencies_follow_priorities_and_updates():
    cap, alpha = 13, 0.6  # not a power of two: tree has 3 never-written leaves
    buf = PrioritizedReplay(cap, alpha=alpha)
    state = _fill(buf, np.arange(cap), chunk=4)
    rng = np.random.default_rng(0)
    for round_ in range(2):
        prios = rng.uniform(0.05, 5.0, cap).astype(np.float32)
        prios[round_] = 20.0  # one dominant item, different per round
        state = _set_priorities(buf, state, prios)
        leaf = (prios.astype(np.float64) + buf.eps) ** alpha
        probs = leaf / leaf.sum()
        batch, idx, _ = _sample_many(buf, state, 6250, beta=0.4, seed=round_)  # 200k draws
        idx = np.asarray(idx)
        assert idx.min() >= 0 and idx.max() < cap
        _assert_rows_match_ids(batch, idx)
        _check_frequencies(idx, probs)


def test_prioritized_frequency_check_can_fail():
    """The tolerance is tight enough to notice sampling by p instead of p**alpha."""
    cap = 13
    buf = PrioritizedReplay(cap, alpha=1.0)  # samples by p
    state = _fill(buf, np.arange(cap))
    prios = np.linspace(0.1, 5.0, cap).astype(np.float32)
    state = _set_priorities(buf, state, prios)
    _, idx, _ = _sample_many(buf, state, 6250, beta=0.4)
    leaf = (prios.astype(np.float64) + 1e-6) ** 0.6  # wrong exponent
    with pytest.raises(AssertionError):
        _check_frequencies(np.asarray(idx), leaf / leaf.sum())


def test_prioritized_importance_weights_match_numpy():
    cap, alpha, beta = 50, 0.6, 0.4
    buf = PrioritizedReplay(cap, alpha=alpha)
    size = 29  # partially filled: min and N are over written slots only
    state = _fill(buf, np.arange(size), chunk=7)
    rng = np.random.default_rng(1)
    prios = rng.uniform(0.0, 3.0, size).astype(np.float32)
    state = _set_priorities(buf, state, prios)
    _, idx, w = _sample_many(buf, state, 50, beta=beta)
    idx, w = np.asarray(idx), np.asarray(w)
    p = (prios.astype(np.float64) + buf.eps) ** alpha
    P = p / p.sum()
    w_all = (size * P) ** (-beta)
    expected = w_all[idx] / w_all.max()
    np.testing.assert_allclose(w, expected, rtol=1e-4)
    assert w.max() <= 1.0 + 1e-6


def test_prioritized_never_samples_unwritten_or_zero_leaves():
    buf = PrioritizedReplay(100)
    size = 7
    state = _fill(buf, np.arange(size))
    # Tiny last-written priorities: a query rounded past the total must not
    # fall through to the empty leaves on the right.
    state = _set_priorities(buf, state, [3.0, 2.0, 1.0, 5.0, 4.0, 0.0, 0.0])
    _, idx, w = _sample_many(buf, state, 2000, beta=0.5)
    idx = np.asarray(idx)
    assert idx.min() >= 0 and idx.max() < size
    assert np.isfinite(np.asarray(w)).all()
    # Push queries to and past the total directly.
    total = float(state.tree[1])
    queries = jnp.array([0.0, total * 0.5, total, np.nextafter(np.float32(total), np.float32(np.inf)), total * 1.01])
    leaf_idx = np.asarray(jax.jit(buf._descend)(state.tree, queries))
    leaves = _leaf_values(buf, state)
    assert (leaf_idx < size).all() and (leaves[leaf_idx] > 0).all()


def test_prioritized_tree_consistent_after_random_updates_with_duplicates():
    cap = 37
    buf = PrioritizedReplay(cap)
    state = _fill(buf, np.arange(30), chunk=6)
    update = jax.jit(buf.update_priorities)
    rng = np.random.default_rng(2)
    ref = np.ones(cap)
    ref[30:] = 0
    for _ in range(20):
        idx = rng.integers(0, 30, size=32)  # 32 out of 30 slots: duplicates guaranteed
        pr = rng.exponential(1.0, size=32).astype(np.float32)
        state = update(state, jnp.asarray(idx, jnp.int32), jnp.asarray(pr))
        _assert_tree_consistent(buf, state)
        # duplicates: the leaf holds the value of one of the duplicates (the last)
        for i, p in zip(idx, pr):
            ref[i] = (p + buf.eps) ** buf.alpha
    np.testing.assert_allclose(_leaf_values(buf, state), ref, rtol=1e-6)


def test_prioritized_capacity_one():
    buf = PrioritizedReplay(1)
    state = _fill(buf, np.arange(3))
    batch, idx, w = buf.sample(state, jax.random.key(0), 4, 0.5)
    assert (np.asarray(idx) == 0).all() and (np.asarray(batch["action"]) == 2).all()
    np.testing.assert_allclose(np.asarray(w), 1.0)


# --------------------------------------------------------------------------- #
# jit / vmap / scan
# --------------------------------------------------------------------------- #


def _stack(items):
    return jax.tree.map(lambda *x: jnp.stack(x), *items)


@pytest.mark.parametrize("prioritized", [False, True])
def test_vmap_over_seeds_matches_unbatched(prioritized):
    seeds, cap = 3, 11
    buf = PrioritizedReplay(cap) if prioritized else UniformReplay(cap)
    keys = jax.random.split(jax.random.key(3), seeds)
    batches = [_batch(np.arange(s * 100, s * 100 + 8)) for s in range(seeds)]

    def run(key, batch):
        state = buf.init(jax.tree.map(lambda x: x[0], batch))
        state = buf.add(state, batch)
        state = buf.add(state, batch)  # 16 items into 11 slots: wraps
        if prioritized:
            out = buf.sample(state, key, 6, 0.4)
            state = buf.update_priorities(state, out[1], jnp.arange(6.0))
            out = buf.sample(state, jax.random.fold_in(key, 1), 6, 0.4)
        else:
            out = buf.sample(state, key, 6)
        return state, out

    vstate, vout = jax.jit(jax.vmap(run))(keys, _stack(batches))
    assert vstate.size.shape == (seeds,)
    for s in range(seeds):
        state, out = jax.jit(run)(keys[s], batches[s])
        jax.tree.map(
            lambda a, b: np.testing.assert_allclose(np.asarray(a)[s], np.asarray(b), rtol=1e-6),
            (vstate, vout),
            (state, out),
        )


@pytest.mark.parametrize("prioritized", [False, True])
def test_state_works_as_scan_carry(prioritized):
    cap, steps = 20, 50
    buf = PrioritizedReplay(cap) if prioritized else UniformReplay(cap)

    @jax.jit
    def train(key):
        def step(carry, t):
            state, key = carry
            key, k = jax.random.split(key)
            state = buf.add(state, _batch_traced(t))
            if prioritized:
                batch, idx, w = buf.sample(state, k, 8, 0.5)
                state = buf.update_priorities(state, idx, batch["reward"] + 1.0)
            else:
                batch, idx = buf.sample(state, k, 8)
            return (state, key), (idx, batch["action"], state.size)

        state = buf.init(jax.tree.map(lambda x: x[0], _batch(np.arange(1))))
        return jax.lax.scan(step, (state, key), jnp.arange(steps))

    (state, _), (idx, actions, sizes) = train(jax.random.key(0))
    idx, actions, sizes = map(np.asarray, (idx, actions, sizes))
    assert int(state.size) == cap and (sizes == np.minimum(np.arange(1, steps + 1), cap)).all()
    assert (idx < sizes[:, None]).all()
    # slot i at step t holds the newest id <= t congruent to i mod cap
    t = np.arange(steps)[:, None]
    expected = t - ((t - idx) % cap)
    np.testing.assert_array_equal(actions, expected)
    if prioritized:
        _assert_tree_consistent(buf, state)


def _batch_traced(t):
    ids = jnp.asarray(t)[None]
    return dict(
        obs=jnp.stack([ids, ids + 0.5, -ids], -1).astype(jnp.float32),
        action=ids.astype(jnp.int32),
        reward=(ids * 2.0).astype(jnp.float32),
        terminated=ids % 2 == 1,
    )


# --- masked adds: transitions with NaN physics never enter the buffer -------------


@pytest.mark.parametrize("kind", ["uniform", "prioritized"])
def test_masked_add_stores_only_valid_items(kind):
    import agents.replay as replay

    buf = replay.UniformReplay(5) if kind == "uniform" else replay.PrioritizedReplay(5)
    state = buf.init(jnp.zeros(()))
    state = buf.add(state, jnp.array([1.0, 2.0, 3.0]), mask=jnp.array([True, False, True]))
    assert int(state.size) == 2 and int(state.insert_pos) == 2
    np.testing.assert_array_equal(np.asarray(state.data[:2]), [1.0, 3.0])
    state = buf.add(state, jnp.array([4.0]), mask=jnp.array([False]))
    assert int(state.size) == 2
    state = buf.add(state, jnp.array([5.0, 6.0, 7.0, 8.0]), mask=jnp.array([True, True, False, True]))
    # 5, 6 fill slots 2-3, 8 goes to slot 4; nothing old was clobbered by the dropped item.
    np.testing.assert_array_equal(np.asarray(state.data), [1.0, 3.0, 5.0, 6.0, 8.0])
    assert int(state.size) == 5 and int(state.insert_pos) == 0
    if kind == "prioritized":  # every stored item is sampleable, nothing else
        _, idx, _ = buf.sample(state, jax.random.PRNGKey(0), 1000, 0.4)
        assert set(np.unique(np.asarray(idx))) == {0, 1, 2, 3, 4}


@pytest.mark.parametrize("kind", ["uniform", "prioritized"])
def test_masked_add_matches_reference_through_wraparound(kind):
    """Dropped items neither take a slot nor clobber old items, also once the ring is full."""
    cap = 7
    buf = UniformReplay(cap) if kind == "uniform" else PrioritizedReplay(cap)
    add = jax.jit(buf.add)
    state = buf.init(_item())
    rng = np.random.default_rng(4)
    ref, n = np.full(cap, -1), 0
    for step in range(12):
        b = int(rng.integers(1, 5))
        ids = np.arange(100 * step, 100 * step + b)
        mask = rng.random(b) < 0.6
        state = add(state, _batch(ids), mask=jnp.asarray(mask))
        for i in ids[mask]:
            ref[n % cap] = i
            n += 1
        assert int(state.size) == min(n, cap) and int(state.insert_pos) == n % cap
        written = ref >= 0
        _assert_rows_match_ids(jax.tree.map(lambda x: x[written], state.data), ref[written])
        if kind == "prioritized":
            _assert_tree_consistent(buf, state)
    if kind == "prioritized":
        _, idx, w = buf.sample(state, jax.random.key(1), 64, 0.5)
        assert (np.asarray(idx) < int(state.size)).all()
        w = np.asarray(w)
        assert np.isfinite(w).all() and (w > 0).all() and (w <= 1 + 1e-6).all()


@pytest.mark.parametrize("kind", ["uniform", "prioritized"])
def test_masked_add_under_vmap_and_scan(kind):
    cap, steps, seeds = 5, 9, 3
    buf = UniformReplay(cap) if kind == "uniform" else PrioritizedReplay(cap)
    masks = np.random.default_rng(5).random((seeds, steps)) < 0.5

    def run(mask):
        def step(state, xs):
            t, m = xs
            return buf.add(state, _batch_traced(t), mask=m[None]), None

        state = buf.init(jax.tree.map(lambda x: x[0], _batch(np.arange(1))))
        return jax.lax.scan(step, state, (jnp.arange(steps), mask))[0]

    states = jax.jit(jax.vmap(run))(jnp.asarray(masks))
    for s in range(seeds):
        kept = np.arange(steps)[masks[s]]
        assert int(states.size[s]) == min(len(kept), cap)
        ref = np.full(cap, -1)
        ref[np.arange(len(kept)) % cap] = kept
        np.testing.assert_array_equal(np.asarray(states.data["action"][s])[ref >= 0], ref[ref >= 0])


# --------------------------------------------------------------------------- #
# Vectorized buffers (what accelerators run) against the loops (what the CPU runs)
# --------------------------------------------------------------------------- #


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["uniform", "prioritized"])
def test_vectorized_buffer_equals_the_loops_bit_for_bit(kind):
    """Masked adds through wrap-around, samples and priority updates with duplicate
    indices: every field of the state, and every sample, equal in both ways. A buffer of
    over 512 KiB makes the loop version read row by row (its large-leaf path)."""
    cap = 12_000

    def make(vectorized):
        if kind == "uniform":
            return UniformReplay(cap, vectorized=vectorized)
        return PrioritizedReplay(cap, alpha=0.6, vectorized=vectorized)

    def program(buf):
        def step(state, x):
            ids, mask, bits, prios = x
            rows = dict(obs=jnp.stack([ids, ids + 0.5, -ids], -1), action=ids.astype(jnp.int32), reward=ids * 2.0,
                        terminated=ids.astype(jnp.int32) % 2 == 1)
            state = buf.add(state, rows, mask=mask)
            if kind == "uniform":
                batch, idx = buf.sample_from_bits(state, bits)
            else:
                batch, idx, weights = buf.sample_from_bits(state, bits, 0.5)
                state = buf.update_priorities(state, idx % 7, prios)  # many duplicate indices
                batch = {**batch, "weights": weights}
            return state, (batch, idx)

        return jax.jit(lambda state, xs: jax.lax.scan(step, state, xs))

    rng = np.random.default_rng(0)
    steps, b, n = 40, 700, 64
    xs = (jnp.asarray(np.arange(steps * b, dtype=np.float32).reshape(steps, b)), jnp.asarray(rng.random((steps, b)) < 0.8),
          jnp.asarray(rng.integers(0, 2**32, (steps, n), dtype=np.uint32)), jnp.asarray(rng.random((steps, n)) * 3))
    loops, vectorized = make(False), make(True)
    expected = program(loops)(loops.init(_item()), xs)
    got = program(vectorized)(vectorized.init(_item()), xs)
    assert int(expected[0].size) == cap  # wrapped around
    for a, e in zip(jax.tree.leaves(got), jax.tree.leaves(expected)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(e))
