"""The suite's envs driven by Brax's own wrappers and trainers (brax.training.agents.ppo).

The reference is Brax itself: its `envs.training.wrap` stack must see exactly the
transitions our env API produces, its PPO trainer must run on our env, and (slow)
its SAC trainer must solve pendulum-mjx, checked both by Brax's evaluator and by
rolling the returned policy out in our own env.
"""

import functools

import jax
import numpy as np
import pytest
from brax.envs.wrappers.training import wrap as brax_wrap
from brax.training.agents.ppo import networks as ppo_networks
from brax.training.agents.ppo import train as ppo

import envs

# Slow run: Brax's wrappers and trainers on our envs (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

EPISODE = 20  # a short episode so that one rollout crosses the time limit
N_ENVS = 8


def run(batch_reset, batch_step, keys, actions):
    """(obs, reward, done, truncation) after each of `actions` (steps x envs x 1), from one reset per key."""

    def body(state, action):
        state = batch_step(state, action)
        return state, (state.obs, state.reward, state.done, state.info["truncation"])

    return jax.jit(lambda k, a: jax.lax.scan(body, batch_reset(k), a)[1])(keys, actions)


@pytest.fixture(scope="module")
def keys_and_actions():
    key_envs, key_actions = jax.random.split(jax.random.PRNGKey(3))
    keys = jax.random.split(key_envs, N_ENVS)
    actions = jax.random.uniform(key_actions, (EPISODE, N_ENVS, 1), minval=-1.0, maxval=1.0)
    return keys, actions


def test_brax_wrappers_see_our_transitions(keys_and_actions):
    """Brax's training stack (vmap, episode limit, auto-reset) over `to_brax(...)` gives the
    same obs, reward, done and truncation as our env from the same keys and actions."""
    keys, actions = keys_and_actions
    brax_env = envs.to_brax("pendulum-mjx", episode_length=EPISODE)
    assert brax_env.episode_length == EPISODE
    ours = envs.make("pendulum-mjx", episode_length=EPISODE)
    theirs = brax_wrap(brax_env, EPISODE)  # Brax's VmapWrapper takes one key per env
    theirs_obs, theirs_reward, theirs_done, theirs_trunc = run(theirs.reset, theirs.step, keys, actions)
    our_obs, our_reward, our_done, our_trunc = run(jax.vmap(ours.reset), jax.vmap(ours.step), keys, actions)

    # Before the time limit: identical transitions.
    np.testing.assert_allclose(theirs_obs[:-1], our_obs[:-1], atol=1e-6)
    np.testing.assert_allclose(theirs_reward, our_reward, atol=1e-5)
    np.testing.assert_array_equal(theirs_done, our_done)
    np.testing.assert_array_equal(theirs_trunc, our_trunc)
    # Both end every episode at step EPISODE, as a truncation (pendulum never terminates).
    assert (np.asarray(our_done)[:-1] == 0).all() and (np.asarray(our_done)[-1] == 1).all()
    assert (np.asarray(our_trunc)[-1] == 1).all()
    # After it, Brax's auto-reset returns each env's first observation (its documented
    # behaviour), where our un-reset env still shows the final one.
    first_obs = jax.vmap(ours.reset)(keys).obs
    np.testing.assert_allclose(theirs_obs[-1], first_obs, atol=1e-6)


def test_without_to_brax_the_time_limit_counts_twice(keys_and_actions):
    """Why `to_brax` exists: our TimeLimit under Brax's EpisodeWrapper ends episodes at half length."""
    keys, actions = keys_and_actions
    doubled = brax_wrap(envs.make("pendulum-mjx", episode_length=EPISODE), EPISODE)
    done = np.asarray(run(doubled.reset, doubled.step, keys, actions)[2])
    assert (done[EPISODE // 2 - 1] == 1).all()


def test_to_brax_refuses_what_brax_cannot_train():
    with pytest.raises(ValueError, match="discrete"):
        envs.to_brax("pendulum-mjx-discrete")
    with pytest.raises(ValueError, match="already wrapped in"):
        envs.to_brax(envs.wrap_for_training(envs.make("pendulum-mjx"), 4))
    with pytest.raises(ValueError, match="episode_length"):
        envs.to_brax(envs.PendulumMjx())
    with pytest.raises(ValueError, match="only apply to a registered name"):
        envs.to_brax(envs.make("pendulum-mjx"), max_speed=4.0)
    with pytest.raises(ValueError, match="unknown env"):
        envs.to_brax("no-such-env")
    # What it accepts: a name with overrides, an env from envs.make, a bare task with a length.
    assert envs.to_brax("cartpole-swingup-mjx").episode_length == 1000
    assert envs.to_brax("pendulum-mjx", max_speed=4.0).unwrapped.params.max_speed == 4.0
    assert envs.to_brax(envs.make("pendulum-mjx")).episode_length == 200
    bare = envs.to_brax(envs.PendulumMjx(), episode_length=50)
    assert (bare.episode_length, bare.observation_size, bare.action_size, bare.backend) == (50, 3, 1, "jax")


def small_networks(hidden=(32, 32)):
    return functools.partial(
        ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=hidden, value_hidden_layer_sizes=hidden
    )


@pytest.mark.slow  # issue #29: out of the default run (make test <= 8 min); a Brax PPO compile (~20 s); PPO through envs.to_brax stays in tests/test_brax_cli.py's tiny run
def test_brax_ppo_trains_on_our_env():
    """A few hundred steps of Brax's PPO through our API: it runs, its metrics are sane, and
    its policy acts in our env."""
    env = envs.to_brax("pendulum-mjx")
    reported = []
    make_policy, params, metrics = ppo.train(
        env,
        episode_length=env.episode_length,
        num_timesteps=480,  # 3 training steps of 8 envs x 2 minibatches x 10-step unrolls
        num_envs=8,
        batch_size=8,
        num_minibatches=2,
        unroll_length=10,
        num_updates_per_batch=1,
        num_evals=1,  # one evaluation, at the end (a second would compile Brax's evaluator again)
        num_eval_envs=8,
        network_factory=small_networks(),
        progress_fn=lambda step, m: reported.append((step, m)),
    )
    assert [step for step, _ in reported] == [480]
    for key in ("eval/episode_reward", "training/policy_loss", "training/v_loss", "training/entropy_loss"):
        assert np.isfinite(float(metrics[key])), (key, metrics[key])
    # A pendulum step costs at most pi^2 + 0.1 * 8^2 + 0.001 * 2^2 = 16.27.
    assert -16.28 * 200 <= float(metrics["eval/episode_reward"]) < 0
    assert float(metrics["eval/avg_episode_length"]) == 200  # Brax saw our 200-step limit
    assert float(metrics["training/sps"]) > 0

    policy = make_policy(params, deterministic=True)
    state = envs.make("pendulum-mjx").reset(jax.random.PRNGKey(0))
    action, _ = policy(state.obs, jax.random.PRNGKey(1))
    assert action.shape == (1,) and -1 <= float(action[0]) <= 1
