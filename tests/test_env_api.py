"""The shared env API: registry, wrappers, jit/vmap/scan, bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.jax_compile_cache import CompileCounter

NAMES = ["cartpole", "cartpole-mjx"]


def test_names():
    assert set(NAMES) <= set(envs.names())


def test_unknown_env_lists_valid_names():
    with pytest.raises(ValueError, match=r"unknown env 'cartpol'.*cartpole-mjx"):
        envs.make("cartpol")


def test_unknown_override_lists_valid_options():
    with pytest.raises(ValueError, match=r"unknown option.*'gravty'.*valid options.*gravity"):
        envs.make("cartpole", gravty=9.0)
    with pytest.raises(ValueError, match="integrator"):
        envs.make("cartpole", integrator="rk4")


# (name, overrides) whose spec is checked against the env `make` builds: discrete by a class's bins, by a
# partial's and by an `action_bins=n` override; continuous; analytic.
SPEC_CASES = [("cartpole-mjx", {}), ("pendulum-mjx-discrete", {}), ("pendulum-mjx", {"action_bins": 5}),
              ("hopper", {}), ("pendulum-mjx", {}), ("cartpole", {})]


def test_spec_tells_what_make_builds():
    """`envs.spec`, which the CLI chooses the agent from, against the envs `make` builds
    (tests/test_imports.py: it loads no MJX and no device)."""
    for name, overrides in SPEC_CASES:
        env = envs.make(name, **overrides)
        assert envs.spec(name, **overrides) == (env.num_actions, env.action_size, False), name
    with pytest.raises(ValueError, match=r"unknown option.*'gravty'"):  # checked as make checks them
        envs.spec("cartpole-mjx", gravty=9.0)


def test_overrides_reach_the_physics():
    env = envs.make("cartpole", gravity=1.0, integrator="semi_implicit", episode_length=7)
    assert env.unwrapped.physics.gravity == 1.0
    assert env.unwrapped.integrator == "semi_implicit"
    assert env.episode_length == 7


@pytest.mark.parametrize("name", NAMES)
def test_wrong_action_shape_or_dtype_fails_at_trace_time(name):
    env = envs.make(name)
    state = env.reset(jax.random.PRNGKey(0))
    with pytest.raises(TypeError, match="one integer action index"):
        jax.eval_shape(env.step, state, jnp.zeros((2,), jnp.int32))
    with pytest.raises(TypeError, match="dtype float32"):
        jax.eval_shape(env.step, state, jnp.float32(1.0))
    batched = envs.wrap_for_training(env, 4)
    with pytest.raises(TypeError, match="leading dimension 4"):
        jax.eval_shape(batched.step, batched.reset(jax.random.PRNGKey(0)), jnp.zeros((3,), jnp.int32))


def test_an_mjx_task_stepped_outside_jit_runs_its_physics_as_one_program():
    """Called op by op (a notebook, a first try), MJX's step compiled hundreds of small programs
    (479 for cartpole-mjx's first step, 18 s on 2 cores) and its second step compiled again; its
    physics is one jitted program, compiled once, and the step equals the jitted env's."""
    env = envs.make("cartpole-mjx")
    state = env.reset(jax.random.PRNGKey(0))
    with CompileCounter() as counter:
        stepped = env.step(state, 1)
    assert 0 < counter.compiles <= 60, counter.compiled
    with CompileCounter() as again:
        env.step(stepped, 0)
    assert again.compiled == []
    jax.tree.map(np.testing.assert_array_equal, stepped, jax.jit(env.step)(state, 1))


def test_programs_that_step_an_mjx_task_trace_its_physics_once(monkeypatch):
    """A run's programs (training, judge, final evaluation) each step the env: MJX's step is traced
    once per shape for all of them, not once each (seconds of a run's start on a CPU)."""
    import mujoco.mjx

    env = envs.make("pendulum-mjx-discrete")  # a task no other test here traces in this process
    calls = []
    real_step = mujoco.mjx.step
    monkeypatch.setattr(mujoco.mjx, "step", lambda model, data: calls.append(1) or real_step(model, data))
    state = env.reset(jax.random.PRNGKey(0))
    jax.jit(env.step).lower(state, 1)
    batch = envs.wrap_for_training(env, 8)
    jax.jit(batch.step).lower(batch.reset(jax.random.PRNGKey(0)), jnp.zeros(8, jnp.int32))
    assert len(calls) <= 1


# cartpole-mjx in the slow tests: pendulum-mjx-discrete runs an MJX task's scan with auto-reset here
@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "cartpole-mjx" else n for n in NAMES])
def test_jit_vmap_scan_1024_envs_500_steps_with_auto_reset(name):
    num_envs, steps = 1024, 500
    env = envs.wrap_for_training(envs.make(name), num_envs)

    def body(carry, _):
        state, key = carry
        key, action_key = jax.random.split(key)
        action = jax.random.randint(action_key, (num_envs,), 0, 2)
        state = env.step(state, action)
        return (state, key), (state.done, state.info["truncation"], state.obs, state.info["last_length"])

    @jax.jit
    def run(key):
        return jax.lax.scan(body, (env.reset(key), key), None, steps)

    (final, _), (done, truncation, obs, last_length) = run(jax.random.PRNGKey(0))
    done, obs = np.asarray(done, bool), np.asarray(obs)
    assert done.sum() > num_envs * 5  # random play ends episodes every ~20 steps
    assert float(truncation.sum()) == 0.0  # none lasts 500 steps under random play
    # After every done the next observation is a fresh start: inside the reset box.
    t, i = np.nonzero(done)
    assert np.abs(obs[t, i]).max() <= 0.05
    # Fresh episodes differ from env to env and from episode to episode.
    assert len(np.unique(obs[t, i], axis=0)) == len(t)
    assert int(last_length.max()) < 500 and int(last_length[-1].min()) > 0


