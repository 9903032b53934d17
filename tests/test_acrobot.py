"""Acrobot-v1 three ways: the analytic env against Gymnasium's own AcrobotEnv, the MJX
task against the analytic env, and C MuJoCo's mj_step on the same XML against the
equations. References are independent: Gymnasium's numpy code (its `wrap`/`bound`
included) and MuJoCo's own RK4."""

import gymnasium
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from gymnasium.envs.classic_control.acrobot import AcrobotEnv, bound, rk4, wrap

import envs

MAX_VEL = np.array([4 * np.pi, 9 * np.pi])
STATE_HIGH = np.concatenate([[np.pi, np.pi], MAX_VEL])  # every state Gymnasium's step can leave behind
MJX_STEPS = 65  # swing-up trajectories compared step by step (see test_mjx_swing_up_matches_analytic)


def random_states(rng, n):
    return rng.uniform(-STATE_HIGH, STATE_HIGH, size=(n, 4))


def pumping_action(dtheta2):
    """Torque along the elbow's motion: pumps energy in and reaches the goal in ~100 steps,
    so trajectories cover big swings, wrapped angles and fast links, not just the rest state."""
    return np.where(np.asarray(dtheta2) > 0, 2, 0)


def state_error(ours, expected, angles_modulo_2pi=False):
    """Max abs difference per state. Float32 may wrap an angle that lands within rounding
    of +-pi to the other end: compare such angles modulo 2 pi. Float64 compares them raw,
    which checks the wrap itself."""
    ours, expected = np.asarray(ours, np.float64), np.asarray(expected, np.float64)
    diff = ours - expected
    if angles_modulo_2pi:
        diff[..., :2] = (diff[..., :2] + np.pi) % (2 * np.pi) - np.pi
    return np.abs(diff).max(axis=-1)


def from_state(state):
    """An analytic env State holding the given (theta1, theta2, dtheta1, dtheta2)."""
    zero = jnp.zeros((), state.dtype)
    return envs.State(state, jnp.zeros(6, state.dtype), zero, zero, info={"truncation": zero, "nan": zero})


def analytic_step_batch(states, actions):
    def one(state, action):
        out = envs.Acrobot().step(from_state(state), action)
        return out.pipeline_state, out.obs, out.reward, out.done

    return jax.jit(jax.vmap(one))(states, actions)


def gym_step_from(gym_env, state, action):
    gym_env.state = np.array(state, dtype=np.float64)
    obs, reward, terminated, _, _ = gym_env.step(int(action))
    return np.array(gym_env.state), obs, reward, terminated


# ---- the analytic env against Gymnasium ---------------------------------------------------


@pytest.mark.parametrize("x64", [False, True], ids=["float32", "float64"])
def test_step_matches_gymnasium(x64):
    """10,000 transitions from states spread over the whole reachable state space."""
    rng = np.random.default_rng(0)
    states = random_states(rng, 10_000)
    actions = rng.integers(0, 3, len(states))
    gym_env = AcrobotEnv()
    expected = [gym_step_from(gym_env, s, a) for s, a in zip(states, actions)]
    expected_states = np.array([e[0] for e in expected])
    expected_obs = np.array([e[1] for e in expected])
    expected_reward = np.array([e[2] for e in expected])
    expected_terminated = np.array([e[3] for e in expected])
    # The sample exercises Gymnasium's velocity clip, its angle wrap and the goal.
    torques = np.asarray(AcrobotEnv.AVAIL_TORQUE)[actions]
    before_wrap = np.array([rk4(gym_env._dsdt, np.append(s, u), [0, gym_env.dt])
                            for s, u in zip(states[:500], torques[:500])])
    assert (np.abs(before_wrap[:, :2]) > np.pi).any(axis=1).mean() > 0.3
    assert (np.abs(expected_states[:, 2:]) == MAX_VEL).any(axis=1).mean() > 0.1
    assert 0.05 < expected_terminated.mean() < 0.5

    with jax.enable_x64(x64):
        dtype = jnp.float64 if x64 else jnp.float32
        ours, obs, reward, done = analytic_step_batch(jnp.asarray(states, dtype), jnp.asarray(actions, jnp.int32))
        assert obs.dtype == dtype

    error = state_error(ours, expected_states, angles_modulo_2pi=not x64)
    assert (np.abs(np.asarray(ours)[:, :2]) <= (np.pi if x64 else np.float32(np.pi))).all()  # wrapped
    if x64:
        assert error.max() <= 1e-10, error.max()
        np.testing.assert_allclose(np.asarray(obs), expected_obs, atol=1e-6)  # Gymnasium's obs is float32
        np.testing.assert_array_equal(np.asarray(done, bool), expected_terminated)
    else:
        # At 9 pi rad/s one 0.2 s RK4 step amplifies rounding ~1e4-fold (float64 shows it at
        # 1e-11), so a few fast states differ by ~1e-3 in float32; typical ones by ~1e-6.
        assert np.median(error) <= 1e-5 and np.quantile(error, 0.99) <= 1e-3 and error.max() <= 1e-2, error.max()
        # float32 may flip a state that lands within rounding of the goal line
        assert (np.asarray(done, bool) != expected_terminated).mean() < 1e-3
    np.testing.assert_array_equal(np.asarray(reward), np.where(np.asarray(done, bool), 0.0, -1.0))
    if x64:
        np.testing.assert_array_equal(np.asarray(reward), expected_reward)


