"""The MJX Pendulum against Gymnasium's own Pendulum-v1 and C MuJoCo against the equations."""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from gymnasium.envs.classic_control.pendulum import PendulumEnv

import envs
from envs.tasks.pendulum_mjx import DISCRETE_TORQUE_BINS

# Slow run: the MJX pendulum's proofs against Gymnasium (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

EPISODE = 200
G, M, L, DT, MAX_SPEED, MAX_TORQUE = 10.0, 1.0, 1.0, 0.05, 8.0, 2.0


def set_state(env, state, theta, theta_dot):
    """`state` moved to (theta, theta_dot); works on a bare or a wrapped env."""
    dtype = state.pipeline_state.qpos.dtype  # float64 under jax.enable_x64
    data = state.pipeline_state.replace(qpos=jnp.reshape(theta, (1,)).astype(dtype),
                                        qvel=jnp.reshape(theta_dot, (1,)).astype(dtype))
    return state.replace(pipeline_state=data, obs=env.unwrapped.observation(data))


def mjx_one_step(env, theta, theta_dot, action):
    """Next (obs, reward, qpos, qvel, ctrl) from a batch of states and actions, one jitted vmap."""

    def one(theta, theta_dot, action):
        state = set_state(env, env.reset(jax.random.PRNGKey(0)), theta, theta_dot)
        state = env.step(state, action)
        data = state.pipeline_state
        return state.obs, state.reward, data.qpos[0], data.qvel[0], data.ctrl[0]

    return jax.tree.map(np.asarray, jax.jit(jax.vmap(one))(theta, theta_dot, action))


def gymnasium_one_step(thetas, theta_dots, torques):
    """Gymnasium's step (float64 state) from each (theta, theta_dot) with each torque."""
    reference = PendulumEnv()
    reference.reset(seed=0)
    obs, rewards, next_states = [], [], []
    for theta, theta_dot, torque in zip(thetas, theta_dots, torques):
        reference.state = np.array([theta, theta_dot], np.float64)
        o, r, terminated, truncated, _ = reference.step(np.array([torque], np.float64))
        assert not terminated and not truncated
        obs.append(o), rewards.append(r), next_states.append(reference.state.copy())
    return np.array(obs), np.array(rewards), np.array(next_states)


@pytest.fixture(scope="module")
def random_transitions():
    """Angles over several turns (reward wraps them), speeds up to the clip, actions past +-1."""
    rng = np.random.default_rng(0)
    n = 2000
    theta = rng.uniform(-3 * np.pi, 3 * np.pi, n).astype(np.float32)
    theta_dot = rng.uniform(-MAX_SPEED, MAX_SPEED, n).astype(np.float32)
    action = rng.uniform(-1.5, 1.5, (n, 1)).astype(np.float32)
    # Gymnasium takes torques in N m; 2 * action is exact in float32, and both sides clip to +-2.
    reference = gymnasium_one_step(theta, theta_dot, 2.0 * action[:, 0].astype(np.float64))
    return theta, theta_dot, action, reference


def test_one_step_matches_gymnasium(random_transitions):
    theta, theta_dot, action, (ref_obs, ref_reward, ref_next) = random_transitions
    clipped = np.abs(ref_next[:, 1]) == MAX_SPEED
    assert clipped.sum() > 40, "the sample must exercise the speed clip"  # 54 of 2000
    env = envs.PendulumMjx()
    obs, reward, qpos, qvel, _ = mjx_one_step(env, theta, theta_dot, action)
    np.testing.assert_allclose(obs, ref_obs, atol=2e-5)
    np.testing.assert_allclose(reward, ref_reward, atol=1e-4, rtol=1e-5)
    np.testing.assert_allclose(qvel, ref_next[:, 1], atol=2e-5)
    np.testing.assert_allclose(qpos, ref_next[:, 0], atol=2e-5)


class UnclippedPendulum(envs.PendulumMjx):
    """What mjx.step alone does: no speed clip."""

    def post_step(self, prev, data):
        return data


