"""half-cheetah against Gymnasium's HalfCheetah-v5 (C MuJoCo, float64) from the same states."""

import numpy as np
import pytest

import envs
from gymnasium_mujoco import (assert_resets_match, assert_same_options,
                              assert_steps_match, exact_noise_bounds, gymnasium_kwargs,
                              gymnasium_reset_samples, gymnasium_steps, reset_samples, transitions)

# Slow run: a contact model's step proof (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

NAME, GYMNASIUM_ID = "half-cheetah", "HalfCheetah-v5"
# float32 (ours) against float64 (Gymnasium), one env step of 5 MuJoCo steps with contacts: positions
# agree to ~4e-6, joint velocities (up to ~20 rad/s) to ~4e-4, the reward to ~5e-6 (measured).
TOLERANCE = {"obs": 1e-3, "reward": 2e-5, "x_position": 1e-5}


@pytest.fixture(scope="module")
def steps():
    ours = transitions(NAME)
    return ours, gymnasium_steps(GYMNASIUM_ID, ours)


def test_steps_match_gymnasium(steps):
    ours, theirs = steps
    assert (theirs.contacts > 0).mean() > 0.3, "many states must touch the floor"  # 46%
    assert np.abs(theirs.obs[:, 8:]).max() > 10, "and move fast"
    assert_steps_match(ours.steps, theirs, TOLERANCE)
    assert set(ours.steps.info) == {"reward_forward", "reward_ctrl", "x_position", "x_velocity"}


@pytest.mark.slow
def test_steps_match_gymnasium_with_every_option_changed():
    overrides = dict(forward_reward_weight=2.5, ctrl_cost_weight=0.7, reset_noise_scale=0.3,
                     exclude_current_positions_from_observation=False)
    ours = transitions(NAME, num_envs=8, num_steps=20, keep=80, **overrides)
    assert ours.steps.obs.shape[1] == 18
    assert_steps_match(ours.steps, gymnasium_steps(GYMNASIUM_ID, ours, **overrides), TOLERANCE)


def test_options_are_gymnasiums():
    assert_same_options(NAME, GYMNASIUM_ID)
    env = envs.make(NAME, ctrl_cost_weight=0.5)
    assert gymnasium_kwargs(env.unwrapped.params)["ctrl_cost_weight"] == 0.5
    np.testing.assert_array_equal(env.action_low, -np.ones(6)), np.testing.assert_array_equal(env.action_high, np.ones(6))


@pytest.mark.parametrize("option, value", [("reset_noise_scale", -0.1), ("ctrl_cost_weight", float("nan")),
                                           ("exclude_current_positions_from_observation", 1)])
def test_bad_options_are_refused(option, value):
    with pytest.raises(ValueError, match=option):
        envs.make(NAME, **{option: value})


def test_reset_distribution_matches_gymnasium():
    qpos, qvel, obs = reset_samples(NAME, 4000)
    their_qpos, their_qvel, their_obs = gymnasium_reset_samples(GYMNASIUM_ID, 4000)
    assert_resets_match(qpos, their_qpos, "qpos")
    assert_resets_match(qvel, their_qvel, "qvel")
    np.testing.assert_array_equal(obs, np.concatenate([qpos[:, 1:], qvel], axis=1))
    exact_noise_bounds(qpos, 0.0, 0.1, "qpos")  # U(-0.1, 0.1) around qpos0 = 0
    assert np.abs(qvel).max() > 0.3, "velocities are 0.1 * N(0, 1), not uniform"


