"""dm_control's LQR tasks (lqr_2_1, lqr_6_2) against dm_control 1.0.50's own envs. The default run compiles
no physics: our model (dm_control's `_make_model` XML, built on MjSpec) equals dm_control's in every number
and name for the same stiffness; the spec (dm_control's unbounded actions and endless episodes against
ours); the reset distribution and the stiffness's draw (per episode here, per env instance there);
the judge's stop for endless episodes. The slow run compiles one program per task (`steps_from`): one
control step from shared states, each with its episode's stiffness handed to dm_control's physics
(and failing with the MJCF's), termination (a state norm below 1e-6 ends the episode with discount 0
in both) and the resets' observation."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

import envs

pytest.importorskip("dm_control", reason="the DeepMind Control Suite tasks are proven against dm-control==1.0.50 "
                                         "(pip install 'mjxsuite[dmc]'; the test extra has it)")

import mujoco  # noqa: E402

from envs.assets import dm_control_asset  # noqa: E402
from envs.interop.dm_control import (ENDLESS_EPISODE_STEPS, JUDGE_FIRST_SEED, Comparison, Steps,  # noqa: E402
                                     action_bounds, dm_control_observations, dm_control_reset_samples,
                                     dm_control_rollouts, dm_control_steps, load, returns_on_dm_control, steps_from)
from envs.tasks.dmc_lqr import STIFFNESS_RANGE, TERMINAL_TOL, lqr_spec  # noqa: E402
from tests.test_dm_control import assert_same_distribution  # noqa: E402
from tests.test_dm_control_swim import assert_models_equal  # noqa: E402

NAMES = {"dmc-lqr-lqr-2-1": "lqr_2_1", "dmc-lqr-lqr-6-2": "lqr_6_2"}
DRAWS = 2000  # resets drawn on each side
# float32 (ours) against float64 (dm_control), one control step of a linear system: the observation's
# absolute bound and the reward's, plus RTOL relative (values up to 7, float32's rounding of them
# 4e-7). Measured worst: 2.1e-7 / 3.6e-7 (docs/tasks.md's proof table).
BOUNDS = {"obs": 1e-6, "reward": 1e-6}
RTOL = 1e-6
# The slow run's start states, per task one batch (each state twice: with its stiffness, with the MJCF's):
# 16 of dm_control's own along its random-action episodes, 24 anywhere (actions beyond [-1, 1]: nothing
# clips them), 12 within the terminal norm, 12 a little outside it.
OWN, ANYWHERE, TINY, SMALL = 16, 24, 12, 12


@pytest.mark.parametrize("name", sorted(NAMES))
def test_lqr_model_and_spec_are_dm_controls(name):
    """`lqr_spec` with a dm_control env's stiffness is that env's model in every number and name
    (two seeds: two draws of the springs); our task's model is the same but its stiffness, 20 in
    every joint, which no episode steps (`episode_model` puts the episode's in). dm_control's actions
    are unbounded and its episodes endless; ours take any action unclipped, offer [-1, 1] and end
    after 1,000 steps. The substeps, control timestep and observation layout are dm_control's."""
    env = envs.make(name).unwrapped
    for seed in (0, 1):
        theirs = load("lqr", NAMES[name], seed)
        their_model = theirs.physics.model.ptr
        ours = lqr_spec(dm_control_asset("lqr.xml"), env.n_bodies, env.n_actuators, their_model.jnt_stiffness)
        assert_models_equal(ours.compile(), their_model, set(), f"{name}, seed {seed}")
        assert_models_equal(env.mj_model, their_model, {"jnt_stiffness"}, name)
        assert np.ptp(their_model.jnt_stiffness) > 0 and np.all(env.mj_model.jnt_stiffness == 20.0)
    assert env.n_substeps == theirs._n_sub_steps == 1 and abs(env.dt - theirs.control_timestep()) < 1e-12
    assert theirs._step_limit == np.inf and envs.options(name)["episode_length"] == 1000
    spec = theirs.action_spec()
    assert np.all(spec.minimum == -mujoco.mjMAXVAL) and np.all(spec.maximum == mujoco.mjMAXVAL)
    assert np.all(env.action_low == -1.0) and np.all(env.action_high == 1.0)
    np.testing.assert_array_equal(env.action_to_ctrl(np.full(env.action_size, -7.5)), -7.5)  # not clipped
    observation = theirs.reset().observation
    assert [(key, np.size(value)) for key, value in observation.items()] == list(env.observation_shapes)
    stiffness = np.linspace(*STIFFNESS_RANGE, env.n_bodies).astype(np.float32)
    np.testing.assert_array_equal(env.episode_model(env.mjx_model, {"stiffness": stiffness}).jnt_stiffness, stiffness)


def their_stiffness(task: str, count: int) -> np.ndarray:
    """The joints' stiffness of `count` dm_control envs (seeds 0, 1, ...): `_make_model`'s draws."""
    from dm_control.suite import lqr
    from lxml import etree

    load("lqr", task)  # dm_control imported under the mujoco 4 shim
    n_bodies, n_actuators = (int(part) for part in task.split("_")[1:])
    drawn = []
    for seed in range(count):
        xml = etree.fromstring(lqr._make_model(n_bodies, n_actuators, np.random.RandomState(seed)))
        drawn.append([float(joint.get("stiffness")) for joint in xml.iter("joint") if joint.get("stiffness")])
    return np.array(drawn)


@pytest.mark.parametrize("name", sorted(NAMES))
def test_lqr_reset_distribution_matches_dm_control(name):
    """2,000 of our resets against 2,000 of dm_control's: qpos of norm sqrt(2) in a uniformly random
    direction (each coordinate, its square and the product of neighbours within 5 standard errors
    of dm_control's), at rest; each episode's stiffness (ours per episode) against the stiffness of
    1,000 dm_control envs (theirs per env instance), U(15, 25) per joint."""
    env = envs.make(name).unwrapped
    keys = jax.random.split(jax.random.PRNGKey(3), DRAWS)
    qpos, qvel, episode = jax.tree.map(np.asarray, jax.jit(jax.vmap(env.draw_start))(keys))
    their_qpos, their_qvel, _ = dm_control_reset_samples("lqr", NAMES[name], DRAWS)
    np.testing.assert_allclose(np.linalg.norm(qpos, axis=1), np.sqrt(2), rtol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(their_qpos, axis=1), np.sqrt(2), rtol=1e-14)
    assert not qvel.any() and not their_qvel.any()
    moments = lambda q: np.column_stack([q, q ** 2, q[:, :-1] * q[:, 1:]])  # noqa: E731
    assert_same_distribution(moments(qpos.astype(np.float64)), moments(their_qpos), f"{name} qpos")
    stiffness, theirs = episode["stiffness"].astype(np.float64), their_stiffness(NAMES[name], DRAWS // 2)
    assert_same_distribution(stiffness, theirs, f"{name} stiffness")
    for drawn in (stiffness, theirs):
        assert drawn.min() >= STIFFNESS_RANGE[0] and drawn.max() <= STIFFNESS_RANGE[1] and np.ptp(drawn) > 9.9
    assert np.ptp(stiffness[:, 0]) > 0, "each episode's own springs"


def test_the_judge_stops_lqrs_endless_episodes():
    """dm_control's lqr has no time limit: the judge stops an episode after our 1,000 steps (a still
    policy never reaches the goal: the springs keep the chain moving), and its random actions for the
    unbounded motors are drawn in [-1, 1]."""
    still = lambda obs: np.zeros(1)  # noqa: E731
    judged = returns_on_dm_control(still, "dmc-lqr-lqr-2-1", 1)
    theirs = load("lqr", "lqr_2_1", JUDGE_FIRST_SEED)
    theirs.reset()
    steps = [theirs.step(np.zeros(1)) for _ in range(ENDLESS_EPISODE_STEPS)]
    assert judged == [sum(step.reward for step in steps)] and not any(step.last() for step in steps)
    env = envs.make("dmc-lqr-lqr-6-2").unwrapped
    low, high = action_bounds(env, load("lqr", "lqr_6_2").action_spec())
    assert np.all(low == -1.0) and np.all(high == 1.0)


def start_states(env) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """qpos, qvel, actions and stiffness of the slow run's states (`OWN`, `ANYWHERE`, `TINY`, `SMALL`)."""
    rng, n = np.random.default_rng(0), env.n_bodies
    own = dm_control_rollouts(env, episodes=4, num_steps=40)
    pick = np.linspace(0, len(own.qpos) - 1, OWN).round().astype(int)
    qpos, qvel = rng.normal(0.0, 1.0, (ANYWHERE, n)), rng.normal(0.0, 2.0, (ANYWHERE, n))
    actions = rng.uniform(-3.0, 3.0, (ANYWHERE, env.action_size))
    # States of norm 1e-9 to 1e-7 (terminal after the step) and 1e-5 to 1e-4 (not), nudged by tiny forces.
    direction = rng.normal(size=(TINY + SMALL, 2 * n))
    norm = 10.0 ** np.concatenate([rng.uniform(-9, -7, TINY), rng.uniform(-5, -4, SMALL)])
    near = direction / np.linalg.norm(direction, axis=1, keepdims=True) * norm[:, None]
    tiny_actions = rng.uniform(-1e-6, 1e-6, (TINY + SMALL, env.action_size))
    stiffness = rng.uniform(*STIFFNESS_RANGE, (ANYWHERE + TINY + SMALL, n))
    return (np.concatenate([own.qpos[pick], qpos, near[:, :n]]), np.concatenate([own.qvel[pick], qvel, near[:, n:]]),
            np.concatenate([own.actions[pick], actions, tiny_actions]),
            np.concatenate([own.episode["stiffness"][pick], stiffness]))


@pytest.fixture(scope="module", params=[pytest.param(name, marks=pytest.mark.slow) for name in sorted(NAMES)])
def stepped(request):
    """Our step from each start state with its stiffness and with the MJCF's (one program), and
    dm_control's step from the same state with the same stiffness and action."""
    env = envs.make(request.param).unwrapped
    qpos, qvel, actions, stiffness = start_states(env)
    count = len(qpos)
    both = np.concatenate([stiffness, np.full_like(stiffness, 20.0)]).astype(np.float32)
    starts = steps_from(env, np.tile(qpos, (2, 1)).astype(np.float32), np.tile(qvel, (2, 1)).astype(np.float32),
                        np.tile(actions, (2, 1)), {"stiffness": both})

    def half(steps: Steps, part: int) -> Steps:
        return Steps(*(x[part * count:(part + 1) * count] for x in (steps.obs, steps.reward, steps.discount)))

    # dm_control is handed the actions themselves (`to_env_action` would clip them to our Box).
    ours = dataclasses.replace(starts, steps=half(starts.steps, 0), actions=actions, episode={"stiffness": stiffness},
                               **{k: getattr(starts, k)[:count] for k in ("qpos", "qvel", "act", "qacc_warmstart")})
    return env, ours, half(starts.steps, 1), dm_control_steps(env, ours), starts


def test_lqr_steps_match_dm_control(stepped):
    """One control step from each start state, the episode's stiffness in both: observation, reward and
    discount; the reward ranges from near 1 (at the goal) to far below 0 (large forces and states)."""
    env, ours, _, theirs, _ = stepped
    Comparison(ours.steps, theirs).assert_within(BOUNDS, RTOL)
    assert theirs.reward.max() > 0.999 and theirs.reward.min() < -1.0 and np.ptp(theirs.obs, axis=0).min() > 1.0


def test_lqr_termination_is_dm_controls(stepped):
    """A step that leaves the state's norm below 1e-6 ends the episode with discount 0 in both (the
    tiny states), one that leaves it above does not (the rest, the states just outside included)."""
    env, ours, _, theirs, _ = stepped
    terminal = np.arange(len(theirs.discount)) >= OWN + ANYWHERE
    terminal[OWN + ANYWHERE + TINY:] = False
    np.testing.assert_array_equal(theirs.discount, np.where(terminal, 0.0, 1.0))
    np.testing.assert_array_equal(ours.steps.discount, theirs.discount)
    after = np.linalg.norm(theirs.obs, axis=1)
    assert after[terminal].max() < TERMINAL_TOL <= after[~terminal].min()


def test_lqr_steps_fail_with_the_mjcfs_stiffness(stepped):
    """The same states stepped with the MJCF's stiffness (20 in every joint) in place of the episode's:
    the proof must fail (each episode's springs are part of the physics)."""
    env, _, ignored, theirs, _ = stepped
    comparison = Comparison(ignored, theirs)
    assert comparison.worst()["obs"] > 100 * BOUNDS["obs"]
    with pytest.raises(AssertionError, match="observation"):
        comparison.assert_within(BOUNDS, RTOL)


def test_lqr_reset_observation_is_dm_controls(stepped):
    """Each of the program's resets (its own stiffness handed to dm_control) is dm_control's
    observation of the same state."""
    env, _, _, _, starts = stepped
    theirs = dm_control_observations(env, starts.reset_qpos, starts.reset_qvel, starts.reset_episode)
    np.testing.assert_allclose(starts.reset_obs, theirs, atol=BOUNDS["obs"], rtol=RTOL)
