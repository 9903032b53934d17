"""SAC (`agents.sac`): its config, transitions, one update against Brax's own training step,
seeds under vmap, exact resume from a host copy of the train state, and (slow) learning."""

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.sac import SAC, SACConfig, Transition, train, unpack
from envs.batching import one_after_another
from conftest import USERS_CODEGEN


class Drift(envs.Env):
    """A point on a line pushed by its action: obs [x, steps / 10], reward -x^2. Cheap to
    compile, so the tests spend their time on SAC. With `terminate_at`, |x| beyond it terminates."""

    observation_size = 2
    action_size = 1

    def __init__(self, terminate_at=None):
        self.terminate_at = terminate_at

    def reset(self, key):
        x = jax.random.uniform(key, (), minval=-1.0, maxval=1.0)
        zero = jnp.zeros(())
        return envs.State(jnp.stack([x, zero]), jnp.stack([x, zero]), zero, zero,
                          info={"truncation": zero, "nan": zero})

    def step(self, state, action):
        self.check_action(action)
        x = state.pipeline_state[0] + 0.2 * action[0]
        t = state.pipeline_state[1] + 0.1
        done = jnp.zeros(()) if self.terminate_at is None else (jnp.abs(x) > self.terminate_at).astype(jnp.float32)
        obs = jnp.stack([x, t])
        return state.replace(pipeline_state=obs, obs=obs, reward=-x * x, done=done)


def drift(episode_length=20, terminate_at=None):
    return envs.TimeLimit(Drift(terminate_at), episode_length=episode_length)


SMALL = SACConfig(num_timesteps=392, num_envs=4, batch_size=16, grad_updates_per_step=2, min_replay_size=32,
                  max_replay_size=256, num_evals=4, num_eval_envs=3, hidden=(8,))