class ClipAfterAnglePendulum(envs.PendulumMjx):
    """The clip in the wrong place: clip the speed but keep the angle mjx.step advanced."""

    def post_step(self, prev, data):
        return data.replace(qvel=jnp.clip(data.qvel, -MAX_SPEED, MAX_SPEED))


@pytest.mark.parametrize("wrong", [UnclippedPendulum, ClipAfterAnglePendulum])
def test_the_check_can_fail_without_gymnasiums_clip(random_transitions, wrong):
    theta, theta_dot, action, (ref_obs, _, ref_next) = random_transitions
    clipped = np.abs(ref_next[:, 1]) == MAX_SPEED
    obs, _, qpos, _, _ = mjx_one_step(wrong(), theta, theta_dot, action)
    assert np.abs(qpos - ref_next[:, 0])[clipped].max() > 1e-3
    assert np.abs(qpos - ref_next[:, 0])[~clipped].max() < 2e-5  # only the clipped steps differ


def gymnasium_episodes(n, policy_kind):
    """`n` Gymnasium episodes from float32-exact random starts: starts, actions in [-1, 1], obs, rewards.

    "random" draws actions uniformly; "pump" pushes along the motion at full torque,
    which drives the pendulum into the speed clip and keeps it there.
    """
    rng = np.random.default_rng({"random": 1, "pump": 2}[policy_kind])
    reference = PendulumEnv()
    starts, actions, observations, rewards = [], [], [], []
    for episode in range(n):
        reference.reset(seed=episode)
        reference.state = reference.state.astype(np.float32).astype(np.float64)
        starts.append(reference.state.copy())
        ep_actions, ep_obs, ep_rewards = [], [], []
        for _ in range(EPISODE):
            if policy_kind == "random":
                a = np.float32(rng.uniform(-1, 1))
            else:
                a = np.float32(1.0 if reference.state[1] >= 0 else -1.0)
            obs, reward, *_ = reference.step(np.array([2.0 * a], np.float64))
            ep_actions.append(a), ep_obs.append(obs), ep_rewards.append(reward)
        actions.append(ep_actions), observations.append(ep_obs), rewards.append(ep_rewards)
    return (np.array(starts, np.float32), np.array(actions, np.float32)[..., None],
            np.array(observations), np.array(rewards))


@pytest.mark.parametrize("policy_kind", ["random", "pump"])
@pytest.mark.parametrize("x64", [False, True], ids=["float32", "float64"])
def test_whole_episodes_match_gymnasium(policy_kind, x64):
    """Same starts, same actions, 200 steps. In float64 MJX follows Gymnasium to its float32
    observations' rounding for the whole episode. In float32 the rounding grows wherever the
    pendulum lingers near upright (unstable, e^(sqrt(15) t)): ~1e-3 after 100 random-action steps."""
    starts, actions, ref_obs, ref_rewards = gymnasium_episodes(16, policy_kind)
    with jax.enable_x64(x64):
        env = envs.make("pendulum-mjx")  # inside the context: float64 model under x64

        def episode(start, episode_actions):
            state = set_state(env, env.reset(jax.random.PRNGKey(0)), start[0], start[1])

            def body(state, action):
                state = env.step(state, action)
                return state, (state.obs, state.reward, state.done, state.info["truncation"])

            return jax.lax.scan(body, state, episode_actions)[1]

        actions = actions.astype(np.float64 if x64 else np.float32)
        obs, rewards, done, truncation = jax.tree.map(np.asarray, jax.jit(jax.vmap(episode))(starts, actions))
    if policy_kind == "pump":
        assert (np.abs(ref_obs[..., 2]) == MAX_SPEED).mean() > 0.3, "pumping must reach the clip"
    if x64:
        np.testing.assert_allclose(obs, ref_obs, atol=1e-6)
        np.testing.assert_allclose(rewards, ref_rewards, rtol=1e-9, atol=1e-9)
    else:
        np.testing.assert_allclose(obs[:, :100], ref_obs[:, :100], atol=2e-3)
        np.testing.assert_allclose(rewards.sum(1), ref_rewards.sum(1), rtol=1e-3)
    # Never terminates; the registry's time limit ends it at 200, as truncation.
    assert (done[:, :-1] == 0).all() and (done[:, -1] == 1).all() and (truncation[:, -1] == 1).all()


