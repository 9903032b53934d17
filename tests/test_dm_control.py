"""The DeepMind Control Suite's tasks (dmc-*) against dm_control 1.0.50's own envs (C MuJoCo, float64):
single steps from shared states, the observation of shared reset states, reset distributions, the
tasks' specs, and `tolerance` against dm_control's `rewards.tolerance`."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs

pytest.importorskip("dm_control", reason="the DeepMind Control Suite tasks are proven against dm-control==1.0.50 "
                                         "(pip install 'mjxsuite[dmc]'; the test extra has it)")

from envs.interop.dm_control import (MUJOCO_4_DROPPED, Comparison, assert_resets_touch_nothing,  # noqa: E402
                                     assert_spec_is_dm_controls, compare_readings_with_dm_control,
                                     compare_with_dm_control,
                                     Steps, dm_control_observations, dm_control_reset_samples, dm_control_rollouts,
                                     dm_control_steps, load, shim_mujoco_4, steps_from, transitions)
from envs.tasks.dm_control_suite import tolerance  # noqa: E402

# Slow run: dm_control's step and reset proofs (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

# Every dmc task: (domain, task) of dm_control.
TASKS = {
    "dmc-ball-in-cup-catch": ("ball_in_cup", "catch"), "dmc-acrobot-swingup": ("acrobot", "swingup"), "dmc-acrobot-swingup-sparse": ("acrobot", "swingup_sparse"),
    "dmc-cartpole-balance": ("cartpole", "balance"), "dmc-cartpole-balance-sparse": ("cartpole", "balance_sparse"),
    "dmc-cartpole-swingup": ("cartpole", "swingup"), "dmc-cartpole-swingup-sparse": ("cartpole", "swingup_sparse"),
    "dmc-cartpole-two-poles": ("cartpole", "two_poles"), "dmc-cartpole-three-poles": ("cartpole", "three_poles"),
    "dmc-cheetah-run": ("cheetah", "run"), "dmc-hopper-hop": ("hopper", "hop"), "dmc-hopper-stand": ("hopper", "stand"),
    "dmc-pendulum-swingup": ("pendulum", "swingup"),
    "dmc-point-mass-easy": ("point_mass", "easy"), "dmc-point-mass-hard": ("point_mass", "hard"),
    "dmc-reacher-easy": ("reacher", "easy"),
    "dmc-reacher-hard": ("reacher", "hard"), "dmc-walker-stand": ("walker", "stand"),
    "dmc-walker-walk": ("walker", "walk"), "dmc-walker-run": ("walker", "run"),
}
# Tasks proven in files of their own (tests/test_dm_control_<domain>.py: heavier compiles, other state sources).
PROVEN_ELSEWHERE = ("dmc-finger-spin", "dmc-finger-turn-easy", "dmc-finger-turn-hard", "dmc-quadruped-walk",
                    "dmc-quadruped-run", "dmc-quadruped-fetch", "dmc-humanoid-stand", "dmc-humanoid-walk",
                    "dmc-humanoid-run", "dmc-humanoid-run-pure-state", "dmc-fish-upright", "dmc-fish-swim",
                    "dmc-swimmer-swimmer6", "dmc-swimmer-swimmer15", "dmc-manipulator-bring-ball",
                    "dmc-manipulator-bring-peg", "dmc-manipulator-insert-ball", "dmc-lqr-lqr-2-1", "dmc-lqr-lqr-6-2")
# One task per domain in the fast suite (one compile each); the others share its physics and differ
# in reward and reset (the reset distributions of all are in the fast suite, their steps in the slow).
FAST = ("dmc-acrobot-swingup", "dmc-ball-in-cup-catch", "dmc-cartpole-swingup", "dmc-cheetah-run", "dmc-hopper-hop", "dmc-pendulum-swingup",
        "dmc-point-mass-easy", "dmc-reacher-easy", "dmc-walker-walk")
# float32 (ours) against float64 (dm_control), one control step: the observation's absolute bound
# (plus 1e-4 relative) and the reward's. Contacts (cheetah, walker) and walker's 10 substeps make
# the velocities' rounding larger.
BOUNDS = {"acrobot": (1e-5, 1e-5), "cartpole": (1e-5, 1e-5), "pendulum": (1e-5, 1e-5),
          "point_mass": (1e-5, 1e-5), "cheetah": (1e-3, 1e-5), "walker": (2e-3, 1e-5), "hopper": (1e-3, 1e-5), "reacher": (1e-5, 1e-5),
          "ball_in_cup": (1e-3, 1e-5)}
# States near each task's goal, where random rollouts from resets rarely go (the cheetah is slow, the
# hopper lies down, the sparse rewards stay 0 or 1, the point mass misses its target): qpos0 plus
# U(-spread, spread) (cartpole's cart: +-0.3, around the sparse reward's +-0.25), velocities
# N(0, velocity), rootx's U(0, 1.5 x the task's speed).
NEAR_GOAL = {"dmc-cheetah-run": (0.1, 1.0, 10.0), "dmc-hopper-hop": (0.1, 1.0, 2.0), "dmc-hopper-stand": (0.1, 1.0, 0.0),
             "dmc-cartpole-balance-sparse": (0.15, 0.5, 0.0), "dmc-cartpole-swingup-sparse": (0.15, 0.5, 0.0),
             "dmc-acrobot-swingup-sparse": (0.3, 0.5, 0.0), "dmc-point-mass-easy": (0.03, 0.05, 0.0)}
FAST_NEAR_GOAL = ("dmc-point-mass-easy",)


def bounds(name):
    obs, reward = BOUNDS[TASKS[name][0]]
    return {"obs": obs, "reward": reward}


# The contact domains and reacher compile longer (tens of seconds each on two cores): their single
# steps and reset observations run in the slow run, the light domains' in the default one.
HEAVY = ("dmc-ball-in-cup-catch", "dmc-cheetah-run", "dmc-hopper-hop", "dmc-reacher-easy", "dmc-walker-walk")


@pytest.fixture(scope="module", params=[pytest.param(n, marks=pytest.mark.slow) if n in HEAVY else n for n in FAST])
def fast_case(request):
    name = request.param
    env = envs.make(name).unwrapped
    starts = transitions(env)
    return name, env, starts, dm_control_steps(env, starts)


def test_steps_match_dm_control(fast_case):
    name, env, starts, theirs = fast_case
    comparison = Comparison(starts.steps, theirs)
    comparison.assert_within(bounds(name))
    assert np.all(theirs.discount == 1.0) and np.all(starts.steps.discount == 1.0)
    assert np.ptp(theirs.reward) > 0 or name in NEAR_GOAL, "the rewards must vary over the states"
    assert np.ptp(theirs.obs, axis=0).min() > 0, "every observation element must vary over the states"


def test_reset_observation_is_dm_controls(fast_case):
    name, env, starts, _ = fast_case
    theirs = dm_control_observations(env, starts.reset_qpos, starts.reset_qvel, starts.reset_episode)
    np.testing.assert_allclose(starts.reset_obs, theirs, atol=bounds(name)["obs"], rtol=1e-4)


def test_a_stale_observation_fails_the_proof():
    """Without dm_control's legacy step (kinematics refreshed after the step) the pendulum's
    observation is one physics step old: the proof must catch it."""
    from envs.tasks.dmc_pendulum import DmcPendulumSwingUp

    class Stale(DmcPendulumSwingUp):
        def refresh(self, model, data):
            return data

    comparison = compare_with_dm_control(Stale(), num_envs=4, num_steps=10, keep=40)
    assert comparison.worst()["obs"] > 1e-3
    with pytest.raises(AssertionError, match="observation"):
        comparison.assert_within({"obs": 1e-5, "reward": 1e-5})


@pytest.mark.slow
@pytest.mark.parametrize("name", ["dmc-reacher-hard", "dmc-walker-run", "dmc-walker-stand"])
def test_steps_match_dm_control_other_tasks(name):
    """The fast tasks' siblings with a reward of their own; the sparse ones and hopper stand are
    proven near their goals, where their rewards are not constant, and cartpole balance is swingup's
    program with another reset (its distribution is tested)."""
    comparison = compare_with_dm_control(name)
    comparison.assert_within(bounds(name))
    assert name in NEAR_GOAL or name == "dmc-reacher-hard" or np.ptp(comparison.theirs.reward) > 0


def states_near_the_goal(name: str, count: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`count` states of `NEAR_GOAL[name]`'s kind, with random actions."""
    env = envs.make(name).unwrapped
    spread, velocity, speed = NEAR_GOAL[name]
    rng = np.random.default_rng(0)
    qpos = env.mj_model.qpos0 + rng.uniform(-spread, spread, (count, env.mj_model.nq))
    if env.domain == "cartpole":
        qpos[:, 0] = rng.uniform(-0.3, 0.3, count)
    qvel = velocity * rng.normal(size=(count, env.mj_model.nv))
    if speed:
        qvel[:, 0] = rng.uniform(0, 1.5 * speed, count)
    return qpos.astype(np.float32), qvel.astype(np.float32), rng.uniform(-1, 1, (count, env.action_size))


