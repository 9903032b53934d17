"""`envs.to_dm_env`: a dmc-* task behind dm_control's `dm_env` interface, stepped beside dm_control's own env of
the task from the same state: the same TimeSteps (types, rewards, discounts, observation dicts) and specs."""

import dm_env
import jax
import numpy as np
import pytest

import envs
from envs.interop.dm_control import load, put_state

pytestmark = pytest.mark.slow  # compiles the cart-pole's MJX step


def test_a_dmc_task_steps_as_dm_controls_own_env_through_dm_env():
    ours = envs.to_dm_env("dmc-cartpole-balance", seed=3, episode_length=40)
    theirs = load("cartpole", "balance")
    assert isinstance(ours, dm_env.Environment)
    assert ours.action_spec() == theirs.action_spec() and ours.observation_spec() == theirs.observation_spec()
    first, their_first = ours.reset(), theirs.reset()
    assert first.first() and first.reward is None
    assert [(key, value.shape, value.dtype) for key, value in first.observation.items()] == [
        (key, value.shape, value.dtype) for key, value in their_first.observation.items()]
    data = ours._state.pipeline_state  # dm_control's physics put in our reset's state
    put_state(theirs.physics, np.asarray(data.qpos, np.float64), np.asarray(data.qvel, np.float64))
    actions = np.random.default_rng(0).uniform(-1, 1, (40, 1))
    for t, action in enumerate(actions):
        step, their_step = ours.step(action), theirs.step(action)
        assert step.step_type == (dm_env.StepType.LAST if t == 39 else dm_env.StepType.MID) and step.discount == 1.0
        np.testing.assert_allclose(step.reward, their_step.reward, atol=1e-4)
        for key, value in step.observation.items():
            np.testing.assert_allclose(value, their_step.observation[key], atol=1e-4, err_msg=key)
    assert ours.step(actions[0]).first()  # our time limit ended it (a truncation, as dm_control's at 1,000 steps)


def test_a_task_outside_the_suite_is_refused_with_the_fix():
    with pytest.raises(ValueError, match="not a DeepMind Control Suite task.*dmc-\\*.*to_gymnasium"):
        envs.to_dm_env("cartpole-mjx")
