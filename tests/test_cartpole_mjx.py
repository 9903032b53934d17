"""The MJX CartPole against the analytic equations and against C MuJoCo."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.tasks.cartpole import CartPolePhysics, integrate

STEPS = 100


def random_starts(key, n):
    high = jnp.array([1.0, 1.0, 0.2, 1.0])
    return jax.random.uniform(key, (n, 4), minval=-high, maxval=high)


def rollout(env, starts, actions):
    """States after each step from given (x, x_dot, theta, theta_dot) starts, ignoring termination."""

    def one(start, episode_actions):
        state = env.reset(jax.random.PRNGKey(0))
        if isinstance(env, envs.MjxEnv):
            data = state.pipeline_state.replace(qpos=start[jnp.array([0, 2])], qvel=start[jnp.array([1, 3])])
            state = state.replace(pipeline_state=data, obs=start)
        else:
            state = state.replace(pipeline_state=envs.CartPoleState.from_array(start), obs=start)

        def body(state, action):
            state = env.step(state, action)
            return state, state.obs

        return jax.lax.scan(body, state, episode_actions)[1]

    return jax.jit(jax.vmap(one))(starts, actions)


@pytest.fixture(scope="module")
def starts_and_actions():
    key_s, key_a = jax.random.split(jax.random.PRNGKey(42))
    starts = random_starts(key_s, 64)
    actions = jax.random.randint(key_a, (64, STEPS), 0, 2)
    return starts, actions


def test_mjx_matches_analytic_semi_implicit(starts_and_actions):
    mjx_states = rollout(envs.CartPoleMjx(), *starts_and_actions)
    analytic = rollout(envs.CartPole(integrator="semi_implicit"), *starts_and_actions)
    error = float(jnp.abs(mjx_states - analytic).max())
    assert error <= 1e-4, error


def test_mjx_differs_from_explicit_euler(starts_and_actions):
    """The check above can fail: Gymnasium's default explicit Euler is a different scheme."""
    mjx_states = rollout(envs.CartPoleMjx(), *starts_and_actions)
    explicit = rollout(envs.CartPole(integrator="euler"), *starts_and_actions)
    assert float(jnp.abs(mjx_states - explicit).max()) > 1e-2


def test_c_mujoco_matches_analytic_semi_implicit():
    """C MuJoCo's mj_step on the same XML, float64, against the equations in numpy-float64."""
    model = envs.CartPoleMjx().mj_model
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    physics = CartPolePhysics()
    worst = 0.0
    with jax.enable_x64(True):
        step = jax.jit(lambda s, f: integrate(physics, s, f, "semi_implicit"))
        for _ in range(20):
            state = rng.uniform(-0.2, 0.2, 4)
            data.qpos[:] = state[[0, 2]]
            data.qvel[:] = state[[1, 3]]
            analytic = envs.CartPoleState.from_array(jnp.asarray(state))
            for _ in range(STEPS):
                action = rng.integers(0, 2)
                data.ctrl[:] = 1.0 if action == 1 else -1.0
                mujoco.mj_step(model, data)
                analytic = step(analytic, 10.0 if action == 1 else -10.0)
                mujoco_state = np.array([data.qpos[0], data.qvel[0], data.qpos[1], data.qvel[1]])
                worst = max(worst, float(np.abs(mujoco_state - np.asarray(analytic.as_array())).max()))
    assert worst <= 1e-10, worst


def test_same_reset_as_analytic():
    keys = jax.random.split(jax.random.PRNGKey(3), 100)
    analytic = jax.vmap(envs.make("cartpole").reset)(keys).obs
    mjx_obs = jax.vmap(envs.make("cartpole-mjx").reset)(keys).obs
    np.testing.assert_array_equal(np.asarray(analytic), np.asarray(mjx_obs))


class NaNCartPole(envs.CartPoleMjx):
    """Feeds a NaN force on the third step."""

    def __init__(self):
        super().__init__()
        self.num_actions = 3  # action 2 is the NaN force

    def action_to_ctrl(self, action):
        return jnp.where(action == 2, jnp.nan, super().action_to_ctrl(action))


def test_nan_physics_ends_the_episode_with_a_flag():
    env = envs.wrap_for_training(NaNCartPole(), num_envs=2)
    state = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    state = step(state, jnp.array([1, 1]))
    before = state.obs
    state = step(state, jnp.array([2, 1]))
    assert state.info["nan"].tolist() == [1.0, 0.0]
    assert state.done.tolist() == [1.0, 0.0]
    assert float(state.reward[0]) == 0.0
    assert bool(jnp.isfinite(state.info["final_obs"]).all()) and bool(jnp.isfinite(state.obs).all())
    np.testing.assert_array_equal(np.asarray(state.info["final_obs"][0]), np.asarray(before[0]))
    assert float(state.info["last_length"][0]) == 2  # counted as a finished episode


class NaNRewardCartPole(envs.CartPoleMjx):
    """Finite physics, but a reward that turns NaN once the cart moves right faster than 0.5 m/s
    (a user's reward bug): such a step ends its episode as NaN physics does."""

    def reward(self, data, action, prev):
        return jnp.where(data.qvel[0] > 0.5, jnp.nan, 1.0)


def test_a_nan_reward_ends_the_episode_with_a_flag_and_never_reaches_a_learner():
    env = envs.wrap_for_training(NaNRewardCartPole(), num_envs=2)
    step = jax.jit(env.step)
    state = env.reset(jax.random.PRNGKey(0))
    flags, dones, rewards = [], [], []
    for _ in range(8):  # the first env pushed right (it speeds up past 0.5 m/s), the second left
        state = step(state, jnp.array([1, 0]))
        flags.append(state.info["nan"].tolist()), dones.append(state.done.tolist()), rewards.append(state.reward)
    flags, dones, rewards = np.array(flags), np.array(dones), np.array(rewards)
    assert flags[:, 0].any() and not flags[:, 1].any()
    assert (dones[flags > 0] == 1).all() and (rewards[flags > 0] == 0).all() and np.isfinite(rewards).all()


def test_missing_mjcf_names_the_file():
    with pytest.raises(FileNotFoundError, match="no_such_model.xml"):
        envs.CartPoleMjx(xml="no_such_model.xml")


def test_malformed_mjcf_names_the_file_and_mujocos_reason(tmp_path):
    broken = tmp_path / "broken.xml"
    broken.write_text("<mujoco><worldbody><body><geom type='box'/></body></worldbody></mujoco>")
    with pytest.raises(ValueError, match=r"broken\.xml.*size 0 must be positive"):
        envs.CartPoleMjx(xml=broken)
    unparsable = tmp_path / "unparsable.xml"
    unparsable.write_text("<mujoco><worldbody>")
    with pytest.raises(ValueError, match=r"unparsable\.xml.*XML"):
        envs.CartPoleMjx(xml=unparsable)