def test_time_limit_reports_truncation_not_termination():
    env = envs.make("cartpole", episode_length=5, x_threshold=100.0, theta_threshold=100.0)
    state = env.reset(jax.random.PRNGKey(0))
    for t in range(5):
        state = env.step(state, 1)
    assert float(state.done) == 1.0 and float(state.info["truncation"]) == 1.0


def test_termination_on_the_last_step_is_termination():
    env = envs.make("cartpole", episode_length=1, x_threshold=0.0)
    state = env.step(env.reset(jax.random.PRNGKey(0)), 1)
    assert float(state.done) == 1.0 and float(state.info["truncation"]) == 0.0


def test_final_obs_is_kept_on_auto_reset():
    env = envs.wrap_for_training(envs.make("cartpole", episode_length=3), 2)
    state = env.reset(jax.random.PRNGKey(0))
    for _ in range(3):
        previous = state
        state = env.step(state, jnp.array([1, 0]))
    assert state.done.tolist() == [1.0, 1.0]
    inner = envs.make("cartpole")
    expected = jax.vmap(inner.step)(previous, jnp.array([1, 0])).obs
    np.testing.assert_allclose(np.asarray(state.info["final_obs"]), np.asarray(expected), rtol=1e-6)
    assert not np.allclose(np.asarray(state.obs), np.asarray(expected))
    assert state.info["last_length"].tolist() == [3, 3] and state.info["last_return"].tolist() == [3.0, 3.0]


def test_physics_can_be_vmapped_for_domain_randomisation():
    env = envs.CartPole()
    gravities = jnp.array([1.0, 9.8, 20.0])
    physics = jax.vmap(lambda g: envs.CartPolePhysics(gravity=g))(gravities)
    state = env.reset(jax.random.PRNGKey(0))
    start = jnp.array([0.0, 0.0, 0.1, 0.0])
    state = state.replace(pipeline_state=envs.CartPoleState.from_array(start), obs=start)

    @jax.vmap
    def step(p):
        return env.replace(physics=p).step(state, 1).obs

    theta_dot = np.asarray(step(physics))[:, 3]
    assert theta_dot[0] < theta_dot[1] < theta_dot[2]  # stronger gravity, faster fall