def assert_trees_equal(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# ---- the config ---------------------------------------------------------------------
def test_chunks_round_up_to_whole_env_step_batches_as_brax_does():
    config = SACConfig(num_timesteps=1000, num_envs=16, min_replay_size=100, num_evals=4)
    assert config.prefill_steps == 112  # 100 rounded up to 7 batches of 16
    assert config.num_chunks == 3  # Brax's num_evals counts its evaluation before training
    assert config.iterations_per_chunk == 19  # ceil(888 / (3 * 16))
    assert config.eval_every == 19 * 16
    assert config.total_steps == 112 + 3 * 304 >= config.num_timesteps
    assert config.eval_episodes == config.num_eval_envs
    assert SMALL.total_steps == SMALL.num_timesteps  # SMALL divides evenly


@pytest.mark.parametrize("field,value,message", [
    ("num_envs", 0, "SACConfig.num_envs"),
    ("tau", 0.0, "SACConfig.tau"),
    ("discounting", 1.5, "SACConfig.discounting"),
    ("num_evals", 1, "SACConfig.num_evals"),
    ("hidden", (), "SACConfig.hidden"),
    ("hidden", (8, 0), "SACConfig.hidden"),
    ("min_replay_size", 392, "min_replay_size .* must be below num_timesteps"),
    ("max_replay_size", 8, "max_replay_size .* raise it to"),
    ("solve_return", float("nan"), "SACConfig.solve_return"),
])
def test_bad_settings_are_refused_with_the_option_and_the_fix(field, value, message):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(SMALL, **{field: value})


def test_a_discrete_env_is_refused():
    with pytest.raises(ValueError, match="continuous-action env"):
        SAC(SMALL, envs.make("cartpole"))


# ---- transitions -----------------------------------------------------------------------
def collected(env, steps=7):
    sac = SAC(dataclasses.replace(SMALL, num_envs=1, min_replay_size=0), env)
    ts = jax.jit(sac.init)(jax.random.PRNGKey(0))
    collect = jax.jit(sac.collect)
    for i in range(steps):
        ts, _ = collect(ts, jax.random.PRNGKey(i))
    return unpack(ts.buffer.data[:steps], 2, 1)


def test_truncation_bootstraps_from_the_true_final_observation():
    batch = collected(drift(episode_length=3))
    np.testing.assert_array_equal(np.asarray(batch.discount), 1.0)  # only truncation ends episodes
    t = np.round(np.asarray(batch.next_obs[:, 1]) * 10)
    np.testing.assert_array_equal(t, [1, 2, 3, 1, 2, 3, 1])  # the final observation, never the reset one
    np.testing.assert_array_equal(np.round(np.asarray(batch.obs[:, 1]) * 10), [0, 1, 2, 0, 1, 2, 0])
    # The stored reward is the reward of the step into next_obs.
    np.testing.assert_allclose(np.asarray(batch.reward), -np.asarray(batch.next_obs[:, 0]) ** 2, rtol=1e-6)


def test_termination_does_not_bootstrap():
    batch = collected(drift(episode_length=100, terminate_at=0.0), steps=3)  # every step terminates
    np.testing.assert_array_equal(np.asarray(batch.discount), 0.0)


# ---- one update against Brax's own training step -------------------------------------------
def brax_first_update(monkeypatch, config, env, seed=0):
    """Brax's `sac.train` run for its first fill and one iteration with one gradient step; what
    went into and came out of its temperature, critic and actor updates, caught as it ran."""
    from brax.training import gradients
    from brax.training.agents.sac import train as brax_sac

    from benchmarks import brax_trainers

    caught = {}
    original = gradients.gradient_update_fn

    def catching(loss_fn, optimizer, pmap_axis_name, has_aux=False):
        name = loss_fn.__name__
        update = original(loss_fn, optimizer, pmap_axis_name, has_aux)

        def f(*args, optimizer_state):
            out = update(*args, optimizer_state=optimizer_state)
            jax.debug.callback(lambda *tree: caught.__setitem__(name, tree), args, optimizer_state, out)
            return out

        return f

    monkeypatch.setattr(gradients, "gradient_update_fn", catching)
    kwargs = brax_trainers.trainer_kwargs(config)
    kwargs.update(num_timesteps=config.prefill_steps + config.num_envs, num_evals=2, seed=seed)
    brax_env = envs.to_brax(env)
    _, params, metrics = brax_sac.train(brax_env, episode_length=brax_env.episode_length, **kwargs)
    return caught, params, metrics


@pytest.mark.slow
def test_one_update_equals_brax_sac_training_step(monkeypatch):
    """Given what Brax's trainer fed its first gradient step (the parameters, the optimizer states,
    the batch, the keys), our `SAC.learn` gives Brax's losses and new parameters: the temperature,
    critic and actor updates read the right parameters (those before the step) in the right order."""
    config = dataclasses.replace(SMALL, grad_updates_per_step=1, num_envs=4, min_replay_size=32)
    env = drift(episode_length=1000)  # no truncation in Brax's batch (its loss would drop those rows)
    caught, brax_params, brax_metrics = brax_first_update(monkeypatch, config, env)
    assert set(caught) == {"alpha_loss", "critic_loss", "actor_loss"}

    (log_alpha, policy_params, normalizer, transitions, key_alpha), alpha_opt, _ = caught["alpha_loss"]
    (q_params, _, _, target_q_params, alpha, _, key_critic), q_opt, brax_critic = caught["critic_loss"]
    (_, _, _, _, _, key_actor), policy_opt, brax_actor = caught["actor_loss"]
    np.testing.assert_array_equal(np.asarray(transitions.extras["state_extras"]["truncation"]), 0.0)
    np.testing.assert_allclose(alpha, np.exp(log_alpha))

    sac = SAC(config, env)
    ts = sac.init(jax.random.PRNGKey(0))
    ts = ts.replace(params=(normalizer, policy_params), q_params=q_params, target_q_params=target_q_params,
                    log_alpha=jnp.asarray(log_alpha), alpha_opt_state=alpha_opt, q_opt_state=q_opt,
                    policy_opt_state=policy_opt)
    ts = jax.tree.map(jnp.asarray, ts)
    batch = Transition(obs=transitions.observation, action=transitions.action, reward=transitions.reward,
                       discount=transitions.discount, next_obs=transitions.next_observation)
    new, stats = jax.jit(sac.learn)(ts, jax.tree.map(jnp.asarray, batch), (key_alpha, key_critic, key_actor))

    np.testing.assert_allclose(stats["alpha_loss"], caught["alpha_loss"][2][0], rtol=1e-6)
    np.testing.assert_allclose(stats["critic_loss"], brax_critic[0], rtol=1e-6)
    np.testing.assert_allclose(stats["actor_loss"], brax_actor[0], rtol=1e-6)
    moved = [not np.array_equal(np.asarray(a), np.asarray(b))
             for a, b in zip(jax.tree.leaves(new.params[1]), jax.tree.leaves(policy_params))]
    assert all(moved) and float(new.log_alpha) != float(log_alpha)
    np.testing.assert_allclose(stats["critic_loss"], brax_metrics["training/critic_loss"], rtol=1e-6)
    for ours, theirs in [(new.log_alpha, caught["alpha_loss"][2][1]), (new.q_params, brax_critic[1]),
                         (new.params[1], brax_actor[1]), (new.params[1], brax_params[1])]:
        for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-8)  # equal on the CPU today
    tau = config.tau
    for a, old, q in zip(jax.tree.leaves(new.target_q_params), jax.tree.leaves(target_q_params),
                         jax.tree.leaves(new.q_params), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(old) * (1 - tau) + np.asarray(q) * tau, rtol=1e-6)