@pytest.mark.parametrize("name", [pytest.param(n, marks=[] if n in FAST_NEAR_GOAL else pytest.mark.slow)
                                  for n in NEAR_GOAL])
def test_steps_near_the_goal_match_dm_control(name):
    env = envs.make(name).unwrapped
    starts = steps_from(env, *states_near_the_goal(name))
    theirs = dm_control_steps(env, starts)
    Comparison(starts.steps, theirs).assert_within(bounds(name))
    assert 0.1 < (theirs.reward > 0.01).mean() and np.ptp(theirs.reward) > 0.1, "the reward must be exercised"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["dmc-walker-walk", "dmc-acrobot-swingup"])
def test_steps_match_dm_control_in_x64(name):
    """Under x64 the float32 rounding goes: what is left is MJX's algorithm against C MuJoCo's. The
    task's physics is one jitted function whose trace JAX keeps per shape: an earlier float32 trace
    of this process must not serve the x64 step, nor the x64 one a later float32 step."""
    jax.clear_caches()
    try:
        with jax.enable_x64(True):
            comparison = compare_with_dm_control(envs.make(name), num_envs=4, num_steps=10, keep=40)
    finally:
        jax.clear_caches()
    comparison.assert_within({"obs": 1e-8, "reward": 1e-9}, rtol=1e-8)