def test_c_mujoco_matches_the_equations():
    """C MuJoCo's mj_step in float64 on the same XML: theta_ddot = 3g/(2l) sin(theta) + 3u/(m l^2),
    then semi-implicit Euler (speed first, angle with the new speed)."""
    model = envs.PendulumMjx().mj_model
    assert model.opt.timestep == DT and model.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    data = mujoco.MjData(model)
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(2000):
        theta, theta_dot, torque = rng.uniform(-np.pi, np.pi), rng.uniform(-MAX_SPEED, MAX_SPEED), rng.uniform(-2, 2)
        data.qpos[:], data.qvel[:], data.ctrl[:] = theta, theta_dot, torque
        mujoco.mj_step(model, data)
        new_theta_dot = theta_dot + (3 * G / (2 * L) * np.sin(theta) + 3.0 / (M * L**2) * torque) * DT
        new_theta = theta + new_theta_dot * DT
        worst = max(worst, abs(data.qvel[0] - new_theta_dot), abs(data.qpos[0] - new_theta))
    assert worst <= 1e-12, worst


def test_c_mujoco_with_the_clip_follows_gymnasium_for_whole_episodes():
    """C MuJoCo, float64, with the task's clip redone on the host, against Gymnasium: 200-step episodes."""
    model = envs.PendulumMjx().mj_model
    data = mujoco.MjData(model)
    starts, actions, ref_obs, ref_rewards = gymnasium_episodes(8, "pump")
    worst = 0.0
    for start, episode_actions, episode_obs in zip(starts, actions, ref_obs):
        data.qpos[:], data.qvel[:] = start
        for action, expected in zip(episode_actions, episode_obs):
            theta = data.qpos[0]
            data.ctrl[:] = 2.0 * action
            mujoco.mj_step(model, data)
            data.qvel[:] = np.clip(data.qvel, -MAX_SPEED, MAX_SPEED)
            data.qpos[:] = theta + data.qvel * DT
            obs = np.array([np.cos(data.qpos[0]), np.sin(data.qpos[0]), data.qvel[0]], np.float32)
            worst = max(worst, float(np.abs(obs - expected).max()))
    assert worst <= 1e-6, worst  # Gymnasium's obs are float32


def test_action_mapping_continuous():
    env = envs.PendulumMjx()
    action = np.array([-3.0, -1.0, -0.5, 0.0, 0.25, 1.0, 1.5], np.float32)[:, None]
    zeros = np.zeros(len(action), np.float32)
    _, _, _, _, ctrl = mjx_one_step(env, zeros, zeros, action)
    np.testing.assert_array_equal(ctrl, [-2.0, -2.0, -1.0, 0.0, 0.5, 2.0, 2.0])


def test_action_bins_are_exact_torques_within_ctrlrange():
    env = envs.make("pendulum-mjx-discrete")
    bins = np.linspace(-MAX_TORQUE, MAX_TORQUE, DISCRETE_TORQUE_BINS)
    assert env.num_actions == DISCRETE_TORQUE_BINS and env.action_size is None
    assert DISCRETE_TORQUE_BINS % 2 == 1 and 0.0 in bins  # "do nothing" is a choice
    low, high = env.unwrapped.mj_model.actuator_ctrlrange[0]
    assert (low, high) == (-MAX_TORQUE, MAX_TORQUE)
    rng = np.random.default_rng(4)
    n = 4 * DISCRETE_TORQUE_BINS
    theta = rng.uniform(-np.pi, np.pi, n).astype(np.float32)
    theta_dot = rng.uniform(-MAX_SPEED, MAX_SPEED, n).astype(np.float32)
    index = np.arange(n, dtype=np.int32) % DISCRETE_TORQUE_BINS
    obs, reward, _, _, ctrl = mjx_one_step(env, theta, theta_dot, index)
    np.testing.assert_array_equal(ctrl, bins[index].astype(np.float32))
    assert (ctrl >= low).all() and (ctrl <= high).all()
    ref_obs, ref_reward, _ = gymnasium_one_step(theta, theta_dot, bins[index])
    np.testing.assert_allclose(obs, ref_obs, atol=2e-5)
    np.testing.assert_allclose(reward, ref_reward, atol=1e-4, rtol=1e-5)
    # The bin count is an option; other counts stay evenly spaced over the full range.
    five = envs.make("pendulum-mjx-discrete", action_bins=5).unwrapped
    np.testing.assert_array_equal([ctrl for (ctrl,) in five.action_bins.values()], [-2, -1, 0, 1, 2])


