"""hopper and walker2d against Gymnasium's Hopper-v5 and Walker2d-v5 (C MuJoCo, float64) from the
same states."""

import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents import env_options
from gymnasium_mujoco import (assert_resets_match, assert_same_options,
                              assert_steps_match, exact_noise_bounds, gymnasium_env, gymnasium_reset_samples,
                              gymnasium_steps, reset_samples, transitions)

# float32 (ours) against float64 (Gymnasium), one env step of 4 RK4 steps with contacts, measured:
# positions agree to ~5e-7, velocities to ~1e-5 (Hopper) and ~1.2e-4 (Walker2d, up to 10 rad/s after
# the clip), the reward to ~5e-6 (x_velocity is a float32 difference of x divided by dt = 0.008).
TASKS = {"hopper": ("Hopper-v5", {"obs": 1e-4, "reward": 2e-5}),
         "walker2d": ("Walker2d-v5", {"obs": 5e-4, "reward": 2e-5})}
METRICS = {"reward_forward", "reward_ctrl", "reward_survive", "x_position", "z_distance_from_origin", "x_velocity"}


@pytest.mark.slow  # compiles its own contact/RK4 step (minutes of CPU): kept out of the default run (issue #29)
@pytest.mark.parametrize("name", TASKS)
def test_steps_match_gymnasium(name):
    gymnasium_id, tolerance = TASKS[name]
    ours = transitions(name)
    theirs = gymnasium_steps(gymnasium_id, ours)
    assert (theirs.contacts > 0).mean() > 0.3, "many states must touch the floor"  # 70% hopper, 47% walker2d
    assert 0.2 < theirs.terminated.mean() < 0.8, "healthy and unhealthy states both"  # about half each
    assert_steps_match(ours.steps, theirs, tolerance)
    assert set(ours.steps.info) == METRICS


@pytest.mark.heavy
@pytest.mark.parametrize("name", TASKS)
def test_steps_match_gymnasium_with_every_option_changed(name):
    gymnasium_id, tolerance = TASKS[name]
    overrides = dict(forward_reward_weight=2.5, ctrl_cost_weight=0.7, healthy_reward=3.0,
                     terminate_when_unhealthy=False, healthy_z_range=(0.9, 1.3), healthy_angle_range=(-0.1, 0.3),
                     reset_noise_scale=0.05, exclude_current_positions_from_observation=False)
    if name == "hopper":
        overrides["healthy_state_range"] = (-5.0, 5.0)
    ours = transitions(name, num_envs=8, num_steps=20, keep=80, **overrides)
    theirs = gymnasium_steps(gymnasium_id, ours, **overrides)
    assert not theirs.terminated.any() and 0 < theirs.info["reward_survive"].mean() < 3.0
    assert_steps_match(ours.steps, theirs, tolerance)


@pytest.mark.parametrize("name", TASKS)
def test_options_are_gymnasiums(name):
    assert_same_options(name, TASKS[name][0])


@pytest.mark.parametrize("option, value", [("healthy_z_range", (1.0, 0.5)), ("healthy_angle_range", 0.2),
                                           ("terminate_when_unhealthy", "no"), ("reset_noise_scale", -1.0)])
def test_bad_options_are_refused(option, value):
    with pytest.raises(ValueError, match=option):
        envs.make("walker2d", **{option: value})


def test_a_tuple_option_reads_from_the_command_line():
    assert env_options.parse_option("hopper", "healthy_z_range", "0.5,inf") == (0.5, float("inf"))


@pytest.mark.parametrize("name", TASKS)
def test_health_at_the_edges_is_gymnasiums(name):
    """The healthy ranges are open intervals: states on and just inside each bound (no physics
    step, so this compares the rule alone)."""
    env = envs.make(name).unwrapped
    theirs = gymnasium_env(TASKS[name][0])
    low_z, high_z = env.params.healthy_z_range
    low_angle, high_angle = env.params.healthy_angle_range
    edges = [(1, low_z), (1, low_z + 1e-3), (2, low_angle), (2, high_angle - 1e-3), (2, high_angle)]
    edges += [(1, high_z)] if np.isfinite(high_z) else [(1, 1e6)]
    states = [(index, value, None) for index, value in edges]
    if name == "hopper":  # every other coordinate, velocities included, inside (-100, 100)
        states += [(None, None, (3, 100.0)), (None, None, (3, 99.9)), (None, None, (5, -100.0))]
    for qpos_index, qpos_value, qvel_change in states:
        qpos, qvel = env.init_qpos.copy(), np.zeros(env.mj_model.nv)
        if qpos_index is not None:
            qpos[qpos_index] = qpos_value
        if qvel_change is not None:
            qvel[qvel_change[0]] = qvel_change[1]
        theirs.set_state(qpos, qvel)
        data = env._initial_data.replace(qpos=jnp.asarray(qpos, jnp.float32), qvel=jnp.asarray(qvel, jnp.float32))
        assert bool(env.is_healthy(data)) == theirs.is_healthy, (qpos, qvel)


@pytest.mark.parametrize("name", TASKS)
def test_reset_distribution_matches_gymnasium(name):
    env = envs.make(name).unwrapped
    qpos, qvel, obs = reset_samples(name, 4000)
    their_qpos, their_qvel, _ = gymnasium_reset_samples(TASKS[name][0], 4000)
    assert_resets_match(qpos, their_qpos, "qpos")
    assert_resets_match(qvel, their_qvel, "qvel")
    exact_noise_bounds(qpos, env.init_qpos, 5e-3, "qpos")
    exact_noise_bounds(qvel, 0.0, 5e-3, "qvel")
    np.testing.assert_array_equal(obs, np.concatenate([qpos[:, 1:], qvel], axis=1))