@pytest.mark.slow
def test_reacher_steps_on_the_target_match_dm_control():
    """Reacher hard's 0-or-1 reward, from states whose target lies within 0.03 of the fingertip."""
    env = envs.make("dmc-reacher-hard").unwrapped
    rng = np.random.default_rng(0)
    qpos = rng.uniform(-np.pi, np.pi, (64, 2)) * [1.0, 0.8]
    data = mujoco.MjData(env.mj_model)
    fingers = []
    for q in qpos:
        data.qpos[:] = q
        mujoco.mj_kinematics(env.mj_model, data)
        fingers.append(data.geom_xpos[env.mj_model.geom("finger").id, :2].copy())
    target = np.array(fingers) + rng.uniform(-0.03, 0.03, (64, 2))
    starts = steps_from(env, qpos.astype(np.float32), rng.normal(0, 0.5, (64, 2)).astype(np.float32),
                        rng.uniform(-1, 1, (64, 2)), {"target": target.astype(np.float32)})
    theirs = dm_control_steps(env, starts)
    Comparison(starts.steps, theirs).assert_within(bounds("dmc-reacher-hard"))
    assert 0.1 < theirs.reward.mean() < 0.9, "both rewards reached"


# ---- point_mass hard (dm_control's EXTRA task: the tendons' coefficients drawn per episode) -------------
IDENTITY = np.array([1.0, 0.0, 0.0, 1.0], np.float32)  # the MJCF's wrap_prm: easy's tendons


