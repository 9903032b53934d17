"""Latency of our replay buffers vs flashbax (optional dependency).

Two timings per operation, both jitted with compilation excluded, each the
median over `repeats` timed loops:

* ``call``: one jitted call per operation (state donated for add/update, so
  neither library pays a buffer copy), `block_until_ready` at the end of each
  loop. Dominated by JAX's per-call dispatch cost on CPU.
* ``scan``: `n` operations inside one `lax.scan`, with the buffer state as the
  carry -- how a fused training loop uses a buffer, and the number that
  matters for the DQN. Sample/update steps include one `random.split`.

flashbax counterparts: `make_item_buffer` (uniform) and
`make_prioritised_item_buffer` (prioritised), i.e. independent items like
ours; `ratio` is flashbax time / our time (> 1 means we are faster).

Run: ``python -m benchmarks.replay`` (``pip install flashbax==0.1.3``).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np

from agents.replay import PrioritizedReplay, UniformReplay

_FILL = 10_000  # items written before timing (or capacity, if smaller)


def _example_item():
    """A CartPole-sized transition."""
    return dict(
        obs=jnp.zeros((4,), jnp.float32),
        action=jnp.zeros((), jnp.int32),
        reward=jnp.zeros((), jnp.float32),
        next_obs=jnp.zeros((4,), jnp.float32),
        terminated=jnp.zeros((), jnp.bool_),
    )


def _items(n: int, offset: int = 0):
    ids = offset + jnp.arange(n)
    return dict(
        obs=jnp.stack([ids] * 4, -1).astype(jnp.float32),
        action=(ids % 2).astype(jnp.int32),
        reward=jnp.ones((n,), jnp.float32),
        next_obs=jnp.stack([ids + 1] * 4, -1).astype(jnp.float32),
        terminated=ids % 50 == 0,
    )


def _import_flashbax():
    try:
        import flashbax
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise SystemExit(
            "bench_replay needs flashbax, an optional benchmark-only dependency:\n"
            "    pip install flashbax==0.1.3"
        ) from e
    return flashbax


def median_time(fn, repeats: int) -> float:
    """Median seconds of `fn()` (which must block) over `repeats` runs, after a warm-up."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _time_call(op, state, arg, donate: bool, n: int, repeats: int) -> float:
    """µs per jitted call of `op(state, arg)`; with `donate`, op returns the next state."""
    f = jax.jit(op, donate_argnums=(0,) if donate else ())
    holder = [jax.tree.map(jnp.copy, state)]

    def loop():
        out = None
        for _ in range(n):
            if donate:
                holder[0] = f(holder[0], arg)
            else:
                out = f(holder[0], arg)
        jax.block_until_ready(holder[0] if donate else out)

    return median_time(loop, repeats) / n * 1e6


def _time_scan(step, carry, n: int, repeats: int) -> float:
    """µs per step of `lax.scan(step)` over `n` steps."""
    f = jax.jit(lambda c: jax.lax.scan(lambda c, _: (step(c), None), c, None, length=n)[0])
    return median_time(lambda: jax.block_until_ready(f(carry)), repeats) / n * 1e6


def _filled(add_batch_fn, state, capacity: int):
    """`state` with min(capacity, _FILL) items added, 1000 at a time."""
    fill = min(capacity, _FILL)
    chunk = min(fill, 1000)
    add_chunk = jax.jit(lambda s, i: add_batch_fn(s, _items(chunk, i)))
    for i in range(0, fill, chunk):
        state = add_chunk(state, i)
    return state


def _ours(kind, capacity, batch, add_batch):
    """(add, sample, update or None, filled state) as functions of a state."""
    if kind == "uniform":
        buf = UniformReplay(capacity)
        sample = lambda s, k: buf.sample(s, k, batch)
        update = None
    else:
        buf = PrioritizedReplay(capacity, alpha=0.6)
        sample = lambda s, k: buf.sample(s, k, batch, 0.4)
        update = buf.update_priorities
    add = buf.add
    state = _filled(buf.add, buf.init(_example_item()), capacity)
    return add, sample, update, state


