"""SAC (`agents.sac`): its config, transitions, one update against Brax's own training step,
seeds under vmap, exact resume from a host copy of the train state, and (slow) learning."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.sac import SAC, SACConfig, Transition, train, unpack


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
    ts = sac.init(jax.random.PRNGKey(0))
    for i in range(steps):
        ts, _ = sac.collect(ts, jax.random.PRNGKey(i))
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

    from agents import brax_agents

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
    kwargs = brax_agents.trainer_kwargs(config)
    kwargs.update(num_timesteps=config.prefill_steps + config.num_envs, num_evals=2, seed=seed)
    brax_env = envs.to_brax(env)
    _, params, metrics = brax_sac.train(brax_env, episode_length=brax_env.episode_length, **kwargs)
    return caught, params, metrics


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
