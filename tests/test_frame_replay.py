"""agents/frame_replay.py against the replay of whole rows it replaces: a stream of stacked frames as `envs.pixels`
makes them (resets fill the stack, steps that are not physics end their episode with the last frame again), its
n-step rows made by `agents.td3.n_step_rows` from whole stacks, and every transition the frame replay can sample
rebuilt equal to its row, across episode ends, resets and the ring's wrap."""

import jax
import jax.numpy as jnp
import numpy as np

from agents.frame_replay import FrameReplay
from agents.sac import Transition
from agents.td3 import n_step_rows

ENVS, STACK, CHANNELS, STEPS, DISCOUNTING = 3, 3, 2, 3, 0.9


def pixel_stream(count: int, seed: int = 0):
    """`count` steps of ENVS envs: (obs, action, reward, discount, next_obs, ended, valid), as `envs.pixels` and
    `agents.sac.step_envs` give them; a step that is not physics has a NaN reward."""
    rng = np.random.default_rng(seed)
    new_frames = lambda: rng.integers(0, 256, (ENVS, 2, 2, CHANNELS), dtype=np.uint8)
    obs = np.tile(new_frames(), (1, 1, 1, STACK))
    for _ in range(count):
        valid = rng.random(ENVS) < 0.9
        ended = (rng.random(ENVS) < 0.15) | ~valid
        terminated = ended & valid & (rng.random(ENVS) < 0.5)
        frame = np.where(valid[:, None, None, None], new_frames(), obs[..., -CHANNELS:])
        next_obs = np.concatenate([obs[..., CHANNELS:], frame], -1)
        reward = np.where(valid, rng.normal(size=ENVS), np.nan).astype(np.float32)
        action = rng.uniform(-1, 1, (ENVS, 2)).astype(np.float32)
        yield obs, action, reward, (1.0 - terminated).astype(np.float32), next_obs, ended, valid
        obs = np.where(ended[:, None, None, None], np.tile(new_frames(), (1, 1, 1, STACK)), next_obs)


def windowed(window, step: Transition, ended, valid, written: int):
    """The n-step rows completed by `step`, as `agents.td3.TD3.collect` makes them."""
    newest = (step, jnp.asarray(ended, jnp.float32), jnp.asarray(valid, jnp.float32))
    window = jax.tree.map(lambda old, new: jnp.concatenate([old[1:], new[None]]), window, newest)
    rows, keep = n_step_rows(*window, DISCOUNTING)
    return window, rows, keep & (written >= STEPS - 1)


def zeros_window(steps: Transition):
    """An empty window of STEPS steps of every env, as `TD3.init` makes it."""
    return jax.tree.map(lambda x: jnp.zeros((STEPS, *np.shape(x)), jnp.asarray(x).dtype),
                        (steps, jnp.zeros(ENVS), jnp.zeros(ENVS)))


def test_every_sampleable_transition_is_rebuilt_equal_to_its_row_of_whole_stacks():
    replay = FrameReplay(capacity=12, num_envs=ENVS, frame_stack=STACK, num_steps=STEPS)
    assert replay.steps == 4 + 2 + 2  # 12 transitions of 3 envs; 2 rows not yet complete; 2 older frames
    state = replay.init((2, 2, CHANNELS), 2)
    add, sample = jax.jit(replay.add), jax.jit(replay.sample_from_bits)
    rows_of_stacks, frame_window, index_window = {}, None, None
    compared = invalid_seen = 0
    for written, (obs, action, reward, discount, next_obs, ended, valid) in enumerate(pixel_stream(60)):
        whole = Transition(jnp.asarray(obs), jnp.asarray(action), jnp.asarray(reward), jnp.asarray(discount),
                           jnp.asarray(next_obs))
        index = jnp.full((ENVS,), written, jnp.int32)
        indexed = whole._replace(obs=index, next_obs=index)
        frame_window = frame_window or zeros_window(whole)
        index_window = index_window or zeros_window(indexed)
        frame_window, rows, keep = windowed(frame_window, whole, ended, valid, written)
        index_window, index_rows, index_keep = windowed(index_window, indexed, ended, valid, written)
        np.testing.assert_array_equal(keep, index_keep)
        for env in np.flatnonzero(keep):
            rows_of_stacks[written - STEPS + 1, env] = jax.tree.map(lambda x: np.asarray(x[env]), rows)
        state = add(state, jnp.asarray(obs), jnp.asarray(next_obs), jnp.asarray(ended), index_rows, index_keep)

        oldest, count = (int(x) for x in replay.sampled_steps(state))
        drawn = count * ENVS  # bits 0, 1, ...: every sampleable (step, env) once, in order
        assert drawn == min(max(written + 1 - STEPS + 1, 0), 4) * ENVS
        if not drawn:
            continue
        batch, learnable = sample(state, jnp.arange(drawn, dtype=jnp.uint32))
        kept = [(oldest + k // ENVS, k % ENVS) in rows_of_stacks for k in range(drawn)]
        assert bool(learnable) == any(kept)
        batch = jax.tree.map(np.asarray, batch)
        assert all(np.isfinite(batch.reward)) and all(np.isfinite(batch.discount))
        for k, was_kept in enumerate(kept):
            drawn_row = jax.tree.map(lambda x: x[k], batch)
            if was_kept:
                expected = rows_of_stacks[oldest + k // ENVS, k % ENVS]
                for name, value in expected._asdict().items():
                    np.testing.assert_array_equal(getattr(drawn_row, name), value, name)
                compared += 1
            elif any(kept):  # replaced by a learnable draw of the same sample
                invalid_seen += 1
                assert any(all(np.array_equal(a, b) for a, b in zip(drawn_row, jax.tree.map(lambda x: x[m], batch)))
                           for m in range(drawn) if kept[m])
    assert compared > 400 and invalid_seen > 20


def test_a_step_costs_two_frames_whatever_the_stack():
    replay = FrameReplay(capacity=100_000, num_envs=64, frame_stack=3, num_steps=3)
    state = jax.eval_shape(lambda: replay.init((84, 84, 3), 1))
    frame_bytes = sum(x.size * x.dtype.itemsize for x in (state.seen, state.next_frame))
    assert frame_bytes == replay.steps * 64 * 2 * 84 * 84 * 3 and replay.steps * 64 < 100_000 + 5 * 64
