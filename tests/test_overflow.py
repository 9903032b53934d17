"""A step whose physics MuJoCo Warp could not hold (info["overflow"]) is kept from the learner:
the DQN never stores it, a training run says once which buffer to raise and stops when most steps
overflow. Warp itself sets the flag in tests/test_warp.py; here a CartPole reports it on the CPU
where the cart is right of the centre, as an undersized contact pool would."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents import DQN, DQNConfig, train_run
from agents import env_options
from envs import mjx_warp

# Slow run: Warp overflow through a DQN run (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

CONFIG = DQNConfig(total_steps=400, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                   eval_episodes=2, hidden=(16,))


class OverflowingCartPole(envs.CartPoleMjx):
    """Reports a contact-pool overflow on every step that ends 2 cm or more right of the centre
    (`threshold=-1`: on every step)."""

    threshold = 0.02

    def _overflow(self, data):
        return jnp.where(data.qpos[0] > self.threshold, mjx_warp.OVERFLOW_CONTACTS, 0.0).astype(jnp.float32)


class AlwaysOverflowingCartPole(OverflowingCartPole):
    threshold = -1e9


for name, task in (("test-overflowing-cartpole", OverflowingCartPole),
                   ("test-always-overflowing-cartpole", AlwaysOverflowingCartPole)):
    if name not in envs.names():
        envs.register(name, task, episode_length=500)


@pytest.mark.slow
def test_an_overflowing_step_ends_the_episode_like_nan_physics():
    env = OverflowingCartPole()
    state = env.reset(jax.random.PRNGKey(0))
    state = state.replace(pipeline_state=state.pipeline_state.replace(qpos=jnp.array([0.5, 0.0])))
    stepped = env.step(state, 1)
    assert float(stepped.info["overflow"]) == 1.0 and float(stepped.info["nan"]) == 0.0
    assert float(stepped.done) == 1.0 and float(stepped.reward) == 0.0
    np.testing.assert_array_equal(stepped.obs, state.obs)  # the previous observation, not the invalid one


def test_the_dqn_never_stores_an_overflowing_step():
    dqn = DQN(CONFIG, envs.TimeLimit(OverflowingCartPole(), 500))
    ts = jax.jit(dqn.init)(jax.random.PRNGKey(0))
    ts, metrics = jax.jit(dqn.chunk)(ts)
    overflowed = int(metrics["overflow_contacts"])
    assert overflowed > 5 and int(metrics["overflow_constraints"]) == 0
    assert int(ts.buffer.size) == int(ts.env_steps) - overflowed  # every other step, none that overflowed


@pytest.mark.slow
def test_a_run_says_once_which_buffer_to_raise(capsys):
    train_run("test-overflowing-cartpole", CONFIG, progress=True)
    printed = capsys.readouterr()
    lines = [line for line in (printed.out + printed.err).splitlines() if "MuJoCo Warp ran out" in line]
    assert len(lines) == 1, printed
    assert "its contact pool" in lines[0] and "--env-opt nconmax=" in lines[0] and "envs.make(..., nconmax=" in lines[0]


@pytest.mark.slow  # issue #29: out of the default run (make test <= 8 min); a third faked-overflow run (~14 s); the flag, the skipped transitions and the message stay
def test_a_run_that_overflows_on_most_steps_stops():
    with pytest.raises(RuntimeError, match=r"MuJoCo Warp ran out of its contact pool .* Most env-steps of chunk 0 "
                                           r"overflowed: the run stops"):
        train_run("test-always-overflowing-cartpole", CONFIG, progress=False)


def test_the_report_names_the_buffer_and_the_override():
    task = envs.CartPoleMjx()
    task.warp_buffers = mjx_warp.WarpBuffers(nconmax=16, njmax=70)
    line = env_options.overflow_report(envs.TimeLimit(task, 10), 3, 4, 1000)
    assert "contact pool (nconmax=16 per env) on 3 of 1,000 env-steps" in line and "--env-opt nconmax=32" in line
    assert "constraint rows (njmax=70 per env) on 4 of 1,000" in line and "--env-opt njmax=140" in line
    task.warp_buffers = mjx_warp.WarpBuffers(nconmax=16, njmax=70, naconmax=5000)
    assert "naconmax=5000 for the batch" in env_options.overflow_report(task, 1, 0, 10)


@pytest.mark.slow  # the benchmark script's counter (benchmark scripts run in the slow run)
def test_throughput_runs_count_the_steps_that_overflowed():
    from benchmarks import env_throughput

    num_envs, steps = 3, 40
    some = int(env_throughput.rollout_fn("test-overflowing-cartpole", num_envs, steps)(jax.random.PRNGKey(0))[2])
    assert 0 < some < num_envs * steps
    records = env_throughput.measure([("mjxsuite", "cartpole-mjx"), ("mjxsuite", "test-always-overflowing-cartpole")],
                                     num_envs, steps, repeats=1)
    assert [r["overflow_steps"] for r in records] == [0, num_envs * steps]
    assert all(r["steps_per_s"] > 0 for r in records)


class AlwaysOverflowingPendulum(envs.PendulumMjx):
    """A continuous task whose every step overflows the constraint rows, for Brax's trainers."""

    def _overflow(self, data):
        return jnp.full((), mjx_warp.OVERFLOW_CONSTRAINTS, jnp.float32)


if "test-always-overflowing-pendulum" not in envs.names():
    envs.register("test-always-overflowing-pendulum", AlwaysOverflowingPendulum, episode_length=50)


@pytest.mark.slow
def test_a_ppo_run_that_overflows_on_most_steps_stops():
    """PPO's chunks count the overflowing steps as DQN's do, and the one lifecycle stops the run."""
    from agents.ppo import PPOConfig

    config = PPOConfig(num_timesteps=512, num_envs=8, batch_size=8, num_minibatches=4, unroll_length=8,
                       num_updates_per_batch=1, num_evals=3, num_eval_envs=4, policy_hidden=(16,), value_hidden=(16,))
    with pytest.raises(RuntimeError, match=r"MuJoCo Warp ran out of its constraint rows .* Most env-steps of chunk 0 "
                                           r"overflowed: the run stops"):
        train_run("test-always-overflowing-pendulum", config, progress=False)