def _flashbax(fbx, kind, capacity, batch, add_batch):
    """Same interface as `_ours`, wrapping flashbax item buffers."""
    kw = dict(max_length=capacity, min_length=1, sample_batch_size=batch)
    if kind == "uniform":
        make = fbx.make_item_buffer
    else:
        make = lambda **k: fbx.make_prioritised_item_buffer(
            **k, priority_exponent=0.6, device="cpu"
        )
    buf = make(**kw, add_batches=add_batch > 1)
    filler = make(**kw, add_batches=True)
    state = _filled(filler.add, buf.init(_example_item()), capacity)

    if add_batch > 1:
        add = buf.add
    else:  # flashbax takes a single item without a batch dim
        add = lambda s, b: buf.add(s, jax.tree.map(lambda x: x[0], b))
    if kind == "uniform":
        def sample(s, k):
            out = buf.sample(s, k).experience
            return out, None
        update = None
    else:
        def sample(s, k):
            out = buf.sample(s, k)
            return out.experience, out.indices, out.probabilities
        update = buf.set_priorities
    return add, sample, update, state


def _measure(impl, capacity, batch, add_batch, n_call, n_scan, repeats):
    add, sample, update, state = impl
    items = _items(add_batch, 123)
    key = jax.random.key(0)
    res = {}

    res["add"] = (
        _time_call(add, state, items, True, n_call, repeats),
        _time_scan(lambda s: add(s, items), state, n_scan, repeats),
    )

    def sample_step(c):
        s, k, acc = c
        k, sk = jax.random.split(k)
        out = sample(s, sk)
        return s, k, acc + out[0]["reward"].sum() + out[0]["obs"].sum()

    res["sample"] = (
        _time_call(lambda s, k: sample(s, k)[0], state, key, False, n_call, repeats),
        _time_scan(sample_step, (state, key, jnp.zeros(())), n_scan, repeats),
    )

    if update is not None:
        n_valid = min(capacity, _FILL)
        idx = jnp.asarray(np.random.default_rng(0).integers(0, n_valid, batch), jnp.int32)
        prios = jnp.linspace(0.1, 3.0, batch, dtype=jnp.float32)

        def update_step(c):
            s, k = c
            k, sk = jax.random.split(k)
            p = prios + jax.random.uniform(sk, (batch,))
            return update(s, idx, p), k

        res["update"] = (
            _time_call(lambda s, p: update(s, idx, p), state, prios, True, n_call, repeats),
            _time_scan(update_step, (state, key), n_scan, repeats),
        )
    return res


def bench_replay(
    capacities=(512, 50_000, 1_000_000),
    batch: int = 32,
    add_batch: int = 1,
    repeats: int = 5,
    n_call: int = 200,
    n_scan: int = 1000,
) -> list[dict]:
    """One row per (capacity, buffer kind, op) with µs per op and flashbax/ours ratios."""
    fbx = _import_flashbax()
    rows = []
    for capacity in capacities:
        for kind in ("uniform", "prioritized"):
            args = (capacity, batch, add_batch, n_call, n_scan, repeats)
            ours = _measure(_ours(kind, capacity, batch, add_batch), *args)
            theirs = _measure(_flashbax(fbx, kind, capacity, batch, add_batch), *args)
            for op in ours:
                (oc, os_), (fc, fs) = ours[op], theirs[op]
                rows.append(
                    dict(
                        capacity=capacity, kind=kind, op=op,
                        ours_call_us=oc, fbx_call_us=fc, call_ratio=fc / oc,
                        ours_scan_us=os_, fbx_scan_us=fs, scan_ratio=fs / os_,
                    )
                )
    return rows


def format_table(rows: list[dict]) -> str:
    head = (
        f"{'capacity':>9} {'buffer':>11} {'op':>7} | {'ours call':>9} {'fbx call':>9} {'ratio':>6}"
        f" | {'ours scan':>9} {'fbx scan':>9} {'ratio':>6}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['capacity']:>9} {r['kind']:>11} {r['op']:>7} | {r['ours_call_us']:>9.2f}"
            f" {r['fbx_call_us']:>9.2f} {r['call_ratio']:>6.2f} | {r['ours_scan_us']:>9.2f}"
            f" {r['fbx_scan_us']:>9.2f} {r['scan_ratio']:>6.2f}"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--capacities", type=int, nargs="+", default=[512, 50_000, 1_000_000])
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--add-batch", type=int, default=1)
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    rows = bench_replay(tuple(args.capacities), args.batch, args.add_batch, args.repeats)
    print(f"µs per op (jax {jax.__version__}, {jax.devices()[0].platform}); ratio = flashbax / ours")
    print(format_table(rows))
