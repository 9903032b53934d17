"""dm_control's finger (spin, turn_easy, turn_hard) against dm_control 1.0.50's own envs: single steps
from dm_control's own physics states (its touches, fast spins and tips on the target among them),
the reset's observation and distribution (collision-free draws), and, with no physics compiled, the
observation and reward of dm_control's states for all three tasks.

Finger's physics (elliptic cones, 200 solver iterations) takes minutes to compile on two cores: the
proof compiles one program (`steps_from`: a batch of resets and one step from the given states) for
turn-easy and runs under `slow`; the default run checks the tasks' observation and reward only."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import envs

pytest.importorskip("dm_control", reason="the DeepMind Control Suite tasks are proven against dm-control==1.0.50 "
                                         "(pip install 'mjxsuite[dmc]'; the test extra has it)")

from envs.interop.dm_control import (Comparison, assert_resets_touch_nothing, assert_spec_is_dm_controls,  # noqa: E402
                                     compare_readings_with_dm_control,
                                     dm_control_observations, dm_control_reset_samples, dm_control_rollouts,
                                     dm_control_steps, steps_from)
from tests.test_dm_control import assert_same_distribution  # noqa: E402

TASKS = {"dmc-finger-spin": ("finger", "spin"), "dmc-finger-turn-easy": ("finger", "turn_easy"),
         "dmc-finger-turn-hard": ("finger", "turn_hard")}
# float32 (ours) against float64 (dm_control), one control step: the observation's absolute bound
# (plus 1e-4 relative; the hinge spins at up to tens of rad/s, contacts make its velocities' rounding
# larger) and the reward's (0 or 1: every reward equal).
BOUNDS = {"obs": 2e-3, "reward": 1e-6}
COUNT = 128  # states per task: one batch shape, one compiled program
TOUCH_OBS = slice(7, 9)  # the observation's touch entries (position 4, velocity 3, touch 2, ...)


def start_states(env, rng):
    """`COUNT` of dm_control's own states: a quarter whose step touches, a quarter near the task's goal
    (the hinge spun to U(-30, 0) rad/s across spin's -15; the spinner's tip turned within 0.8 rad of
    turn's target, about 1.5 times the easy target's half-width), the rest spread over the episodes."""
    rollouts = dm_control_rollouts(env, episodes=6, num_steps=250)
    touching = np.flatnonzero(rollouts.steps.obs[:, TOUCH_OBS].max(axis=1) > 0)[:COUNT // 4]
    others = np.setdiff1d(np.arange(len(rollouts.qpos)), touching)
    chosen = np.concatenate([touching, others[np.linspace(0, len(others) - 1, COUNT - len(touching)).astype(int)]])
    qpos, qvel = rollouts.qpos[chosen].copy(), rollouts.qvel[chosen].copy()
    episode = {name: values[chosen] for name, values in rollouts.episode.items()}
    near = np.arange(len(touching), len(touching) + COUNT // 4)
    hinge = env.mj_model.joint("hinge")
    if env.task == "spin":
        qvel[near, hinge.dofadr[0]] = rng.uniform(-30.0, 0.0, len(near))
    else:
        to_target = episode["target"][near] - env.mj_model.body("spinner").pos[[0, 2]]
        # The tip sits 0.13 up the spinner's z-axis; the hinge turns about -y, so the tip's angle from
        # +z towards +x is minus the hinge angle.
        qpos[near, hinge.qposadr[0]] = -np.arctan2(to_target[:, 0], to_target[:, 1]) + rng.uniform(-0.8, 0.8, len(near))
    actions = rng.uniform(-1.0, 1.0, (COUNT, env.action_size))
    return qpos.astype(np.float32), qvel.astype(np.float32), actions, {k: v.astype(np.float32) for k, v in episode.items()}


# Spin's physics is turn's with one constant changed (the hinge's damping, which
# test_finger_tasks_are_dm_controls holds to dm_control's): only turn-easy's program is compiled in
# the slow run, to keep it within its budget; spin's readings are proven in the default run.
@pytest.fixture(scope="module", params=[pytest.param("dmc-finger-turn-easy", marks=pytest.mark.heavy)])
def finger_case(request):
    name = request.param
    env = envs.make(name).unwrapped
    starts = steps_from(env, *start_states(env, np.random.default_rng(0)))
    return name, env, starts, dm_control_steps(env, starts)


def test_finger_steps_match_dm_control(finger_case):
    name, env, starts, theirs = finger_case
    Comparison(starts.steps, theirs).assert_within(BOUNDS)
    assert np.all(theirs.discount == 1.0) and np.all(starts.steps.discount == 1.0)
    assert 0.05 < theirs.reward.mean() < 0.95, "both rewards (0 and 1) must occur"
    assert (theirs.obs[:, TOUCH_OBS].max(axis=1) > 0).mean() > 0.05, "the fingertip must touch in some steps"


def test_finger_reset_observation_is_dm_controls(finger_case):
    name, env, starts, _ = finger_case
    theirs = dm_control_observations(env, starts.reset_qpos, starts.reset_qvel, starts.reset_episode)
    np.testing.assert_allclose(starts.reset_obs, theirs, atol=1e-5, rtol=1e-4)


def test_finger_reset_distribution_matches_dm_control(finger_case):
    """The joints (and turn's target, as the observation's target_position) in distribution; C MuJoCo
    finds no contact at any of our resets, though the randomiser's raw draws touch: the loop rejects."""
    name, env, starts, _ = finger_case
    their_qpos, their_qvel, their_obs = dm_control_reset_samples(*TASKS[name], 1000)
    assert_same_distribution(starts.reset_qpos, their_qpos, f"{name} qpos")
    assert_same_distribution(starts.reset_obs, their_obs, f"{name} reset observation")
    assert not starts.reset_qvel.any() and not their_qvel.any()
    raw = np.asarray(jax.jit(jax.vmap(env.joints_drawn))(jax.random.split(jax.random.PRNGKey(1), 500)))
    assert_resets_touch_nothing(env, starts.reset_qpos, raw)


def spin_and_turn(physics, rng):
    """The hinge spun across spin's threshold and turned anywhere (onto turn's target at times)."""
    hinge = physics.model.name2id("hinge", "joint")
    physics.data.qvel[physics.model.jnt_dofadr[hinge]] = rng.uniform(-30.0, 0.0)
    physics.data.qpos[physics.model.jnt_qposadr[hinge]] = rng.uniform(-np.pi, np.pi)


@pytest.mark.parametrize("name", sorted(TASKS))
def test_finger_observation_and_reward_of_dm_controls_states(name):
    """Our observation and reward of dm_control's own physics after each of its steps (no physics runs
    here), over random-action episodes spun and turned every third step: every task's readings of
    the sensors, its target and its thresholds."""
    comparison = compare_readings_with_dm_control(name, perturb=spin_and_turn)
    comparison.assert_within({"obs": 1e-6, "reward": 0.0}, rtol=1e-5)
    if name == "dmc-finger-spin":
        assert 0 < comparison.theirs.reward.mean() < 1, "both rewards must occur"


def test_finger_tasks_are_dm_controls():
    """Specs (the action bounds, timestep, substeps, episode, observation layout) and the model edits
    dm_control makes in every episode: spin's hinge damping, turn's target radius."""
    for name in TASKS:
        env, theirs = assert_spec_is_dm_controls(name)
        for field in ("dof_damping", "site_size", "site_rgba"):
            np.testing.assert_array_equal(getattr(env.mj_model, field), getattr(theirs.physics.model, field),
                                          err_msg=f"{name} {field}")
