"""swimmer against Gymnasium's Swimmer-v5 (C MuJoCo, float64) from the same states."""

import numpy as np
import pytest

import envs
from gymnasium_mujoco import (assert_resets_match, assert_same_options,
                              assert_steps_match, exact_noise_bounds, gymnasium_reset_samples,
                              gymnasium_steps, reset_samples, transitions)

NAME, GYMNASIUM_ID = "swimmer", "Swimmer-v5"
# float32 (ours) against float64 (Gymnasium), one env step of 4 RK4 steps in the fluid, measured:
# positions agree to ~7e-7, velocities to ~4e-6, the reward to ~1e-6.
TOLERANCE = {"obs": 2e-5, "reward": 1e-5}
HINGE_LIMIT = np.deg2rad(100)


@pytest.fixture(scope="module")
def steps():
    ours = transitions(NAME)
    return ours, gymnasium_steps(GYMNASIUM_ID, ours)


@pytest.mark.slow  # compiles its own contact/RK4 step (minutes of CPU): kept out of the default run (issue #29)
def test_steps_match_gymnasium(steps):
    ours, theirs = steps
    assert (np.abs(theirs.obs[:, 1:3]) > HINGE_LIMIT).any(), "some states must push a hinge past its limit"
    assert_steps_match(ours.steps, theirs, TOLERANCE)
    assert set(ours.steps.info) == {"reward_forward", "reward_ctrl", "x_position", "y_position",
                                    "distance_from_origin", "x_velocity", "y_velocity"}


@pytest.mark.heavy
def test_steps_match_gymnasium_with_every_option_changed():
    overrides = dict(forward_reward_weight=2.5, ctrl_cost_weight=0.7, reset_noise_scale=0.3,
                     exclude_current_positions_from_observation=False)
    ours = transitions(NAME, num_envs=8, num_steps=20, keep=80, **overrides)
    assert ours.steps.obs.shape[1] == 10
    assert_steps_match(ours.steps, gymnasium_steps(GYMNASIUM_ID, ours, **overrides), TOLERANCE)


def test_options_are_gymnasiums():
    assert_same_options(NAME, GYMNASIUM_ID)


def test_reset_distribution_matches_gymnasium():
    qpos, qvel, obs = reset_samples(NAME, 4000)
    their_qpos, their_qvel, _ = gymnasium_reset_samples(GYMNASIUM_ID, 4000)
    assert_resets_match(qpos, their_qpos, "qpos")
    assert_resets_match(qvel, their_qvel, "qvel")
    exact_noise_bounds(qpos, 0.0, 0.1, "qpos")
    exact_noise_bounds(qvel, 0.0, 0.1, "qvel")
    np.testing.assert_array_equal(obs, np.concatenate([qpos[:, 2:], qvel], axis=1))


