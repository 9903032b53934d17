"""dm_control's humanoid stand, walk, run and run_pure_state against dm_control 1.0.50's own envs: single steps from
dm_control's own physics states (falls and floor contacts) and from states standing near the goal,
the reset's observation and distribution (collision-free draws), and, with no physics compiled, the
observation and reward of dm_control's states for the four tasks.

The humanoid's physics (161 contact pairs, 5 substeps, the collision-free loop at reset) compiles slowly on
two cores: the step proof compiles one program (`steps_from`: resets and one step from the given states, mapped
on the CPU) for stand and runs under `heavy`; walk and run are stand's physics with
other rewards, and run_pure_state is run's with MuJoCo's state (qpos, qvel) as its observation, all
proven by their readings."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import envs

pytest.importorskip("dm_control", reason="the DeepMind Control Suite tasks are proven against dm-control==1.0.50 "
                                         "(pip install 'mjxsuite[dmc]'; the test extra has it)")

from envs.interop.dm_control import (Comparison, _batched, assert_resets_touch_nothing,  # noqa: E402
                                     assert_spec_is_dm_controls, compare_readings_with_dm_control,
                                     dm_control_observations, dm_control_reset_samples, dm_control_rollouts,
                                     dm_control_steps, steps_from)
from tests.test_dm_control import assert_same_distribution  # noqa: E402

TASKS = {"dmc-humanoid-stand": ("humanoid", "stand"), "dmc-humanoid-walk": ("humanoid", "walk"),
         "dmc-humanoid-run": ("humanoid", "run"), "dmc-humanoid-run-pure-state": ("humanoid", "run_pure_state")}
COUNT = 64  # states: one batch shape, one compiled program
# float32 (ours) against float64 (dm_control), one control step (+ 1e-4 relative). At a few states
# of a fall, with limbs lying on the floor, MJX's contact solve parts from C MuJoCo's far beyond this,
# and x64 leaves it as it is (docs/tasks.md): not rounding but MJX's algorithm. Such steps are
# counted, at most SPIKES of the COUNT, and their rewards still held to the bound.
BOUNDS = {"obs": 1e-3, "reward": 1e-5}
SPIKES = 4


def stand_up(physics, rng):
    """Upright at the model's initial pose, nearly still (stand's reward) or moving at up to 1.5 times
    run's speed (walk's and run's): every reward term."""
    physics.data.qpos[:] = physics.model.qpos0 + rng.uniform(-0.05, 0.05, physics.model.nq)
    physics.data.qvel[:] = rng.normal(0.0, 0.1, physics.model.nv)
    physics.data.qvel[:2] = rng.choice([0.1, 15.0]) * rng.uniform(-1.0, 1.0, 2)


@pytest.mark.parametrize("name", sorted(TASKS))
def test_humanoid_observation_and_reward_of_dm_controls_states(name):
    """Our observation and reward of dm_control's own physics after each of its steps (no physics runs
    here): the joints, the head, the extremities in the torso's frame, the centre of mass's velocity
    sensor, and every reward term (standing up every third step)."""
    comparison = compare_readings_with_dm_control(name, episodes=3, num_steps=8, perturb=stand_up)
    comparison.assert_within({"obs": 1e-5, "reward": 1e-6}, rtol=1e-5)
    assert comparison.theirs.reward.max() > 0.3, "the reward must be exercised"


def test_humanoid_tasks_are_dm_controls():
    for name in TASKS:
        assert_spec_is_dm_controls(name)


def test_on_the_cpu_the_step_proof_steps_its_states_one_after_another():
    """`steps_from`'s program holds no batched Cholesky on the CPU: there jaxlib's batched one waits on XLA's thread
    pool from inside it, and two at once (the reset's and the step's Newton solves) hung `stand_case` on two cores."""
    factor = _batched(lambda matrix, scale: jax.numpy.linalg.cholesky(matrix * scale))
    matrices, scales = np.tile(np.eye(3, dtype=np.float32), (4, 1, 1)), np.arange(1.0, 5.0, dtype=np.float32)
    jaxpr = str(jax.make_jaxpr(factor)(matrices, scales))
    assert "f32[3,3] = cholesky" in jaxpr and "f32[4,3,3] = cholesky" not in jaxpr, jaxpr
    np.testing.assert_allclose(factor(matrices, scales), np.sqrt(scales)[:, None, None] * matrices)


@pytest.fixture(scope="module")
def stand_case():
    """Half dm_control's own states along four falls from its resets, half standing near qpos0."""
    env = envs.make("dmc-humanoid-stand").unwrapped
    rng = np.random.default_rng(0)
    rollouts = dm_control_rollouts(env, episodes=4, num_steps=60)
    chosen = np.linspace(0, len(rollouts.qpos) - 1, COUNT // 2).round().astype(int)
    standing = env.mj_model.qpos0 + rng.uniform(-0.05, 0.05, (COUNT // 2, env.mj_model.nq))
    moving = rng.normal(0.0, 0.5, (COUNT // 2, env.mj_model.nv))
    moving[:, :2] = rng.uniform(-2.0, 2.0, (COUNT // 2, 2))
    qpos = np.concatenate([rollouts.qpos[chosen], standing]).astype(np.float32)
    qvel = np.concatenate([rollouts.qvel[chosen], moving]).astype(np.float32)
    starts = steps_from(env, qpos, qvel, rng.uniform(-1.0, 1.0, (COUNT, env.action_size)))
    return env, starts, dm_control_steps(env, starts)


@pytest.mark.heavy
def test_humanoid_steps_match_dm_control(stand_case):
    env, starts, theirs = stand_case
    within = np.all(np.abs(starts.steps.obs - theirs.obs) <= BOUNDS["obs"] + 1e-4 * np.abs(theirs.obs), axis=1)
    assert (~within).sum() <= SPIKES, f"{(~within).sum()} of {COUNT} steps beyond the bound"
    calm = lambda steps: type(steps)(steps.obs[within], steps.reward[within], steps.discount[within])  # noqa: E731
    Comparison(calm(starts.steps), calm(theirs)).assert_within(BOUNDS)
    np.testing.assert_allclose(starts.steps.reward, theirs.reward, atol=BOUNDS["reward"], rtol=1e-4)
    assert np.all(theirs.discount == 1.0) and np.all(starts.steps.discount == 1.0)
    assert theirs.reward.max() > 0.5 and theirs.reward.min() < 0.1, "the reward must be exercised"


@pytest.mark.heavy
def test_humanoid_reset_observation_is_dm_controls(stand_case):
    env, starts, _ = stand_case
    theirs = dm_control_observations(env, starts.reset_qpos, starts.reset_qvel)
    np.testing.assert_allclose(starts.reset_obs, theirs, atol=1e-5, rtol=1e-4)


@pytest.mark.heavy
def test_humanoid_reset_distribution_matches_dm_control(stand_case):
    """The joints and the root's quaternion (a normalised U(0, 1)^4) in distribution; C MuJoCo finds no
    contact at any of our resets, though the randomiser's raw draws touch: the loop rejects."""
    env, starts, _ = stand_case
    their_qpos, their_qvel, _ = dm_control_reset_samples("humanoid", "stand", 1000)
    assert_same_distribution(starts.reset_qpos, their_qpos, "qpos")
    assert not starts.reset_qvel.any() and not their_qvel.any()
    raw = np.asarray(jax.jit(jax.vmap(env.joints_drawn))(jax.random.split(jax.random.PRNGKey(1), 200)))
    assert_resets_touch_nothing(env, starts.reset_qpos, raw)


