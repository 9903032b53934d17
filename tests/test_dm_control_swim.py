"""dm_control's swimming domains, fish (upright, swim) and swimmer (swimmer6, swimmer15), against
dm_control 1.0.50's own envs: the models (the swimmers built as dm_control's `_make_model(n)` builds
them; the one edit, collisions removed, is neutral), the specs, the observation and reward of
dm_control's own states (no physics compiled), the reset distributions with each episode's target
(the default run), and, in the slow run, single steps from dm_control's own states with each
episode's target handed to dm_control's physics, and the reset's observation.

Fish upright steps the same model as swim (only the target's colour differs, held to dm_control's):
its physics is proven by swim's steps and its observation and reward by its readings."""

from __future__ import annotations

import copy
import functools

import jax
import mujoco
import numpy as np
import pytest

import envs

pytest.importorskip("dm_control", reason="the DeepMind Control Suite tasks are proven against dm-control==1.0.50 "
                                         "(pip install 'mjxsuite[dmc]'; the test extra has it)")

from envs.interop.dm_control import (Comparison, assert_spec_is_dm_controls,  # noqa: E402
                                     compare_readings_with_dm_control, dm_control_observations,
                                     dm_control_reset_samples, dm_control_rollouts, dm_control_steps, load,
                                     steps_from)
from tests.test_dm_control import assert_same_distribution  # noqa: E402

TASKS = {"dmc-fish-upright": ("fish", "upright"), "dmc-fish-swim": ("fish", "swim"),
         "dmc-swimmer-swimmer6": ("swimmer", "swimmer6"), "dmc-swimmer-swimmer15": ("swimmer", "swimmer15")}
# The flag that makes zeroing contype/conaffinity neutral, per domain.
DISABLED = {"fish": mujoco.mjtDisableBit.mjDSBL_CONSTRAINT, "swimmer": mujoco.mjtDisableBit.mjDSBL_CONTACT}
# The target: its world geom (each episode's geom_pos) and, for the swimmer, its light.
TARGET = {"fish": ("target", None), "swimmer": ("target", "target_light")}
# float32 (ours) against float64 (dm_control), one control step: the observation's absolute bound
# (plus 1e-4 relative) and the reward's. Measured worst: see docs/tasks.md's proof table. Swimmer15's
# gyros carry float32's rounding through 15 Euler steps of a 17-dof chain in the fluid: a looser
# bound there (in x64 the same steps agree to float64 rounding, so it is not MJX's algorithm).
BOUNDS = {"dmc-fish-swim": {"obs": 1e-4, "reward": 1e-5}, "dmc-swimmer-swimmer6": {"obs": 1e-4, "reward": 1e-5},
          "dmc-swimmer-swimmer15": {"obs": 2e-3, "reward": 1e-5}}
COUNT = 64  # start states per task: one batch shape, one compiled program


