"""inverted-pendulum and inverted-double-pendulum against Gymnasium's InvertedPendulum-v5 and
InvertedDoublePendulum-v5 (C MuJoCo, float64) from the same states."""

import numpy as np
import pytest

import envs
from gymnasium_mujoco import (assert_resets_match, assert_same_options, assert_steps_match,
                              exact_noise_bounds, gymnasium_reset_samples, gymnasium_steps, lockstep, reset_samples,
                              select, transitions)

# float32 (ours) against float64 (Gymnasium), no contacts (measured): observations agree to 5e-7
# (InvertedPendulum) and 4e-5 of velocities up to 10 (InvertedDoublePendulum), rewards to 4e-6;
# assert_steps_match adds 1e-4 relative.
TOLERANCE = {"obs": 2e-5, "reward": 2e-5}


@pytest.mark.slow
def test_inverted_pendulum_steps_match_gymnasium():
    # The pole falls within a few steps under random actions: short episodes, many of them.
    ours = transitions("inverted-pendulum", num_envs=64, num_steps=8, keep=320)
    theirs = gymnasium_steps("InvertedPendulum-v5", ours)
    assert 0.05 < theirs.terminated.mean() < 0.95, "both kinds of step must be in the sample"
    assert_steps_match(ours.steps, theirs, TOLERANCE)
    assert set(ours.steps.info) == {"reward_survive"}
    # Gymnasium pays 1 per step and 0 on the step that ends the episode.
    np.testing.assert_array_equal(theirs.reward, ~theirs.terminated)


@pytest.mark.heavy  # issue #29: out of the default run (make test <= 8 min); the double pendulum's own step compile (~33 s); the single pendulum's stays
def test_inverted_double_pendulum_steps_match_gymnasium():
    ours = transitions("inverted-double-pendulum", num_envs=32, num_steps=10, keep=320)
    theirs = gymnasium_steps("InvertedDoublePendulum-v5", ours)
    assert 0.05 < theirs.terminated.mean() < 0.95
    assert (theirs.obs[:, 8] != 0).mean() > 0.02, "the cart's constraint force (its rail limit) must be seen"
    assert (np.abs(theirs.obs[:, 5:8]) == 10).any(), "and the clipped velocities"
    assert_steps_match(ours.steps, theirs, TOLERANCE)
    assert set(ours.steps.info) == {"reward_survive", "distance_penalty", "velocity_penalty"}


@pytest.mark.heavy  # compiles its own contact/RK4 step (minutes of CPU): kept out of the default run (issue #29)
def test_inverted_double_pendulum_episodes_match_gymnasium():
    """Whole episodes side by side: the reset's observation (tip site, constraint force) and
    the steps that read what MuJoCo's RK4 leaves behind."""
    ours, theirs, live = lockstep("inverted-double-pendulum", "InvertedDoublePendulum-v5", num_episodes=16,
                                  num_steps=12)
    assert_steps_match(select(ours, live), select(theirs, live), {"obs": 1e-4, "reward": 1e-4})


@pytest.mark.parametrize("name, gymnasium_id", [("inverted-pendulum", "InvertedPendulum-v5"),
                                                ("inverted-double-pendulum", "InvertedDoublePendulum-v5")])
def test_options_are_gymnasiums(name, gymnasium_id):
    assert_same_options(name, gymnasium_id)
    env = envs.make(name)
    high = 3.0 if name == "inverted-pendulum" else 1.0  # Gymnasium's action space: the ctrlrange
    np.testing.assert_array_equal(env.action_low, [-high]), np.testing.assert_array_equal(env.action_high, [high])


@pytest.mark.heavy
def test_steps_match_gymnasium_with_every_option_changed():
    overrides = dict(healthy_reward=3.0, reset_noise_scale=0.2)
    ours = transitions("inverted-double-pendulum", num_envs=8, num_steps=10, keep=80, **overrides)
    assert_steps_match(ours.steps, gymnasium_steps("InvertedDoublePendulum-v5", ours, **overrides), TOLERANCE)


@pytest.mark.parametrize("name, option, value", [("inverted-pendulum", "reset_noise_scale", -0.1),
                                                 ("inverted-double-pendulum", "healthy_reward", float("inf"))])
def test_bad_options_are_refused(name, option, value):
    with pytest.raises(ValueError, match=option):
        envs.make(name, **{option: value})


def test_inverted_pendulum_reset_distribution_matches_gymnasium():
    qpos, qvel, obs = reset_samples("inverted-pendulum", 4000)
    their_qpos, their_qvel, _ = gymnasium_reset_samples("InvertedPendulum-v5", 4000)
    assert_resets_match(qpos, their_qpos, "qpos"), assert_resets_match(qvel, their_qvel, "qvel")
    np.testing.assert_array_equal(obs, np.concatenate([qpos, qvel], axis=1))
    exact_noise_bounds(qpos, 0.0, 0.01, "qpos"), exact_noise_bounds(qvel, 0.0, 0.01, "qvel")


@pytest.mark.slow
def test_inverted_double_pendulum_reset_distribution_matches_gymnasium():
    qpos, qvel, obs = reset_samples("inverted-double-pendulum", 4000)
    their_qpos, their_qvel, their_obs = gymnasium_reset_samples("InvertedDoublePendulum-v5", 4000)
    assert_resets_match(qpos, their_qpos, "qpos"), assert_resets_match(qvel, their_qvel, "qvel")
    assert_resets_match(obs, their_obs, "observation")  # tip and constraint force from mj_forward at reset
    exact_noise_bounds(qpos, 0.0, 0.1, "qpos")
    assert np.abs(qvel).max() > 0.25, "velocities are 0.1 * N(0, 1), not uniform"