def test_point_mass_hard_steps_match_dm_control():
    """One step from dm_control's own states (4 episodes of its random actions) and from 64 states near
    the target, each with its episode's `wrap_prm` (dm_control's draws) copied in; the same states with
    the MJCF's coefficients in ours (the episode's ignored) must fail the proof. Also each reset's
    observation, and the coefficients' draw against dm_control's."""
    env = envs.make("dmc-point-mass-hard").unwrapped
    theirs = dm_control_rollouts(env, episodes=4, num_steps=40)
    qpos, qvel, actions = states_near_the_goal("dmc-point-mass-easy")
    prm = theirs.episode["wrap_prm"]
    qpos, qvel = np.concatenate([theirs.qpos, qpos]).astype(np.float32), np.concatenate([theirs.qvel, qvel]).astype(np.float32)
    actions, prm = np.concatenate([theirs.actions, actions]), np.concatenate([prm, prm[::-1][:64]]).astype(np.float32)
    # One compile: each state twice, with its coefficients and with the MJCF's.
    starts = steps_from(env, np.tile(qpos, (2, 1)), np.tile(qvel, (2, 1)), np.tile(actions, (2, 1)),
                        {"wrap_prm": np.concatenate([prm, np.tile(IDENTITY, (len(prm), 1))])})
    count = len(prm)
    half = lambda steps, part: Steps(*(x[part * count:(part + 1) * count] for x in (steps.obs, steps.reward, steps.discount)))
    ours = dataclasses.replace(starts, steps=half(starts.steps, 0), episode={"wrap_prm": prm},
                               **{k: getattr(starts, k)[:count] for k in ("qpos", "qvel", "act", "qacc_warmstart",
                                                                          "actions")})
    their_steps = dm_control_steps(env, ours)
    Comparison(ours.steps, their_steps).assert_within(bounds("dmc-point-mass-hard"))
    assert np.ptp(their_steps.reward) > 0.1 and np.ptp(their_steps.obs, axis=0).min() > 0, "reward and obs must vary"
    ignored = Comparison(half(starts.steps, 1), their_steps)
    assert ignored.worst()["obs"] > 100 * bounds("dmc-point-mass-hard")["obs"]
    with pytest.raises(AssertionError, match="observation"):
        ignored.assert_within(bounds("dmc-point-mass-hard"))
    their_resets = dm_control_observations(env, starts.reset_qpos, starts.reset_qvel, starts.reset_episode)
    np.testing.assert_allclose(starts.reset_obs, their_resets, atol=bounds("dmc-point-mass-hard")["obs"], rtol=1e-4)
    # The reset's coefficients: two unit vectors, never nearly parallel, drawn as dm_control draws them.
    keys = jax.random.split(jax.random.PRNGKey(4), 2000)
    drawn = np.asarray(jax.jit(jax.vmap(lambda key: env.draw_episode(key)[1]["wrap_prm"]))(keys), np.float64)
    dm = load("point_mass", "hard")
    their_prm = []
    for _ in range(2000):
        dm.reset()
        their_prm.append(dm.physics.model.wrap_prm.copy())
    their_prm = np.array(their_prm)
    with_dot = lambda p: np.column_stack([p, np.abs((p[:, :2] * p[:, 2:]).sum(1))])
    assert_same_distribution(with_dot(drawn), with_dot(their_prm), "wrap_prm, |dir1 . dir2|")
    for p in (drawn, their_prm):
        np.testing.assert_allclose(np.linalg.norm(p.reshape(-1, 2, 2), axis=2), 1.0, atol=1e-6)
        assert with_dot(p)[:, 4].max() <= 0.9 and with_dot(p)[:, 4].min() < 0.01


# ---- cartpole's chains of poles (dm_control's EXTRA two_poles, three_poles) ---------------------------
POLES = ("dmc-cartpole-two-poles", "dmc-cartpole-three-poles")


@pytest.mark.parametrize("name", POLES)
def test_pole_chain_models_are_dm_controls(name):
    """Our `cartpole_spec(n)` compiles to the model dm_control's `_make_model(n)` XML gives, in every
    number and name (the chain, the floor and cameras moved), but the `energy` flag we clear."""
    from tests.test_dm_control_swim import assert_models_equal

    env, theirs = assert_spec_is_dm_controls(name)
    their_model = theirs.physics.model.ptr
    assert_models_equal(env.mj_model, their_model, {"opt.enableflags"}, name)
    assert their_model.opt.enableflags == int(mujoco.mjtEnableBit.mjENBL_ENERGY) and env.mj_model.opt.enableflags == 0
    assert env.mj_model.nbody == 2 + env.n_poles