def numeric_fields(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    """Every array and number of an MjModel, its options' included."""
    fields = {}
    for owner, prefix in ((model, ""), (model.opt, "opt.")):
        for name in dir(owner):
            value = getattr(owner, name, None) if not name.startswith("_") else None
            if isinstance(value, (np.ndarray, int, float)) and not isinstance(value, bool):
                fields[prefix + name] = np.asarray(value)
    return fields


def assert_models_equal(ours: mujoco.MjModel, theirs: mujoco.MjModel, skip: set[str], what: str) -> None:
    ours_fields, their_fields = numeric_fields(ours), numeric_fields(theirs)
    assert set(ours_fields) == set(their_fields) and len(ours_fields) > 500
    for name in sorted(set(their_fields) - skip):
        np.testing.assert_array_equal(ours_fields[name], their_fields[name], err_msg=f"{what}: {name}")
    assert ours.names == theirs.names, f"{what}: names"


@pytest.mark.parametrize("name", sorted(TASKS))
def test_swim_tasks_are_dm_controls(name):
    """Specs, and our model equal to the one dm_control's env steps in every number (the swimmer's
    segments, motors and sensors as `_make_model(n)` adds them; fish upright's hidden target) but the
    target's per-episode position (`state.info` here) and the geoms' contype and conaffinity: 0 here,
    where dm_control's model disables collisions by flag."""
    env, theirs = assert_spec_is_dm_controls(name)
    model, their_model = env.mj_model, theirs.physics.model.ptr
    geom, light = TARGET[env.domain]
    ours_model = copy.copy(model)
    ours_model.geom_pos[model.geom(geom).id] = their_model.geom_pos[their_model.geom(geom).id]
    if light is not None:
        ours_model.light_pos[model.light(light).id] = their_model.light_pos[their_model.light(light).id]
    assert_models_equal(ours_model, their_model, {"geom_contype", "geom_conaffinity"}, name)
    assert not model.geom_contype.any() and not model.geom_conaffinity.any()
    assert their_model.geom_contype.any() and their_model.opt.disableflags & int(DISABLED[env.domain])


@pytest.mark.parametrize("domain, task", [("fish", "swim"), ("swimmer", "swimmer6"), ("swimmer", "swimmer15")])
def test_removing_collisions_is_neutral_in_c_mujoco(domain, task):
    """dm_control's own model and the same with every contype and conaffinity 0 give bit-equal C
    MuJoCo trajectories (100 physics steps of random controls from a reset, set moving), and clearing
    the flag that makes it so is refused."""
    theirs = load(domain, task)
    theirs.reset()
    model = theirs.physics.model.ptr
    edited = copy.copy(model)
    edited.geom_contype[:] = 0
    edited.geom_conaffinity[:] = 0
    rng = np.random.default_rng(0)
    controls, qvel = rng.uniform(-1, 1, (100, model.nu)), rng.normal(0.0, 0.5, model.nv)
    runs = []
    for m in (model, edited):
        data = mujoco.MjData(m)
        data.qpos[:], data.qvel[:] = theirs.physics.data.qpos, qvel
        for ctrl in controls:
            data.ctrl[:] = ctrl
            mujoco.mj_step(m, data)
        runs.append(np.concatenate([data.qpos, data.qvel, data.qacc, data.sensordata]))
    assert np.abs(runs[0][:model.nq] - theirs.physics.data.qpos).max() > 1e-3, "the body must move"
    np.testing.assert_array_equal(runs[0], runs[1])
    name = next(n for n, pair in TASKS.items() if pair == (domain, task))
    with pytest.raises(ValueError, match=DISABLED[domain].name), pytest.warns(UserWarning):
        envs.make(name, opt={"disableflags": int(model.opt.disableflags) & ~int(DISABLED[domain])})


# The target's offset from the mouth or nose in a stirred state, per coordinate: the reward's margin
# (fish swim: 2 radii, 0.09; swimmer: 5 radii, 0.5), so the reward spans its range.
EFFECTOR, REACH = {"fish": "mouth", "swimmer": "nose"}, {"fish": 0.09, "swimmer": 0.5}
# A stirred state's velocities, N(0, SPEED) per dof: about the spread of dm_control's own random-action
# episodes (fish: the root's linear and angular velocity, then the hinges; swimmer: the two slides,
# rootz, then each hinge, however many). Twice the fish's makes dm_control's own physics unstable
# (mjWARN_BADQACC), and so does swimmer6's spread on swimmer15 (hinges limited to +-24 degrees, a
# 1.5 m chain in the fluid; random actions never reach such states): a tenth of it there.
SPEED = {"fish": ((0.02,) * 3 + (0.5,) * 3, 3.0), "swimmer": ((0.1, 0.1, 1.0), 1.5)}
SPEED_SCALE = {"swimmer15": 0.1}


def speed(domain: str, task: str, nv: int) -> np.ndarray:
    """SPEED's spread for each of a model's `nv` dofs: the root's, then the hinges'."""
    root, hinge = SPEED[domain]
    return SPEED_SCALE.get(task, 1.0) * np.array(root + (hinge,) * (nv - len(root)))


def stir(physics, rng, domain, task):
    """A state random actions rarely reach: the body turned and set moving, and the target (where the
    task has one) moved near the mouth or nose."""
    named = physics.named
    physics.data.qvel[:] = rng.normal(0.0, speed(domain, task, physics.model.nv))
    if domain == "fish":
        quat = rng.normal(size=4)
        named.data.qpos["root"][3:7] = quat / np.linalg.norm(quat)
    else:
        named.data.qpos["rootz"] = rng.uniform(-np.pi, np.pi)
    physics.forward()
    near = named.data.geom_xpos[EFFECTOR[domain]] + rng.uniform(-REACH[domain], REACH[domain], 3)
    axes = 3 if domain == "fish" else 2  # the swimmer's target keeps its height
    named.model.geom_pos["target", :axes] = near[:axes]


@pytest.mark.parametrize("name", sorted(TASKS))
def test_observation_and_reward_of_dm_controls_states(name):
    """Our observation and reward of dm_control's own physics after each of its steps (no physics runs
    here), stirred every third step: the joints, the uprightness, the target in the mouth's or head's
    frame, the swimmer's velocimeters and gyros in dm_control's order, and the reward."""
    perturb = functools.partial(stir, domain=TASKS[name][0], task=TASKS[name][1])
    comparison = compare_readings_with_dm_control(name, episodes=4, num_steps=12, perturb=perturb)
    comparison.assert_within({"obs": 1e-5, "reward": 1e-6}, rtol=1e-5)
    assert np.ptp(comparison.theirs.reward) > 0.5, "the reward must vary"


def their_targets(domain: str, task: str, count: int) -> np.ndarray:
    theirs = load(domain, task, seed=2)
    found = []
    for _ in range(count):
        theirs.reset()
        found.append(theirs.physics.named.model.geom_pos["target"].copy())
    return np.array(found)


@pytest.mark.parametrize("name", ["dmc-fish-swim", "dmc-swimmer-swimmer6", "dmc-swimmer-swimmer15"])
def test_reset_distribution_matches_dm_control(name):
    """2,000 draws of each: the joints, the root's orientation (fish: uniform on the sphere) and the
    episode's target in distribution (the swimmer's: the share within its close box too), at rest.
    Fish upright draws its joints as swim does (the same `initial_qpos_qvel`)."""
    env = envs.make(name).unwrapped
    keys = jax.random.split(jax.random.PRNGKey(3), 2000)
    # float64 here: a float32 mean of 2,000 equal values is off by more than the constant coordinates' 1e-6.
    qpos, qvel = (np.asarray(x, np.float64) for x in jax.jit(jax.vmap(env.initial_qpos_qvel))(keys))
    target = np.asarray(jax.jit(jax.vmap(lambda k: env.draw_episode(k)[1]["target"]))(keys))
    their_qpos, their_qvel, _ = dm_control_reset_samples(*TASKS[name], 2000)
    assert_same_distribution(qpos, their_qpos, f"{name} qpos")
    assert not qvel.any() and not their_qvel.any()
    drawn = their_qpos.std(0) > 1e-9  # numpy's std of 2,000 equal values is not always 0
    assert np.array_equal(qpos.std(0) > 1e-9, drawn), "the positions dm_control draws, and only those"
    theirs = their_targets(*TASKS[name], 2000)[:, :target.shape[1]]
    assert_same_distribution(target, theirs, f"{name} target")
    if env.domain == "swimmer":
        close = [np.mean(np.abs(t).max(axis=1) <= 0.3) for t in (target, theirs)]
        # P = 0.2 + 0.8 * 0.15^2 = 0.218; 5 standard errors of the difference of two shares of 2,000.
        assert abs(close[0] - close[1]) < 5 * np.sqrt(2 * 0.218 * 0.782 / 2000), close


# ---- single steps (slow: one compiled program per domain) -------------------------------------------
def start_states(env, rng):
    """`COUNT` of dm_control's own states along random-action episodes from its resets, with their
    episodes' targets; every other one with its target moved near the mouth or nose (the reward's
    range), every fourth set moving at N(0, SPEED) (the fluid's forces grow with speed)."""
    rollouts = dm_control_rollouts(env, episodes=4, num_steps=100)
    chosen = np.linspace(0, len(rollouts.qpos) - 1, COUNT).round().astype(int)
    qpos, qvel = rollouts.qpos[chosen].copy(), rollouts.qvel[chosen].copy()
    target = rollouts.episode["target"][chosen].copy()
    qvel[1::4] = rng.normal(0.0, speed(env.domain, env.task, env.mj_model.nv), qvel[1::4].shape)
    data, effector = mujoco.MjData(env.mj_model), env.mj_model.geom(EFFECTOR[env.domain]).id
    for index in range(0, COUNT, 2):
        data.qpos[:] = qpos[index]
        mujoco.mj_kinematics(env.mj_model, data)
        near = data.geom_xpos[effector] + rng.uniform(-REACH[env.domain], REACH[env.domain], 3)
        target[index] = near[:target.shape[1]]
    actions = rng.uniform(-1.0, 1.0, (COUNT, env.action_size))
    return qpos.astype(np.float32), qvel.astype(np.float32), actions, {"target": target.astype(np.float32)}


# swimmer15's program, the largest of the three to compile, is proven in the heavy run, out of CI's time.
@pytest.fixture(scope="module", params=[pytest.param(name, marks=pytest.mark.heavy if name == "dmc-swimmer-swimmer15"
                                                     else pytest.mark.slow)
                                        for name in BOUNDS])
def swim_case(request):
    env = envs.make(request.param).unwrapped
    starts = steps_from(env, *start_states(env, np.random.default_rng(0)))
    return request.param, env, starts, dm_control_steps(env, starts)


def test_steps_match_dm_control(swim_case):
    """One control step (10 or 15 physics steps in the fluid) from each state, the episode's target
    handed to dm_control's physics (`put_episode`)."""
    name, env, starts, theirs = swim_case
    comparison = Comparison(starts.steps, theirs)
    comparison.assert_within(BOUNDS[name])
    assert np.all(theirs.discount == 1.0) and np.all(starts.steps.discount == 1.0)
    assert np.ptp(theirs.reward) > 0.5, "the reward must vary"
    assert np.ptp(theirs.obs, axis=0).min() > 0, "every observation element must vary over the states"


def test_reset_observation_is_dm_controls(swim_case):
    """Our resets (the same program's) are dm_control's observation of the same state and target."""
    name, env, starts, _ = swim_case
    theirs = dm_control_observations(env, starts.reset_qpos, starts.reset_qvel, starts.reset_episode)
    np.testing.assert_allclose(starts.reset_obs, theirs, atol=1e-5, rtol=1e-4)


def test_the_swimmers_target_light_moves_with_its_target_in_warps_data():
    """dm_control moves swimmer's `target_light` over each episode's target (`put_episode`): with
    MuJoCo Warp's data (its renderer lights the pictures from `_impl.light_xpos`, stood in for here
    by a pytree of that one field) `with_episode` moves the light too; the other light, its height
    and JAX's data (no lights) are left as they are."""
    from flax import struct

    @struct.dataclass
    class WarpLights:
        light_xpos: jax.Array

    task = envs.make("dmc-swimmer-swimmer6").unwrapped
    model = task.mj_model
    lights = np.asarray(model.light_pos, np.float32)
    data = task.reset_data.replace(_impl=WarpLights(light_xpos=jax.numpy.asarray(lights)))
    target = np.array([0.25, -0.1], np.float32)
    moved = np.asarray(task.with_episode(data, {"target": target})._impl.light_xpos)
    light = model.light("target_light").id
    np.testing.assert_array_equal(moved[light], [*target, lights[light, 2]])
    np.testing.assert_array_equal(np.delete(moved, light, 0), np.delete(lights, light, 0))
    plain = task.with_episode(task.reset_data, {"target": target})  # JAX's data: only the sensor moves
    assert not hasattr(plain._impl, "light_xpos")