def test_batched_auto_reset_gives_the_same_states_as_vmapped_auto_reset():
    """Every branch (no env ended, a few reset by index, all) against VmapWrapper(AutoReset)."""
    num_envs = 64
    env = envs.make("cartpole")
    reference = envs.VmapWrapper(envs.AutoReset(env), num_envs)
    by_index = envs.BatchedAutoReset(env, num_envs, max_resets=2, reset_by_index=True)
    selected = envs.BatchedAutoReset(env, num_envs, reset_by_index=False)

    def run(wrapped):
        def body(state, key):
            action = jax.random.randint(key, (num_envs,), 0, 2)
            state = wrapped.step(state, action)
            return state, (state.obs, state.info["final_obs"], state.done)

        keys = jax.random.split(jax.random.PRNGKey(1), 200)
        return jax.jit(lambda: jax.lax.scan(body, wrapped.reset(jax.random.PRNGKey(0)), keys))()

    expected = run(reference)
    ended = np.asarray(expected[1][2]).sum(axis=1)
    assert (ended == 0).any() and ((ended > 0) & (ended <= 2)).any() and (ended > 2).any()
    for wrapped in (by_index, selected):
        for a, b in zip(jax.tree.leaves(run(wrapped)), jax.tree.leaves(expected)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


class _CostlyReset(envs.Wrapper):
    costly_reset = True  # as dm_control's cheetah, whose reset runs 200 physics steps


@pytest.mark.slow  # compiles a vmapped training step of its own
def test_a_costly_reset_under_a_vmap_over_seeds_decides_for_every_seed_at_once(monkeypatch):
    """Under the agents' vmap over seeds, a costly reset's batch switches once over the envs of every
    seed (none ended: no reset work; a few: by index; many: all), with the states of the select that
    resets every env on every step, per seed."""
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    num_envs, seeds = 8, 3
    env = _CostlyReset(envs.make("cartpole"))
    across = envs.BatchedAutoReset(env, num_envs, max_resets=1, under_vmap=True)
    selected = envs.BatchedAutoReset(env, num_envs, reset_by_index=False, under_vmap=True)
    assert across.reset_across_vmap and not envs.BatchedAutoReset(envs.make("cartpole"), 8, under_vmap=True).reset_by_index
    on_warp = envs.make("cartpole-mjx")  # under MuJoCo Warp a reset is Warp's forward pass: costly
    assert not envs.BatchedAutoReset(on_warp, 8, under_vmap=True).reset_by_index
    monkeypatch.setattr(on_warp.unwrapped, "impl", "warp")
    assert envs.BatchedAutoReset(on_warp, 8, under_vmap=True).reset_across_vmap

    def run(wrapped, key):
        def body(state, key):
            state = wrapped.step(state, jax.random.randint(key, (num_envs,), 0, 2))
            return state, (state.obs, state.info["final_obs"], state.done)

        return jax.lax.scan(body, wrapped.reset(key), jax.random.split(key, 150))[1]

    keys = jax.random.split(jax.random.PRNGKey(2), seeds)
    expected = jax.jit(jax.vmap(lambda key: run(selected, key)))(keys)
    ended = np.asarray(expected[2]).sum(axis=(0, 2))  # over seeds and envs, per step
    assert (ended == 0).any() and ((ended > 0) & (ended <= seeds)).any() and (ended > seeds).any()
    for a, b in zip(jax.tree.leaves(jax.jit(jax.vmap(lambda key: run(across, key)))(keys)), jax.tree.leaves(expected)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("name", ["cartpole", "acrobot", pytest.param("cartpole-mjx", marks=pytest.mark.slow)])
def test_a_batch_of_one_steps_unbatched_to_the_same_states(name, monkeypatch):
    """Without reset-by-index (the GPU's choice) an analytic env's batch of one steps as
    scalars, MJX's stays batched (its unbatched step is slower); both give the same states,
    episode ends and fresh episodes as VmapWrapper(AutoReset), with `[1]`-shaped leaves
    (bit for bit for the CartPole; XLA rounds acrobot's integrator and a few of MJX's ~1e-25
    rotation entries differently unbatched, MJX's forced here)."""
    env = envs.make(name, episode_length=30)  # acrobot's random play rarely ends otherwise
    assert envs.BatchedAutoReset(env, 1, reset_by_index=False).step_unbatched == (name != "cartpole-mjx")
    assert not envs.BatchedAutoReset(env, 1, reset_by_index=True).step_unbatched
    assert not envs.BatchedAutoReset(env, 2, reset_by_index=False).step_unbatched
    assert not envs.BatchedAutoReset(env, 1, reset_by_index=False, under_vmap=True).step_unbatched
    monkeypatch.setattr(type(env.unwrapped), "batch_of_one_as_scalars", True)
    one = envs.BatchedAutoReset(env, 1, reset_by_index=False)
    reference = envs.VmapWrapper(envs.AutoReset(env), 1)
    assert one.step_unbatched

    def run(wrapped):
        def body(state, key):
            state = wrapped.step(state, jax.random.randint(key, (1,), 0, 2))
            return state, state

        keys = jax.random.split(jax.random.PRNGKey(2), 120)
        return jax.jit(lambda: jax.lax.scan(body, wrapped.reset(jax.random.PRNGKey(0)), keys))()[1]

    ours, expected = run(one), run(reference)
    assert int(np.asarray(expected.done).sum()) >= 3  # several fresh episodes compared
    assert jax.tree.structure(ours) == jax.tree.structure(expected)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(expected)):
        assert a.shape == b.shape and a.shape[1] == 1
        if name == "cartpole" or not jnp.issubdtype(a.dtype, jnp.floating):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
        else:
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(ours.done), np.asarray(expected.done))