# ---- seeds, the pure `train`, and exact resume -----------------------------------------------
_PROGRAMS = {}  # (id(agent), batched, record, users_codegen): (agent, its jitted steps and judge), for the test file


def run_chunks(sac, ts, chunks, batched=None, record=True, users_codegen=False):
    """`chunks` chunks of `ts` as train_run drives them: the training steps, then the judge (`batched`: over seeds;
    `record`: the judge's first episode; `users_codegen`: compiled as users' programs are, where two programs must
    agree bit for bit). The programs are jitted once per agent, seed axis, `record` and codegen, so a resume's chunks
    run the whole run's compiled programs."""
    cache_key = (id(sac), batched, record, users_codegen)
    options = USERS_CODEGEN if users_codegen else None
    if cache_key not in _PROGRAMS:
        train_steps, judge = sac.train_steps, partial(sac.evaluate_and_keep_best, record=record)
        if batched is not None:
            train_steps, judge = batched(train_steps), batched(judge)
        _PROGRAMS[cache_key] = sac, *(jax.jit(fn, compiler_options=options) for fn in (train_steps, judge))
    _, train_steps, judge = _PROGRAMS[cache_key]
    history = []
    for _ in range(chunks):
        ts, trained, eval_key = train_steps(ts)
        ts, judged = judge(ts, eval_key)
        history.append({**trained, **judged})
    return ts, history


mapped = one_after_another  # train_run's "map" seed axis (the CPU's): one seed after another


@pytest.mark.heavy  # ~20 s: the default run stays under 6 minutes on 2 cores (test_resume keeps SAC exact there)
def test_seed_i_of_a_batched_run_is_a_one_seed_run_of_seed_i():
    """Seeds mapped (train_run's way on the CPU) are one-seed runs bit for bit. Vmapped (its way on
    accelerators) they agree to the last bits only: XLA rewrites a division by a per-seed scalar
    differently in a vmapped program, here in optax's Adam (its bias corrections) and in Brax's
    normalizer update (its count). With agents.ppo's pinned Adam and the normalizer's update left
    out, a vmapped chunk was a one-seed chunk bit for bit (tried by hand, not kept)."""
    env = drift()
    sac = SAC(SMALL, env)
    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    singles = [run_chunks(sac, jax.jit(sac.init)(key), SMALL.num_chunks)[0] for key in keys]
    ts, _ = run_chunks(sac, jax.jit(mapped(sac.init))(keys), SMALL.num_chunks, mapped)
    vmapped, history = run_chunks(sac, jax.jit(jax.vmap(sac.init))(keys), SMALL.num_chunks, jax.vmap)
    for i, single in enumerate(singles):
        assert_trees_equal(jax.tree.map(lambda x: x[i], ts), single)
        for a, b in zip(jax.tree.leaves(jax.tree.map(lambda x: x[i], vmapped)), jax.tree.leaves(single), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-5)
    assert int(singles[0].env_steps) == SMALL.total_steps
    # No NaN in Drift: every step stored, and the buffer wrapped around.
    assert int(singles[0].buffer.size) == SMALL.max_replay_size
    assert int(singles[0].buffer.insert_pos) == SMALL.total_steps % SMALL.max_replay_size
    # Independent keys give different agents.
    first = [np.asarray(jax.tree.leaves(s.params[1])[0]) for s in singles]
    assert not np.allclose(first[0], first[1])
    assert {"critic_loss", "actor_loss", "alpha_loss", "alpha", "episodes", "train_return", "nan_episodes",
            "overflow_contacts", "overflow_constraints", "env_steps", "eval_return", "best_return"} <= set(history[0])
    assert all(np.isfinite(np.asarray(history[-1][k])).all() for k in ("critic_loss", "actor_loss", "eval_return"))


@pytest.mark.slow  # one more compile of the whole run (~5 s)
def test_the_pure_train_is_the_chunked_run():
    env = drift()
    sac = SAC(SMALL, env)
    key = jax.random.PRNGKey(7)
    single, _ = run_chunks(sac, jax.jit(sac.init)(key), SMALL.num_chunks)
    best, metrics = jax.jit(lambda k: train(SMALL, env, k))(key)
    assert_trees_equal((best, metrics["final_params"]), (single.best_params, single.params))
    assert metrics["eval_return"].shape == (SMALL.num_chunks,) and int(metrics["solve_step"]) == -1