def test_episodes_match_gymnasium():
    """Whole episodes from Gymnasium's own resets, both fed the same actions, in float64.

    Episodes use the swing-up policy with 10% random actions and reach the goal in
    77-160 steps. The acrobot is chaotic once it swings hard: rounding differences
    (1e-16) stay below 1e-13 for the first 60 steps, then grow up to ~1e-6 by the
    end of the longest episodes, so the whole-episode tolerance is looser.
    """
    gym_env = gymnasium.make("Acrobot-v1")
    rng = np.random.default_rng(1)
    lengths, worst, worst_early = [], 0.0, 0.0
    with jax.enable_x64(True):
        env = envs.make("acrobot")
        step = jax.jit(env.step)
        for episode in range(20):
            gym_obs, _ = gym_env.reset(seed=episode)
            state = env.reset(jax.random.PRNGKey(episode))
            start = jnp.asarray(gym_env.unwrapped.state, jnp.float64)  # Gymnasium draws float32 starts
            state = state.replace(pipeline_state=start)
            for t in range(500):
                action = int(rng.integers(0, 3)) if rng.random() < 0.1 else int(pumping_action(gym_obs[5]))
                gym_obs, gym_reward, terminated, truncated, _ = gym_env.step(action)
                state = step(state, jnp.int32(action))
                error = float(state_error(state.pipeline_state, gym_env.unwrapped.state))
                worst = max(worst, error)
                worst_early = max(worst_early, error) if t < 60 else worst_early
                np.testing.assert_allclose(np.asarray(state.obs), gym_obs, atol=1e-5)
                assert float(state.reward) == gym_reward, (episode, t)
                assert bool(state.done) == (terminated or truncated), (episode, t)
                if terminated or truncated:
                    break
            assert terminated, f"episode {episode} should reach the goal"
            lengths.append(t + 1)
    assert worst_early <= 1e-12, worst_early
    assert worst <= 1e-5, worst
    assert max(lengths) > 150, lengths  # long enough for the swings to get big


def test_truncation_at_500_is_not_termination():
    """No torque: energy is conserved, the tip never reaches the goal, and Gymnasium's
    500-step limit ends the episode as truncation."""
    gym_env = gymnasium.make("Acrobot-v1")
    gym_env.reset(seed=0)
    for t in range(500):
        _, reward, terminated, truncated, _ = gym_env.step(1)
        if terminated or truncated:
            break
    assert (t, reward, terminated, truncated) == (499, -1.0, False, True)

    assert envs.options("acrobot")["episode_length"] == envs.options("acrobot-mjx")["episode_length"] == 500
    env = envs.make("acrobot")

    def run(state, _):
        state = env.step(state, jnp.int32(1))
        return state, (state.reward, state.done, state.info["truncation"])

    _, (reward, done, truncation) = jax.jit(lambda s: jax.lax.scan(run, s, None, 500))(env.reset(jax.random.PRNGKey(0)))
    assert np.flatnonzero(np.asarray(done)).tolist() == [499]
    assert float(truncation[499]) == 1.0 and float(truncation[:499].sum()) == 0.0
    assert float(reward.sum()) == -500.0