def test_reset_distribution_and_first_observation():
    env = envs.make("pendulum-mjx")
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(5), 20_000))
    theta = np.asarray(states.pipeline_state.qpos[:, 0])
    theta_dot = np.asarray(states.pipeline_state.qvel[:, 0])
    assert theta.min() >= -np.pi and theta.max() <= np.pi
    assert theta.min() < -np.pi + 0.01 and theta.max() > np.pi - 0.01  # the whole circle is used
    assert theta_dot.min() >= -1 and theta_dot.max() <= 1
    assert theta_dot.min() < -0.99 and theta_dot.max() > 0.99
    # Uniform: each quarter of either range holds about a quarter of the starts (5 sigma ~ 0.015).
    for values, bound in ((theta, np.pi), (theta_dot, 1.0)):
        counts = np.histogram(values, bins=4, range=(-bound, bound))[0] / len(values)
        np.testing.assert_allclose(counts, 0.25, atol=0.015)
    obs = np.asarray(states.obs)
    np.testing.assert_allclose(obs, np.stack([np.cos(theta), np.sin(theta), theta_dot], 1), atol=1e-6)
    assert (np.asarray(states.done) == 0).all() and (np.asarray(states.reward) == 0).all()


def test_overrides_reach_the_task():
    env = envs.make("pendulum-mjx", max_speed=4.0, reset_angle=0.1, reset_speed=0.0)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(6), 1000))
    assert np.abs(np.asarray(states.pipeline_state.qpos)).max() <= 0.1
    assert (np.asarray(states.pipeline_state.qvel) == 0).all()
    zero = np.zeros(1, np.float32)
    _, _, _, qvel, _ = mjx_one_step(env.unwrapped, zero + 1.5, zero + 3.9, np.ones((1, 1), np.float32))
    assert float(qvel[0]) == 4.0
    with pytest.raises(ValueError, match=r"unknown option.*'max_sped'.*max_speed"):
        envs.make("pendulum-mjx", max_sped=1.0)


@pytest.mark.parametrize("name", [pytest.param("pendulum-mjx", marks=pytest.mark.slow), "pendulum-mjx-discrete"])
def test_jit_vmap_scan_64_envs_450_steps_with_auto_reset(name):
    num_envs, steps = 64, 450
    env = envs.wrap_for_training(envs.make(name), num_envs)
    discrete = env.num_actions is not None

    def body(carry, _):
        state, key = carry
        key, action_key = jax.random.split(key)
        if discrete:
            action = jax.random.randint(action_key, (num_envs,), 0, env.num_actions)
        else:
            action = jax.random.uniform(action_key, (num_envs, 1), minval=-1, maxval=1)
        state = env.step(state, action)
        return (state, key), (state.done, state.info["truncation"], state.info["final_obs"])

    state = env.reset(jax.random.PRNGKey(0))
    _, (done, truncation, final_obs) = jax.jit(lambda s: jax.lax.scan(body, (s, jax.random.PRNGKey(1)), None, steps))(state)
    done, truncation, final_obs = np.asarray(done), np.asarray(truncation), np.asarray(final_obs)
    ends = np.flatnonzero(done.any(axis=1)) + 1
    assert ends.tolist() == [200, 400] and (done[ends - 1] == 1).all() and (truncation[ends - 1] == 1).all()
    assert done.sum() == 2 * num_envs
    assert np.isfinite(final_obs).all() and np.abs(final_obs[..., 2]).max() <= MAX_SPEED
    np.testing.assert_allclose(final_obs[..., 0] ** 2 + final_obs[..., 1] ** 2, 1.0, atol=1e-5)
    assert math.isclose(env.unwrapped.dt, DT)