def stir_poles(physics, rng):
    """The poles anywhere around their hinges, spinning (random actions from a swing-up reset leave
    them hanging: every upright value, the sparse thresholds' neighbourhood included, is reached)."""
    physics.data.qpos[1:] = rng.uniform(-np.pi, np.pi, physics.model.nq - 1)
    physics.data.qvel[:] = rng.normal(0.0, 3.0, physics.model.nv)


@pytest.mark.parametrize("name", POLES)
def test_pole_chain_readings_of_dm_controls_states(name):
    """Each pole's world zz and xz in dm_control's order, the poles' mean uprightness and the slowest
    hinge's velocity term in the reward, read from dm_control's own states (no physics compiled)."""
    comparison = compare_readings_with_dm_control(name, perturb=stir_poles)
    comparison.assert_within(bounds(name))
    assert np.ptp(comparison.theirs.reward) > 0.3, "the reward must vary"
    assert np.ptp(comparison.theirs.obs, axis=0).min() > 0.5, "every observation element must vary"


@pytest.mark.parametrize("name", [pytest.param("dmc-cartpole-three-poles", marks=pytest.mark.slow),
                                  pytest.param("dmc-cartpole-two-poles", marks=pytest.mark.heavy)])
def test_pole_chain_steps_match_dm_control(name):
    """One control step from 64 states anywhere on the rail, the hinges at any angle, spinning at
    N(0, 2) rad/s (the whole chain's dynamics, not only the hanging rest that random actions from
    resets stay near), and each reset's observation. Two poles' physics is three's code on a chain
    one pole shorter (its model proven equal above): its steps run in the heavy run."""
    env = envs.make(name).unwrapped
    rng = np.random.default_rng(0)
    qpos = rng.uniform(-np.pi, np.pi, (64, env.mj_model.nq))
    qpos[:, 0] = rng.uniform(-1.7, 1.7, 64)
    qvel = rng.normal(0.0, 2.0, (64, env.mj_model.nv))
    starts = steps_from(env, qpos.astype(np.float32), qvel.astype(np.float32), rng.uniform(-1, 1, (64, 1)))
    theirs = dm_control_steps(env, starts)
    Comparison(starts.steps, theirs).assert_within(bounds(name))
    assert np.all(theirs.discount == 1.0) and np.all(starts.steps.discount == 1.0)
    assert np.ptp(theirs.reward) > 0.3 and np.ptp(theirs.obs, axis=0).min() > 0.5, "reward and observation must vary"
    their_resets = dm_control_observations(env, starts.reset_qpos, starts.reset_qvel, starts.reset_episode)
    np.testing.assert_allclose(starts.reset_obs, their_resets, atol=bounds(name)["obs"], rtol=1e-4)


# ---- resets ----------------------------------------------------------------------------------------
def assert_same_distribution(ours: np.ndarray, theirs: np.ndarray, what: str) -> None:
    """Per coordinate, the means and the variances within 5 standard errors of their differences
    (each variance's standard error from the sample's fourth moment, so uniform and normal draws are
    judged alike); a coordinate constant on one side must be the same constant on the other."""
    def variance_error(x):
        centred = x - x.mean(0)
        return np.sqrt(np.maximum((centred ** 4).mean(0) - x.var(0) ** 2, 0) / len(x))

    mean_error = np.sqrt(ours.var(0) / len(ours) + theirs.var(0) / len(theirs))
    np.testing.assert_array_less(np.abs(ours.mean(0) - theirs.mean(0)), 5 * mean_error + 1e-6, err_msg=f"{what}: mean")
    spread_error = np.sqrt(variance_error(ours) ** 2 + variance_error(theirs) ** 2)
    np.testing.assert_array_less(np.abs(ours.var(0) - theirs.var(0)), 5 * spread_error + 1e-9,
                                 err_msg=f"{what}: variance")


def our_reset_draws(name: str, count: int) -> tuple[np.ndarray, np.ndarray]:
    """`count` draws of the task's reset state (its `initial_qpos_qvel`, jitted and vmapped)."""
    env = envs.make(name).unwrapped
    keys = jax.random.split(jax.random.PRNGKey(3), count)
    return tuple(np.asarray(x) for x in jax.jit(jax.vmap(env.initial_qpos_qvel))(keys))


