"""cartpole-swingup-mjx: dm_control's cart-pole swing-up on MJX.

One jitted rollout (16 envs x 1000 steps, compiled once for the module) feeds
most checks, from starts taken from one jitted batch of resets (also the reset
distribution's sample); C MuJoCo's `mj_step` on the same XML in float64 is the reference
for the physics, and rewards are checked against values worked out by hand
from dm_control's definition.
"""

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.assets import asset_path
from envs.tasks.cartpole_swingup_mjx import gaussian_tolerance, quadratic_tolerance

# Slow run: the RK4 cart-pole's proofs (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

N_ENVS, N_STEPS = 16, 1000
UPRIGHT_ROW = N_ENVS - 1  # the row that starts exactly upright, centred and still


def rollout(env, state, qpos, qvel, actions):
    """Every step's obs, reward, done, truncation, qpos and qvel of one env from (qpos, qvel),
    set into a reset `state` (a reset made outside: not one more reset compiled into the rollout)."""
    data = state.pipeline_state.replace(qpos=qpos, qvel=qvel)
    state = state.replace(pipeline_state=data, obs=env.unwrapped.observation(data))

    def body(state, action):
        state = env.step(state, action)
        data = state.pipeline_state
        return state, (state.obs, state.reward, state.done, state.info["truncation"], data.qpos, data.qvel)

    return jax.lax.scan(body, state, actions)[1]


@pytest.fixture(scope="module")
def env():
    return envs.make("cartpole-swingup-mjx")


@pytest.fixture(scope="module")
def resets(env):
    """4000 reset states, one jitted program: the reset distribution's sample, and the
    rollout's starts (its first N_ENVS)."""
    return jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 4000))


@pytest.fixture(scope="module")
def starts(resets):
    return jax.tree.map(lambda x: x[:N_ENVS], resets)


@pytest.fixture(scope="module")
def starts_and_actions(starts):
    """Reset states, then actions: random in [-1, 1] (rows 0-7), a bang-bang push at
    about the pole's natural period that swings it right round (rows 8-14), and
    zero force from the exact upright, centred, still state (last row)."""
    _, key_actions, key_phase = jax.random.split(jax.random.PRNGKey(7), 3)  # the actions as drawn before
    qpos = np.array(starts.pipeline_state.qpos)
    qvel = np.array(starts.pipeline_state.qvel)
    actions = np.array(jax.random.uniform(key_actions, (N_ENVS, N_STEPS, 1), minval=-1.0, maxval=1.0))
    t = np.arange(N_STEPS) * 0.01
    phases = np.array(jax.random.uniform(key_phase, (7,), maxval=2 * math.pi))
    actions[8:15, :, 0] = np.sign(np.sin(2 * math.pi * t / 1.7 + phases[:, None]))
    qpos[UPRIGHT_ROW], qvel[UPRIGHT_ROW], actions[UPRIGHT_ROW] = 0.0, 0.0, 0.0
    return qpos, qvel, actions


@pytest.fixture(scope="module")
def trajectories(env, starts, starts_and_actions):
    run = jax.jit(jax.vmap(lambda s, q, v, a: rollout(env, s, q, v, a)))
    names = ("obs", "reward", "done", "truncation", "qpos", "qvel")
    return dict(zip(names, map(np.asarray, run(starts, *map(jnp.asarray, starts_and_actions)))))


def test_registered_as_continuous_1000_step_task(env):
    assert env.episode_length == 1000
    assert (env.observation_size, env.action_size, env.num_actions) == (5, 1, None)
    assert env.unwrapped.dt == pytest.approx(0.01)


def test_starts_hanging_down(resets):
    starts = resets  # 4000 of them
    qpos, qvel = np.asarray(starts.pipeline_state.qpos), np.asarray(starts.pipeline_state.qvel)
    # dm_control: slider ~ 0.01 N(0,1), hinge ~ pi + 0.01 N(0,1), velocities ~ 0.01 N(0,1).
    offsets = np.concatenate([qpos - [0.0, math.pi], qvel], axis=1)
    np.testing.assert_allclose(offsets.mean(axis=0), 0.0, atol=1.5e-3)
    np.testing.assert_allclose(offsets.std(axis=0), 0.01, rtol=0.1)
    obs = np.asarray(starts.obs)
    assert (obs[:, 1] < -0.998).all()  # cos(angle): pointing down
    np.testing.assert_allclose(obs, np.stack([qpos[:, 0], np.cos(qpos[:, 1]), np.sin(qpos[:, 1]), *qvel.T], 1), atol=1e-6)
    assert float(starts.reward.max()) == 0.0 and float(starts.done.max()) == 0.0


def test_tolerance_shapes():
    """dm_control's `rewards.tolerance` at the points its docstring defines."""
    assert float(gaussian_tolerance(0.0, 2.0)) == 1.0
    assert float(gaussian_tolerance(2.0, 2.0)) == pytest.approx(0.1)
    assert float(gaussian_tolerance(-2.0, 2.0)) == pytest.approx(0.1)
    assert float(gaussian_tolerance(4.0, 2.0)) == pytest.approx(0.1**4)  # a Gaussian: exp(-k d^2)
    assert float(quadratic_tolerance(0.0, 1.0)) == 1.0
    assert float(quadratic_tolerance(0.5, 1.0)) == pytest.approx(0.75)
    assert float(quadratic_tolerance(-1.0, 1.0)) == 0.0
    assert float(quadratic_tolerance(3.0, 1.0)) == 0.0