def test_reset_distribution_matches_gymnasium():
    gym_env = AcrobotEnv()
    gym_starts = []
    for seed in range(2000):
        gym_env.reset(seed=seed)
        gym_starts.append(gym_env.state)
    gym_starts = np.array(gym_starts)
    keys = jax.random.split(jax.random.PRNGKey(0), 10_000)
    ours = np.asarray(jax.jit(jax.vmap(envs.make("acrobot").reset))(keys).pipeline_state)
    for starts in (gym_starts, ours):
        assert starts.min() >= -0.1 and starts.max() <= 0.1
        assert starts.min() < -0.099 and starts.max() > 0.099
        # Uniform on [-0.1, 0.1]: mean 0, std 0.2 / sqrt(12) per component.
        np.testing.assert_allclose(starts.mean(0), 0.0, atol=0.008)
        np.testing.assert_allclose(starts.std(0), 0.2 / np.sqrt(12), rtol=0.05)
    # The MJX task draws the very same starts for the same keys (shared AcrobotRules).
    mjx_start = jax.jit(jax.vmap(envs.make("acrobot-mjx").reset))(keys[:100]).pipeline_state
    np.testing.assert_array_equal(np.concatenate([mjx_start.qpos, mjx_start.qvel], axis=1), ours[:100])


# ---- the MJX task against the analytic env ------------------------------------------------


def swing_up_actions(starts, steps):
    """Open-loop action sequences: the swing-up policy run on the analytic env in float64
    (the episode is not stopped at the goal), to be replayed on both backends."""
    with jax.enable_x64(True):
        env = envs.Acrobot()

        def one(start):
            def body(state, _):
                action = jnp.where(state.pipeline_state[3] > 0, 2, 0).astype(jnp.int32)
                return env.step(state, action), action

            return jax.lax.scan(body, from_state(start), None, steps)[1]

        return np.asarray(jax.jit(jax.vmap(one))(jnp.asarray(starts, jnp.float64)))


def rollout(env, starts, actions):
    """Observations, rewards, dones and angles (theta1, theta2) after each step from given
    (theta1, theta2, dtheta1, dtheta2); the episodes run on past the goal."""

    def one(start, episode_actions):
        if isinstance(env, envs.MjxEnv):
            state = env.reset(jax.random.PRNGKey(0))
            state = state.replace(pipeline_state=state.pipeline_state.replace(qpos=start[:2], qvel=start[2:]))
        else:
            state = from_state(start)

        def body(state, action):
            state = env.step(state, action)
            angles = state.pipeline_state.qpos if isinstance(env, envs.MjxEnv) else state.pipeline_state[:2]
            return state, (state.obs, state.reward, state.done, angles)

        return jax.lax.scan(body, state, episode_actions)[1]

    return jax.jit(jax.vmap(one))(starts, actions)


@pytest.fixture(scope="module")
def mjx_and_analytic():
    """One jitted, vmapped MJX rollout (one compile) serving both tests below: 256 random
    states across the state space with random actions (their first step is a one-step
    check) and 32 reset-distribution starts under the swing-up policy."""
    rng = np.random.default_rng(2)
    random_starts = random_states(rng, 256)
    reset_starts = rng.uniform(-0.1, 0.1, size=(32, 4))
    starts = jnp.asarray(np.concatenate([random_starts, reset_starts]), jnp.float32)
    actions = np.concatenate([rng.integers(0, 3, (256, MJX_STEPS)), swing_up_actions(reset_starts, MJX_STEPS)])
    actions = jnp.asarray(actions, jnp.int32)
    mjx_out = rollout(envs.AcrobotMjx(), starts, actions)
    analytic_out = rollout(envs.Acrobot(), starts, actions)
    return [np.asarray(x) for x in mjx_out], [np.asarray(x) for x in analytic_out]


@pytest.mark.slow
def test_mjx_step_matches_analytic(mjx_and_analytic):
    """First transition from 256 random states: MuJoCo's RK4, post_step's clip and wrap."""
    (mjx_obs, mjx_reward, mjx_done, _), (obs, _, done, _) = [[x[:256, 0] for x in out] for out in mjx_and_analytic]
    error = np.abs(mjx_obs - obs).max(axis=-1)
    assert np.median(error) <= 1e-5 and error.max() <= 1e-2, error.max()  # float32: see test_step_matches_gymnasium
    assert (np.abs(obs[:, 4:]) == np.float32(MAX_VEL)).any(axis=1).mean() > 0.1  # the clip was exercised
    assert (mjx_done != done).sum() <= 1
    np.testing.assert_array_equal(mjx_reward, np.where(mjx_done > 0, 0.0, -1.0))