@pytest.mark.parametrize("name", sorted(set(TASKS) - {"dmc-cheetah-run"}))
def test_reset_distribution_matches_dm_control(name):
    qpos, qvel = our_reset_draws(name, 2000)
    their_qpos, their_qvel, _ = dm_control_reset_samples(*TASKS[name], 2000)
    assert_same_distribution(qpos, their_qpos, f"{name} qpos")
    assert_same_distribution(qvel, their_qvel, f"{name} qvel")
    drawn = their_qpos.std(0) > 0
    assert drawn.any() and np.array_equal(qpos.std(0) > 0, drawn), "the positions dm_control draws, and only those"


def test_ball_in_cup_resets_touch_nothing():
    """dm_control draws the ball again until nothing touches (`ncon == 0`): C MuJoCo finds no contact
    at any of our reset states, though more than a tenth of the raw draws touch."""
    env = envs.make("dmc-ball-in-cup-catch").unwrapped
    qpos, _ = our_reset_draws("dmc-ball-in-cup-catch", 500)
    raw = jax.jit(jax.vmap(env._draw))(jax.random.split(jax.random.PRNGKey(0), 200))
    assert_resets_touch_nothing(env, qpos, np.asarray(raw), raw_touching=0.1)


def test_reacher_target_distribution_matches_dm_control():
    """Reacher's per-episode target (dm_control: `geom_pos` of the target, here `info["target"]`)."""
    env = envs.make("dmc-reacher-easy").unwrapped
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(5), 2000))
    ours = np.asarray(states.info["target"])
    theirs = load("reacher", "easy")
    their_targets = []
    for _ in range(2000):
        theirs.reset()
        their_targets.append(theirs.physics.named.model.geom_pos["target", :2].copy())
    assert_same_distribution(ours, np.array(their_targets), "target")
    radius = np.linalg.norm(ours, axis=1)
    assert radius.min() >= 0.05 - 1e-6 and radius.max() <= 0.2 + 1e-6 and np.ptp(radius) > 0.14


@pytest.mark.slow  # a compile of its own (the wrappers' reset and step)
def test_reacher_target_moves_with_each_episode_under_auto_reset():
    """The target lives in `state.info`: auto-reset draws a new one, it stays through an episode,
    and the observation's to_target is measured from it."""
    env = envs.wrap_for_training(envs.make("dmc-reacher-easy", episode_length=5), 4)
    state, step = jax.jit(env.reset)(jax.random.PRNGKey(0)), jax.jit(env.step)
    targets, seen = [], []
    for _ in range(12):
        state = step(state, jnp.full((4, 2), 0.5))
        finger = np.asarray(state.pipeline_state.geom_xpos[:, env.unwrapped.mj_model.geom("finger").id, :2])
        targets.append(np.asarray(state.info["target"])), seen.append(np.asarray(state.obs[:, 2:4]) + finger)
    targets = np.array(targets)
    np.testing.assert_allclose(np.array(seen), targets, atol=1e-6)
    changed = np.abs(np.diff(targets, axis=0)).max(axis=(1, 2)) > 0
    np.testing.assert_array_equal(changed, [(i + 1) % 5 == 4 for i in range(11)])


@pytest.mark.slow
def test_cheetah_reset_distribution_matches_dm_control():
    """Cheetah settles for 200 physics steps at reset: after them, the same distribution."""
    qpos, qvel = our_reset_draws("dmc-cheetah-run", 128)
    their_qpos, their_qvel, _ = dm_control_reset_samples("cheetah", "run", 128)
    assert_same_distribution(qpos, their_qpos, "qpos")
    assert_same_distribution(qvel, their_qvel, "qvel")


@pytest.mark.slow
def test_cheetahs_capped_settle_leaves_the_settled_states(monkeypatch):
    """The settling steps' line search capped at `SETTLE_LS_ITERATIONS` settles as MuJoCo's 50
    iterations do: most draws bit for bit, every one within 2e-5 (float32 and dm_control's float64
    settle differ by about 1e-5)."""
    from envs.tasks import dmc_cheetah

    env = envs.make("dmc-cheetah-run").unwrapped
    assert env.settle_model.opt.ls_iterations == dmc_cheetah.SETTLE_LS_ITERATIONS < env.reset_model.opt.ls_iterations
    keys = jax.random.split(jax.random.PRNGKey(11), 64)
    capped = np.concatenate(jax.jit(jax.vmap(env.initial_qpos_qvel))(keys), axis=1)
    monkeypatch.setattr(dmc_cheetah, "SETTLE_LS_ITERATIONS", env.reset_model.opt.ls_iterations)
    uncapped = np.concatenate(jax.jit(jax.vmap(env.initial_qpos_qvel))(keys), axis=1)
    differ = np.abs(capped - uncapped).max(axis=1)
    assert differ.max() <= 2e-5 and (differ == 0).mean() >= 0.9, differ