@pytest.mark.slow  # compiles the accelerator's program shapes on the CPU (~10 s)
def test_the_accelerator_program_trains_the_same_on_the_cpu():
    """Off the CPU the replay writes with a scatter and reads with a gather (`agents.device_options`):
    the same agent as the CPU's loops, bit for bit."""
    env = drift()
    key = jax.random.PRNGKey(7)
    cpu, gpu = SAC(SMALL, env, platform="cpu"), SAC(SMALL, env, platform="gpu")
    assert gpu.buffer.vectorized and not cpu.buffer.vectorized
    assert_trees_equal(run_chunks(gpu, jax.jit(gpu.init)(key), 2)[0], run_chunks(cpu, jax.jit(cpu.init)(key), 2)[0])


@pytest.mark.slow  # its kill -9 twin is slow too; PPO's resume and the DQN lifecycle tests run by default
def test_a_run_resumed_from_a_host_copy_of_its_state_ends_as_the_uninterrupted_run():
    """The whole state of a seed, the replay buffer included, is the train state: copied to numpy
    (as a checkpoint holds it) after a chunk and back, the run continues bit for bit."""
    sac = SAC(SMALL, drift())
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    init = jax.jit(jax.vmap(sac.init))
    whole, whole_history = run_chunks(sac, init(keys), SMALL.num_chunks, jax.vmap)
    part, _ = run_chunks(sac, init(keys), 1, jax.vmap)
    saved = jax.tree.map(np.asarray, part)
    assert int(saved.buffer.size[0]) > SMALL.prefill_steps  # the buffer travels with it
    resumed, resumed_history = run_chunks(sac, jax.tree.map(jnp.asarray, saved), SMALL.num_chunks - 1, jax.vmap)
    assert_trees_equal(resumed, whole)
    np.testing.assert_array_equal(resumed_history[-1]["eval_return"], whole_history[-1]["eval_return"])


# ---- the policy, and evaluation ---------------------------------------------------------------------
def test_the_policy_is_brax_deterministic_policy_on_brax_parameter_layout():
    """`params` has the layout of Brax's SAC parameters (what `benchmarks.brax_trainers` builds), and
    `policy` acts as Brax's deterministic policy does, in [-1, 1]."""
    from benchmarks import brax_trainers

    env = drift()
    config = dataclasses.replace(SMALL, hidden=(8, 8))
    sac = SAC(config, env)
    ts = jax.jit(sac.init)(jax.random.PRNGKey(0))
    template = brax_trainers.params_template(config, env.observation_size, env.action_size)
    assert jax.tree.structure(template) == jax.tree.structure(ts.params)
    for a, b in zip(jax.tree.leaves(template), jax.tree.leaves(ts.params), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
    obs = 10 * jax.random.normal(jax.random.PRNGKey(1), (32, env.observation_size))
    ours = jax.jit(sac.policy)(ts.params, obs)
    brax = brax_trainers.deterministic_policy(config, env.observation_size, env.action_size)(ts.params, obs, None)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(brax))
    assert ours.shape == (32, env.action_size) and np.all(np.abs(np.asarray(ours)) <= 1.0)


@pytest.mark.slow
def test_evaluate_returns_deterministic_episodes_and_records_the_first():
    env = drift(episode_length=20)
    sac = SAC(SMALL, env)
    ts = jax.jit(sac.init)(jax.random.PRNGKey(0))
    key = jax.random.PRNGKey(5)
    returns, episode = jax.jit(lambda p, k: sac.evaluate(p, k, num_episodes=5, record=True))(ts.params, key)
    assert returns.shape == (5,)
    assert int(episode.length) == 20 and episode.action.shape == (20, 1)
    np.testing.assert_allclose(float(episode.reward.sum()), float(returns[0]), rtol=1e-5)
    again = jax.jit(lambda p, k: sac.evaluate(p, k, num_episodes=5))(ts.params, key)
    np.testing.assert_array_equal(np.asarray(again), np.asarray(returns))
    # The judge keeps the best parameters and the first step that reached solve_return.
    solving = SAC(dataclasses.replace(SMALL, solve_return=-1e9), env)
    judged, metrics = jax.jit(solving.evaluate_and_keep_best)(ts, key)
    assert int(judged.solve_step) == int(ts.env_steps) and metrics["eval_episode"] is None
    assert float(judged.best_return) == float(metrics["eval_return"])
    never, _ = jax.jit(sac.evaluate_and_keep_best)(ts, key)  # solve_return None: never solved
    assert int(never.solve_step) == -1


# ---- learning ---------------------------------------------------------------------------------