def test_mjx_swing_up_matches_analytic(mjx_and_analytic):
    """32 swing-ups from rest, step by step, both in float32.

    65 steps take the links from hanging to swinging over the top (angles wrap, the
    tip rises past the pivot, the first ones reach the goal). The two differ by ~5e-5
    at the end; beyond ~75 steps float32 rounding alone, amplified by the chaos,
    separates any two float32 implementations (the analytic env in float32 and in
    float64 as much as MJX and the analytic env).
    """
    (mjx_obs, mjx_reward, mjx_done, mjx_angles), (obs, reward, done, angles) = [
        [x[256:] for x in out] for out in mjx_and_analytic
    ]
    error = float(np.abs(mjx_obs - obs).max())
    assert error <= 1e-4, error
    # post_step wraps MuJoCo's qpos as Gymnasium wraps its angles.
    assert np.abs(mjx_angles).max() <= np.float32(np.pi) and np.abs(angles).max() > 3.0
    assert state_error(np.concatenate([mjx_angles, mjx_obs[..., 4:]], -1),
                       np.concatenate([angles, obs[..., 4:]], -1), angles_modulo_2pi=True).max() <= 1e-4
    np.testing.assert_array_equal(mjx_reward, reward)
    np.testing.assert_array_equal(mjx_done, done)
    # The trajectories are big swings, not small oscillations near rest: the tip of
    # most rises above the pivot, every first link passes horizontal, a few reach the goal.
    cos1, sin1, cos2, sin2 = np.moveaxis(obs[..., :4], -1, 0)
    tip_height = -cos1 - (cos1 * cos2 - sin1 * sin2)  # -cos(t1) - cos(t1 + t2)
    assert (tip_height.max(axis=1) > 0).mean() > 0.5
    assert (cos1 < 0).any(axis=1).all()
    assert done.any()


# ---- C MuJoCo against the equations ----------------------------------------------------------


def test_c_mujoco_matches_equations():
    """C MuJoCo's mj_step (RK4) on assets/acrobot.xml, float64, with Gymnasium's own wrap and
    bound applied after each step, against the analytic env: every MuJoCo transition along
    20 runs of 300 steps (from rest or from random states, mostly swing-up actions, not
    stopped at the goal) is recomputed by the equations from MuJoCo's state."""
    model = envs.AcrobotMjx().mj_model
    data = mujoco.MjData(model)
    rng = np.random.default_rng(3)
    before, actions, after = [], [], []
    for run in range(20):
        start = rng.uniform(-0.1, 0.1, 4) if run % 2 else random_states(rng, 1)[0]
        data.qpos[:], data.qvel[:] = start[:2], start[2:]
        for _ in range(300):
            state = np.concatenate([data.qpos, data.qvel])
            action = int(rng.integers(0, 3)) if rng.random() < 0.1 else int(pumping_action(data.qvel[1]))
            data.ctrl[:] = action - 1.0  # gear 1: ctrl is the torque
            mujoco.mj_step(model, data)
            data.qpos[:] = [wrap(q, -np.pi, np.pi) for q in data.qpos]
            data.qvel[:] = [bound(v, -m, m) for v, m in zip(data.qvel, MAX_VEL)]
            before.append(state), actions.append(action), after.append(np.concatenate([data.qpos, data.qvel]))
    after = np.array(after)
    assert (np.abs(after[:, 2:]) == MAX_VEL).any(axis=1).any()  # reached the clip
    with jax.enable_x64(True):
        ours = analytic_step_batch(jnp.asarray(np.array(before)), jnp.asarray(actions, jnp.int32))[0]
    error = state_error(ours, after).max()
    assert error <= 1e-10, error


def test_actions_are_gymnasium_torques():
    """Action i puts exactly Gymnasium's AVAIL_TORQUE[i] on the elbow and nothing on the shoulder."""
    env = envs.AcrobotMjx()
    data = mujoco.MjData(env.mj_model)
    for action, torque in enumerate(AcrobotEnv.AVAIL_TORQUE):
        data.ctrl[:] = np.asarray(env.action_to_ctrl(jnp.int32(action)))
        mujoco.mj_forward(env.mj_model, data)
        np.testing.assert_array_equal(data.qfrc_actuator, [0.0, torque])


# ---- DQN reaches Gymnasium's threshold --------------------------------------------------------

# Default DQN hyperparameters, except for the goal and a cheaper evaluation: an unsolved greedy
# policy plays all 500 steps, so 64 episodes every 1,000 steps would cost more than training.