@pytest.mark.parametrize("name", ["cartpole", "cartpole-mjx"])
def test_a_batch_carries_one_scalar_per_env_for_each_value_its_next_step_reads(name):
    """The contract of envs/core.py: physics state, key stream and step counter are `[N]`
    arrays (an `[N, k]` array makes XLA recompute an env's step once per column on a GPU);
    `episode_stats=False` leaves the statistics out."""
    batch = envs.wrap_for_training(envs.make(name), 8, episode_stats=False)
    state = batch.reset(jax.random.PRNGKey(0))
    assert not {"episode_return", "last_return"} & set(state.info)
    assert [w.shape for w in state.info["rng"]] == [(8,), (8,)] and state.info["steps"].shape == (8,)
    if name == "cartpole":
        assert [leaf.shape for leaf in jax.tree.leaves(state.pipeline_state)] == [(8,)] * 4
        np.testing.assert_array_equal(state.obs, state.pipeline_state.as_array())
    stats = envs.wrap_for_training(envs.make(name), 8).reset(jax.random.PRNGKey(0))
    assert stats.info["episode_return"].shape == (8,)


def test_a_loop_that_reads_no_observation_carries_none():
    """XLA leaves `obs` and `info["final_obs"]` out of a jitted loop that does not read them:
    the benchmark loop's carry holds only `[N]` arrays (and the loop's own scalars)."""
    import re

    from benchmarks.env_throughput import rollout_fn

    num_envs = 64
    text = rollout_fn("cartpole", num_envs, 10).lower(jax.random.PRNGKey(0)).compile().as_text()
    scan = [line for line in text.splitlines() if " while(" in line and 'op_name="jit(run)/while"' in line]
    carry = re.search(r"= \(([^)]*)\) while\(", scan[0]).group(1)
    shapes = re.findall(r"([a-z]+\d*)\[([\d,]*)\]", carry)
    # The scan's counter, the physics (4 x f32), the key stream and step counter (u32, s32; XLA
    # may add values it hoists out of the loop, e.g. the seed word's share of the hash), the
    # action key and the reward total; no f32[64,4] observation, nothing two-dimensional.
    assert sorted(s for s in shapes if s[0] == "f32") == sorted([("f32", "")] + [("f32", "64")] * 4), carry
    assert {s for s in shapes if s[0] != "f32"} == {("s32", ""), ("s32", "64"), ("u32", "64"), ("u32", "2")}, carry


class _ResetOverflows(envs.CartPoleMjx):
    """Reports a constraint overflow for a state at time 0 (a reset's), as MuJoCo Warp's forward pass at reset
    reports one when its rows run out (tests/test_warp.py runs Warp itself)."""

    def _overflow(self, data):
        return jnp.where(data.time == 0, envs.mjx_warp.OVERFLOW_CONSTRAINTS, 0.0).astype(jnp.float32)


@pytest.mark.parametrize("reset_by_index", [False, pytest.param(True, marks=pytest.mark.slow)])  # a compile each
def test_a_reset_that_overflowed_is_counted_on_the_step_whose_end_started_it(reset_by_index):
    """`reset` reports its own Warp work's overflow; an auto-reset adds it to the step that ended the episode, so
    the agents keep that transition from the learner and count it (the fresh episode's own steps are physics)."""
    env = envs.TimeLimit(_ResetOverflows(), 3)
    assert float(env.reset(jax.random.PRNGKey(0)).info["overflow"]) == envs.mjx_warp.OVERFLOW_CONSTRAINTS
    batch = envs.BatchedAutoReset(env, 4, max_resets=1 if reset_by_index else None, reset_by_index=reset_by_index)

    def run(key):
        return jax.lax.scan(lambda s, _: (batch.step(s, jnp.zeros(4, jnp.int32)),) * 2, batch.reset(key), length=7)[1]

    states = jax.jit(run)(jax.random.PRNGKey(0))
    ended = np.asarray(states.done) > 0  # every env, at its third and sixth step
    np.testing.assert_array_equal(np.asarray(states.info["overflow"]), np.where(ended, 2.0, 0.0))
    assert ended[[2, 5]].all() and ended.sum() == 8
