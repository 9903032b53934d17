"""The analytic CartPole against Gymnasium's own CartPoleEnv."""

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.envs.classic_control.cartpole import CartPoleEnv

import envs

N_TRANSITIONS = 10_000
GYM_INTEGRATOR = {"euler": "euler", "semi_implicit": "semi-implicit euler"}


def random_states(rng, n):
    """States across the whole non-terminal region and beyond (|v| up to 3)."""
    high = np.array([2.4, 3.0, 0.21, 3.0])
    return rng.uniform(-high, high, size=(n, 4))


def gym_cartpole(integrator, make=False):
    """Gymnasium's env with its `kinematics_integrator` attribute set (it is not a constructor argument)."""
    env = gymnasium.make("CartPole-v1") if make else CartPoleEnv()
    env.unwrapped.kinematics_integrator = GYM_INTEGRATOR[integrator]
    return env


def gym_step_from(gym_env, state, action):
    gym_env.state = np.array(state, dtype=np.float64)
    gym_env.steps_beyond_terminated = None
    _, reward, terminated, truncated, _ = gym_env.step(int(action))
    return np.array(gym_env.state), reward, terminated, truncated


def our_step_batch(env, states, actions):
    def one(state, action):
        zero = jnp.zeros((), state.dtype)
        start = envs.State(envs.CartPoleState.from_array(state), state, zero, zero, info={"truncation": zero, "nan": zero})
        out = env.step(start, action)
        return out.obs, out.reward, out.done

    return jax.jit(jax.vmap(one))(states, actions)


@pytest.mark.parametrize("integrator", ["euler", "semi_implicit"])
@pytest.mark.parametrize("x64", [False, True], ids=["float32", "float64"])
def test_step_matches_gymnasium(integrator, x64):
    rng = np.random.default_rng(0)
    states = random_states(rng, N_TRANSITIONS)
    actions = rng.integers(0, 2, N_TRANSITIONS)
    gym_env = gym_cartpole(integrator)
    expected = [gym_step_from(gym_env, s, a) for s, a in zip(states, actions)]
    expected_states = np.array([e[0] for e in expected])
    expected_terminated = np.array([e[2] for e in expected])

    with jax.enable_x64(x64):
        env = envs.CartPole(integrator=integrator)
        dtype = jnp.float64 if x64 else jnp.float32
        obs, reward, done = our_step_batch(env, jnp.asarray(states, dtype), jnp.asarray(actions, jnp.int32))
        assert obs.dtype == dtype

    error = np.abs(np.asarray(obs, np.float64) - expected_states).max()
    assert error <= (1e-12 if x64 else 1e-5), error
    np.testing.assert_array_equal(np.asarray(reward), 1.0)
    if x64:  # float32 may flip a state that lands within rounding of a threshold
        np.testing.assert_array_equal(np.asarray(done, bool), expected_terminated)
    else:
        assert (np.asarray(done, bool) != expected_terminated).mean() < 1e-3


@pytest.mark.parametrize("integrator", ["euler", "semi_implicit"])
def test_episodes_terminate_on_the_same_step(integrator):
    """Whole episodes from Gymnasium's own resets under random actions."""
    gym_env = gym_cartpole(integrator, make=True)
    rng = np.random.default_rng(1)
    with jax.enable_x64(True):
        env = envs.make("cartpole", integrator=integrator)
        step = jax.jit(env.step)
        for episode in range(30):
            gym_obs, _ = gym_env.reset(seed=episode)
            state = env.reset(jax.random.PRNGKey(episode))
            start = jnp.asarray(gym_env.unwrapped.state, jnp.float64)
            state = state.replace(pipeline_state=envs.CartPoleState.from_array(start), obs=start)
            for t in range(500):
                action = int(rng.integers(0, 2))
                gym_obs, gym_reward, terminated, truncated, _ = gym_env.step(action)
                state = step(state, jnp.int32(action))
                np.testing.assert_allclose(np.asarray(state.obs), gym_env.unwrapped.state, atol=1e-12)
                assert float(state.reward) == gym_reward
                assert bool(state.done) == (terminated or truncated), (episode, t)
                if terminated or truncated:
                    break


def balancing_action(obs):
    """A hand-made controller that keeps the pole up for 500+ steps."""
    x, x_dot, theta, theta_dot = obs
    return (theta + 0.5 * theta_dot + 0.01 * x + 0.1 * x_dot > 0).astype(jnp.int32)


@pytest.mark.parametrize("name", ["cartpole", "cartpole-mjx"])
def test_truncation_at_500_is_not_termination(name):
    gym_env = gymnasium.make("CartPole-v1")
    gym_obs, _ = gym_env.reset(seed=0)
    for t in range(500):
        gym_obs, _, terminated, truncated, _ = gym_env.step(int(balancing_action(gym_obs)))
        if terminated or truncated:
            break
    assert (t, terminated, truncated) == (499, False, True), "controller should balance in Gymnasium"

    env = envs.make(name)

    def run(state, _):
        state = env.step(state, balancing_action(state.obs))
        return state, (state.done, state.info["truncation"])

    _, (done, truncation) = jax.jit(lambda s: jax.lax.scan(run, s, None, 500))(env.reset(jax.random.PRNGKey(0)))
    assert np.flatnonzero(np.asarray(done)).tolist() == [499]
    assert float(truncation[499]) == 1.0
    assert float(truncation[:499].sum()) == 0.0


def test_reset_distribution_matches_gymnasium_bounds():
    gym_env = CartPoleEnv()
    gym_starts = np.array([gym_env.reset(seed=i)[0] for i in range(2000)])
    env = envs.make("cartpole")
    ours = np.asarray(jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 10_000)).obs)
    for starts in (gym_starts, ours):
        assert starts.min() >= -0.05 and starts.max() <= 0.05
        assert starts.min() < -0.049 and starts.max() > 0.049
        # Uniform on [-0.05, 0.05]: mean 0, std 0.1 / sqrt(12) per component.
        np.testing.assert_allclose(starts.mean(0), 0.0, atol=0.004)
        np.testing.assert_allclose(starts.std(0), 0.1 / np.sqrt(12), rtol=0.05)
