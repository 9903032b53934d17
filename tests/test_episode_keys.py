"""The pcg4d episode keys behind auto-reset: the hash as published, keys that work with
`jax.random`, and reset draws that are uniform and independent across envs and episodes."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import envs
from envs.episode_keys import PCG4D, episode_keys, next_episode_key, pcg4d
from envs.wrappers import AutoReset


def pcg4d_reference(v):
    """Jarzynski and Olano's GLSL listing, in Python integers modulo 2**32."""
    m = 0xFFFFFFFF
    x, y, z, w = ((c * 1664525 + 1013904223) & m for c in v)
    x = (x + y * w) & m; y = (y + z * x) & m; z = (z + x * y) & m; w = (w + y * z) & m  # noqa: E702
    x, y, z, w = (c ^ (c >> 16) for c in (x, y, z, w))
    x = (x + y * w) & m; y = (y + z * x) & m; z = (z + x * y) & m; w = (w + y * z) & m  # noqa: E702
    return x, y, z, w


def test_pcg4d_matches_the_published_listing():
    inputs = [(0, 0, 0, 0), (1, 2, 3, 4), (0xFFFFFFFF,) * 4, (0xDEADBEEF, 12345, 0, 0xB175)]
    columns = [jnp.array(c, jnp.uint32) for c in zip(*inputs)]
    got = np.stack([np.asarray(c) for c in pcg4d(*columns)], axis=1)
    assert got.tolist() == [list(pcg4d_reference(v)) for v in inputs]


def test_pcg4d_keys_work_with_jax_random():
    key = jax.random.key(0, impl=PCG4D)
    a, b = jax.random.split(key)
    assert jax.random.key_data(a).shape == (2,) and not np.array_equal(jax.random.key_data(a), jax.random.key_data(b))
    u = jax.random.uniform(a, (1000,))
    assert u.dtype == jnp.float32 and 0 <= float(u.min()) and float(u.max()) < 1
    assert jax.random.normal(b, (3, 5)).shape == (3, 5)
    assert jax.random.bits(a, (7,), jnp.uint8).dtype == jnp.uint8
    assert not np.array_equal(jax.random.key_data(jax.random.fold_in(key, 1)), jax.random.key_data(jax.random.fold_in(key, 2)))
    np.testing.assert_array_equal(jax.random.uniform(a, (5,)), u[:5])  # deterministic, and counter-based


def test_episode_key_stream_advances_and_draws_independent_uniform_resets():
    """Four reset coordinates for each of 3 episodes of 50,000 envs: each coordinate uniform
    (Kolmogorov-Smirnov), no correlation between coordinates, episodes or neighbouring envs."""
    words = jax.vmap(episode_keys)(jax.random.split(jax.random.key(1), 50_000))

    def episodes(w):
        draws = []
        for _ in range(3):
            nxt, key = next_episode_key(w)
            assert [word.shape for word in nxt] == [(), ()]  # two uint32 scalars per env
            w = nxt
            draws.append(jax.random.uniform(key, (4,)))
        return jnp.concatenate(draws)

    u = np.asarray(jax.jit(jax.vmap(episodes))(words), np.float64)  # (envs, 12)
    for column in u.T:
        assert stats.kstest(column, "uniform").pvalue > 1e-4
    corr = np.corrcoef(np.concatenate([u[:-1], u[1:]], axis=1).T)  # this env and the next one
    off_diagonal = corr[~np.eye(24, dtype=bool)]
    assert np.abs(off_diagonal).max() < 0.025  # ~5 standard errors at 50,000 samples


@pytest.mark.parametrize("name", ["cartpole", "cartpole-mjx"])
def test_auto_reset_draws_the_first_episode_from_the_given_key_and_later_ones_from_its_stream(name):
    env = envs.make(name)
    key = jax.random.PRNGKey(3)
    state = AutoReset(env).reset(key)
    np.testing.assert_array_equal(state.obs, env.reset(jax.random.split(key)[1]).obs)
    words = np.asarray(state.info["rng"])
    assert words.dtype == np.uint32 and words.shape == (2,)
    done = state.replace(done=jnp.ones_like(state.done))
    fresh = AutoReset(env).reset_if_done(done)
    _, episode_key = next_episode_key(state.info["rng"])
    np.testing.assert_array_equal(fresh.obs, env.reset(episode_key).obs)
    assert not np.array_equal(fresh.info["rng"], words)


def test_next_episode_key_splits_the_key_of_seed_and_counter_and_advances_only_the_counter():
    """The hand-fused stream step gives exactly the second key of `jax.random.split`."""
    seed, counter = episode_keys(jax.random.key(5))
    for k in range(3):
        key = jax.random.wrap_key_data(jnp.stack([seed, counter + jnp.uint32(k)]), impl=PCG4D)
        (next_seed, next_counter), ours = next_episode_key((seed, counter + jnp.uint32(k)))
        assert next_seed == seed and next_counter == counter + jnp.uint32(k + 1)
        np.testing.assert_array_equal(jax.random.key_data(ours), jax.random.key_data(jax.random.split(key)[1]))
    (_, wrapped), _ = next_episode_key((seed, jnp.uint32(0xFFFFFFFF)))
    assert wrapped == 0  # the counter wraps around