# ---- what the tasks are ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(TASKS))
def test_task_is_dm_controls(name):
    """Action bounds, control timestep, episode length and observation layout equal dm_control's."""
    assert_spec_is_dm_controls(name)


def test_names_and_gymnasium_ids():
    from envs.interop.gymnasium_ids import IDS

    assert sorted(name for name in envs.names() if name.startswith("dmc-")) == sorted({*TASKS, *PROVEN_ELSEWHERE})
    assert all(IDS[f"{name}-v0"] == (name, 1000) for name in {*TASKS, *PROVEN_ELSEWHERE})


# ---- tolerance, the shim ---------------------------------------------------------------------------------
SIGMOIDS = ("gaussian", "hyperbolic", "long_tail", "reciprocal", "cosine", "linear", "quadratic", "tanh_squared")


@pytest.mark.parametrize("sigmoid", SIGMOIDS)
def test_tolerance_is_dm_controls(sigmoid):
    from dm_control.utils import rewards

    x = np.linspace(-6, 6, 2401)
    cases = [((0.0, 0.0), 1.0, 0.1), ((-1.0, 2.0), 2.0, 0.3), ((1.2, np.inf), 0.6, 0.5), ((-np.inf, 0.5), 3.0, 0.01)]
    with jax.enable_x64(True):
        for bounds_, margin, value in cases:
            ours = np.asarray(tolerance(jnp.asarray(x), bounds_, margin, sigmoid, value))
            np.testing.assert_allclose(ours, rewards.tolerance(x, bounds_, margin, sigmoid, value), atol=1e-14,
                                       err_msg=str((bounds_, margin, value)))
    ours32 = np.asarray(tolerance(jnp.asarray(x, jnp.float32), (-1.0, 2.0), 2.0, sigmoid, 0.3))
    assert ours32.dtype == np.float32
    np.testing.assert_allclose(ours32, rewards.tolerance(x, (-1.0, 2.0), 2.0, sigmoid, 0.3), atol=1e-6)


def test_tolerance_margin_zero_and_refusals():
    from dm_control.utils import rewards

    x = np.array([-0.3, -0.25, 0.0, 0.25, 0.26])
    np.testing.assert_array_equal(np.asarray(tolerance(jnp.asarray(x), (-0.25, 0.25))), rewards.tolerance(x, (-0.25, 0.25)))
    for bad in (dict(bounds=(1.0, 0.0)), dict(margin=-1.0)):
        with pytest.raises(ValueError):
            tolerance(jnp.asarray(x), **{"bounds": (0.0, 0.0), "margin": 1.0, **bad})
    for sigmoid, value in (("gaussian", 0.0), ("linear", 1.0), ("cubic", 0.1)):
        with pytest.raises(ValueError):
            tolerance(jnp.asarray(x), margin=1.0, sigmoid=sigmoid, value_at_margin=value)
        with pytest.raises(ValueError):
            rewards.tolerance(x, margin=1.0, sigmoid=sigmoid, value_at_margin=value)


def test_the_shim_removes_exactly_mujoco_4s_dropped_fields():
    from dm_control.mujoco.wrapper.mjbindings import sizes

    shim_mujoco_4()
    shim_mujoco_4()  # idempotent
    for struct, cls in (("mjmodel", mujoco.MjModel), ("mjdata", mujoco.MjData)):
        assert all(hasattr(cls, name) for name in sizes.array_sizes[struct])
        if mujoco.__version__.startswith("4."):
            assert not any(hasattr(cls, name) for name in MUJOCO_4_DROPPED[struct])
            assert not MUJOCO_4_DROPPED[struct] & set(sizes.array_sizes[struct])