@pytest.mark.parametrize(
    "x, theta, theta_dot, force, expected",
    [
        (0.0, 0.0, 0.0, 0.0, 1.0),  # upright, centred, still, no force
        (0.0, math.pi, 0.0, 0.0, 0.0),  # hanging down: upright = 0
        (2.0, math.pi / 2, 5.0, 1.0, 0.5 * 0.55 * 0.8 * 0.55),  # every term at its margin
        (0.0, math.pi / 3, 0.0, 0.5, 0.75 * 1.0 * 0.95 * 1.0),  # cos = 1/2; (4 + 0.75) / 5
        (-2.0, 0.0, -5.0, -1.0, 1.0 * 0.55 * 0.8 * 0.55),  # the terms are symmetric
    ],
)
def test_reward_by_hand(env, x, theta, theta_dot, force, expected):
    """upright * centered * small_control * small_velocity, as dm_control defines them."""
    task = env.unwrapped
    data = task._initial_data.replace(
        qpos=jnp.array([x, theta]), qvel=jnp.array([0.3, theta_dot]), ctrl=jnp.array([force])
    )
    # The cart's speed (0.3) does not enter dm_control's reward; only the pole's does.
    assert float(task.reward(data, jnp.array([force]), data)) == pytest.approx(expected, rel=1e-5)


def test_reward_is_one_when_upright_centred_and_still(trajectories):
    """From the exact upright equilibrium with no force nothing moves: reward 1 every step."""
    np.testing.assert_allclose(trajectories["reward"][UPRIGHT_ROW], 1.0, atol=1e-6)
    np.testing.assert_allclose(trajectories["obs"][UPRIGHT_ROW], np.tile([0, 1, 0, 0, 0], (N_STEPS, 1)), atol=1e-6)


def test_jit_vmap_full_episode(trajectories):
    obs, reward = trajectories["obs"], trajectories["reward"]
    assert obs.shape == (N_ENVS, N_STEPS, 5) and reward.shape == (N_ENVS, N_STEPS)
    assert np.isfinite(obs).all()
    assert (reward >= 0).all() and (reward <= 1).all()
    # Never terminates; the time limit truncates at step 1000 and reports it as truncation.
    assert (trajectories["done"][:, :-1] == 0).all() and (trajectories["done"][:, -1] == 1).all()
    assert (trajectories["truncation"][:, -1] == 1).all()
    # The bang-bang rows really swing the pole up (cos > 0.9 at some point) and round.
    assert (obs[8:15, :, 1].max(axis=1) > 0.9).all()


def c_mujoco_errors(model, starts_and_actions, trajectories, steps):
    """Worst |state| and |obs| differences per row between MJX and C MuJoCo's mj_step (float64).

    The observation is rebuilt as dm_control defines it, from the pole's world rotation
    matrix (cos = xmat zz, sin = xmat xz), rather than from the joint angle.
    """
    data = mujoco.MjData(model)
    pole = model.body("pole").id
    qpos0, qvel0, actions = starts_and_actions
    state_errors, obs_errors = np.zeros(N_ENVS), np.zeros(N_ENVS)
    for row in range(N_ENVS):
        mujoco.mj_resetData(model, data)
        data.qpos[:], data.qvel[:] = qpos0[row], qvel0[row]
        for t in range(steps):
            data.ctrl[:] = actions[row, t]
            mujoco.mj_step(model, data)
            reference = np.concatenate([data.qpos, data.qvel])
            mjx_state = np.concatenate([trajectories["qpos"][row, t], trajectories["qvel"][row, t]])
            state_errors[row] = max(state_errors[row], np.abs(reference - mjx_state).max())
            mujoco.mj_kinematics(model, data)  # xmat for the new qpos (mj_step leaves the old one)
            xmat = data.xmat[pole].reshape(3, 3)
            dm_obs = np.array([data.qpos[0], xmat[2, 2], xmat[0, 2], *data.qvel])
            obs_errors[row] = max(obs_errors[row], np.abs(dm_obs - trajectories["obs"][row, t]).max())
    return state_errors, obs_errors


# Compared over the first 300 steps: once the bang-bang rows whirl the pole round
# (|theta_dot| > 10 rad/s) and slam the cart into the slider's limit, the motion is
# chaotic and float32 rounding grows. Measured per row over 300 steps: median 7e-6,
# worst 3e-3 (rows hitting the limit hard); over 1000 steps some rows drift apart by O(1).
COMPARED_STEPS = 300


@pytest.mark.parametrize("solver", ["as in the XML", "MuJoCo's default"])
def test_matches_c_mujoco(env, starts_and_actions, trajectories, solver):
    """C MuJoCo's mj_step on the same XML, float64, from the same starts with the same forces.

    "MuJoCo's default" gives C MuJoCo dm_control's solver budget (100 iterations, 50
    line-search steps) instead of the XML's reduced one: the trajectories must not change.
    """
    model = env.unwrapped.mj_model
    if solver == "MuJoCo's default":
        model = mujoco.MjModel.from_xml_path(str(asset_path(env.unwrapped.xml)))
        model.opt.iterations, model.opt.ls_iterations = 100, 50
    state_errors, obs_errors = c_mujoco_errors(model, starts_and_actions, trajectories, COMPARED_STEPS)
    assert np.median(state_errors) < 1e-4, state_errors
    assert state_errors.max() < 1e-2, state_errors  # the rows that hit the limit hardest
    assert obs_errors.max() < 1e-2, obs_errors


def test_slider_is_limited(trajectories):
    """dm_control's slider range [-1.8, 1.8] m holds (a soft limit: a little overshoot)."""
    x = trajectories["qpos"][..., 0]
    assert np.abs(x).max() < 2.2
    assert np.abs(x).max() > 1.8  # the bang-bang rows do reach it, so the check can fail
