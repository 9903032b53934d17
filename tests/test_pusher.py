"""pusher against Gymnasium's Pusher-v5 (C MuJoCo, float64) from the same states.

Under random actions the arm almost never reaches the object (no finger touched it in 3,000
random steps of Gymnasium's own env; the object's cylinder always rests on the table, three
contacts whose normal is along z, where the object has no joint). So the step is compared twice:
from states reached under random actions (the arm alone, now and then a finger on the table), and
from the same arm states with the object put against a finger that moves into it, where the
contact pushes the object."""

import jax
import mujoco
import numpy as np
import pytest

import envs
from gymnasium_mujoco import (Steps, Transitions, assert_resets_match, assert_same_options,
                              assert_steps_match, exact_noise_bounds, gymnasium_env, gymnasium_reset_samples,
                              gymnasium_steps, lockstep, reset_samples, select, transitions)

NAME, GYMNASIUM_ID = "pusher", "Pusher-v5"
ARM, OBJECT, GOAL = slice(0, 7), slice(7, 9), slice(9, 11)  # qpos / qvel: the arm, the object's and the goal's slides
OBJECT_XPOS = slice(17, 20)  # the observation's object position
# float32 (ours) against float64 (Gymnasium); the object rests on the table (measured over 3,200
# random-action states, 0.2% with a finger on the table: arm angles 5.5e-7, joint velocities
# 1.4e-5 of up to 8 rad/s, body positions 2.3e-7, reward 3.5e-7).
TOLERANCE = {"obs": 1e-4, "reward": 2e-5}


@pytest.fixture(scope="module")
def starts():
    # Every step of 32 episodes of Pusher's 100 steps: the pool the pushing states are built from.
    return transitions(NAME, num_envs=32, num_steps=100, keep=3200)


@pytest.mark.heavy  # compiles pusher's contact step (~40 s on 2 cores)
def test_steps_match_gymnasium(starts):
    theirs = gymnasium_steps(GYMNASIUM_ID, starts)
    assert np.abs(theirs.obs[:, 7:14]).max() > 5, "the arm must move fast"
    assert (theirs.contacts > 3).any(), "a finger must touch the table in some states"
    assert_steps_match(starts.steps, theirs, TOLERANCE)
    assert set(starts.steps.info) == {"reward_dist", "reward_ctrl", "reward_near"}


def pushing_starts(starts: Transitions, limit: int) -> Transitions:
    """`starts` where a finger capsule's lowest end is at the object's height, with the object
    (at rest) moved against that end, 1 mm deep, on the side the end moves to: the next step
    pushes it. C MuJoCo (mj_forward) says where the fingers are and that the contact is there."""
    env = gymnasium_env(GYMNASIUM_ID)
    model, data = env.model, env.data
    wrist = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "r_wrist_roll_link")
    fingers = [g for g in range(model.ngeom) if model.geom_bodyid[g] == wrist and model.geom_contype[g]]
    cylinder = int(np.flatnonzero(model.geom_bodyid == mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "object"))[0])
    radius, half_height = model.geom_size[cylinder, :2]
    object_origin = model.body_pos[model.geom_bodyid[cylinder]]  # the object's xpos at qpos 0
    rng = np.random.default_rng(0)
    chosen, qpos_out = [], []
    velocity = np.zeros(6)
    for i, (qpos, qvel) in enumerate(zip(starts.qpos.astype(np.float64), starts.qvel.astype(np.float64))):
        data.qpos[:], data.qvel[:] = qpos, qvel
        mujoco.mj_forward(model, data)
        ends = [(data.geom_xpos[g] + sign * model.geom_size[g, 1] * data.geom_xmat[g].reshape(3, 3)[:, 2], g)
                for g in fingers for sign in (-1.0, 1.0)]
        end, finger = min(ends, key=lambda e: e[0][2])
        finger_radius = model.geom_size[finger, 0]
        if not object_origin[2] - half_height + finger_radius < end[2] < object_origin[2] + half_height:
            continue  # not at the object's height
        mujoco.mj_objectVelocity(model, data, mujoco.mjtObj.mjOBJ_GEOM, finger, velocity, 0)
        moving = velocity[3:5] + np.cross(velocity[:3], end - data.geom_xpos[finger])[:2]
        direction = moving / np.linalg.norm(moving) if np.linalg.norm(moving) > 1e-3 else rng.normal(size=2)
        centre = end[:2] + (radius + finger_radius - 1e-3) * direction / np.linalg.norm(direction)
        qpos = qpos.copy()
        qpos[OBJECT] = (centre - object_origin[:2])[::-1]  # obj_slidey, then obj_slidex
        data.qpos[:] = qpos
        mujoco.mj_forward(model, data)
        on_object = [c for c in data.contact[:data.ncon] if cylinder in (c.geom1, c.geom2)
                     and {c.geom1, c.geom2} & set(fingers)]
        if on_object and min(c.dist for c in on_object) > -3e-3:  # touching, not buried in another finger
            chosen.append(i), qpos_out.append(qpos)
        if len(chosen) == limit:
            break
    chosen = np.array(chosen)
    qvel = starts.qvel[chosen].copy()
    qvel[:, OBJECT] = 0.0
    return Transitions(np.array(qpos_out, np.float32), qvel, starts.qacc_warmstart[chosen], starts.actions[chosen],
                       starts.env_actions[chosen], steps=None)


def our_steps(name: str, starts: Transitions, **overrides) -> Steps:
    """Our env (float32, jit + vmap) stepped once from each start state with its action."""
    env = envs.make(name, **overrides).unwrapped

    @jax.jit
    @jax.vmap
    def step(qpos, qvel, warmstart, action):
        state = env.reset(jax.random.PRNGKey(0))
        data = state.pipeline_state.replace(qpos=qpos, qvel=qvel, qacc_warmstart=warmstart)
        state = env.step(state.replace(pipeline_state=data), action)
        return state.obs, state.reward, state.done, state.metrics

    obs, reward, done, metrics = jax.tree.map(np.asarray, step(starts.qpos, starts.qvel, starts.qacc_warmstart,
                                                               starts.actions))
    return Steps(obs, reward, done.astype(bool), metrics)


@pytest.mark.heavy  # issue #29: out of the default run (make test <= 8 min); compiles pusher's contact step again (~30 s)
def test_steps_while_pushing_differ_as_measured(starts):
    """MJX's capsule-cylinder contact is not C MuJoCo's (docs/tasks.md): C finds one contact at
    the exact depth with a horizontal normal; MJX (`collision_sdf.capsule_cylinder`, gradient
    descent on the shapes' signed distances from two starting points) usually two at about the
    same point, 10-15% shallower, normals tilted by a few degrees, and sometimes none. Measured on
    these 77 states: the object moves a median 1.9 times as far as in Gymnasium's step (0.37 mm
    against 0.19 mm), joint velocities differ by up to 4.3e-3 rad/s, the object's position by
    5e-4, the reward by 4e-4 (default weights); 47% of the steps agree to 1e-3. The bounds below
    hold that (and fail if MJX's contact changes, so the docs get updated)."""
    # Every option changed here, for Gymnasium too: the weights only scale the reward's terms.
    overrides = dict(reward_near_weight=0.7, reward_dist_weight=2.0, reward_control_weight=0.3)
    pushing = pushing_starts(starts, limit=200)
    assert len(pushing.qpos) >= 50, len(pushing.qpos)
    ours = our_steps(NAME, pushing, **overrides)
    theirs = gymnasium_steps(GYMNASIUM_ID, pushing, **overrides)
    before = pushing.qpos[:, OBJECT][:, ::-1] + np.array([0.45, -0.05])  # the object's x, y before the step
    their_push = np.linalg.norm(theirs.obs[:, OBJECT_XPOS][:, :2] - before, axis=1)
    our_push = np.linalg.norm(ours.obs[:, OBJECT_XPOS][:, :2] - before, axis=1)
    assert (their_push > 1e-6).all(), "Gymnasium's step must push the object"
    ratio = np.median(our_push / their_push)
    error = np.abs(ours.obs - theirs.obs).max(axis=1)
    print(f"pushing ({len(error)} states): object moved {ratio:.2f}x as far (median); largest observation "
          f"difference, quantiles 50/90/100%: {np.quantile(error, [0.5, 0.9, 1])}; "
          f"reward {np.abs(ours.reward - theirs.reward).max():.2e}")
    assert 1.5 < ratio < 2.5, ratio
    assert error.max() < 1e-2 and 0.25 < (error < 1e-3).mean() < 0.75, np.quantile(error, [0.5, 0.9, 1])
    np.testing.assert_allclose(ours.obs[:, ARM], theirs.obs[:, ARM], atol=5e-4)  # the arm's angles
    np.testing.assert_allclose(ours.reward, theirs.reward, atol=3e-3)
    for name in ("reward_dist", "reward_ctrl", "reward_near"):
        np.testing.assert_allclose(ours.info[name], theirs.info[name], atol=2e-3, err_msg=name)
    np.testing.assert_array_equal(ours.terminated, False), np.testing.assert_array_equal(theirs.terminated, False)


@pytest.mark.heavy  # issue #29: out of the default run (make test <= 8 min); compiles its own 100-step episode (~25 s)
def test_episodes_match_gymnasium():
    """Whole episodes side by side, from the reset's observation (body positions) on. Two float32
    and float64 trajectories part where a finger meets the table (measured: every step within
    1.5e-5 for the first 20 steps of 8 episodes, the first step beyond 1e-3 at steps 45-97 in 5 of
    them, up to 0.2 by step 100); the first 30 steps are held to 1e-3."""
    ours, theirs, live = lockstep(NAME, GYMNASIUM_ID, num_episodes=8, num_steps=100)
    assert live.all()  # Pusher never terminates
    early = (np.arange(len(live)) % 100) < 30
    assert_steps_match(select(ours, early), select(theirs, early), {"obs": 1e-3, "reward": 1e-4})
    error = np.abs(ours.obs - theirs.obs).max(axis=1).reshape(8, 100)
    print("episodes: largest observation difference by step 20/30/50/100:", [error[:, :n].max() for n in (20, 30, 50, 100)])


def test_options_are_gymnasiums():
    assert_same_options(NAME, GYMNASIUM_ID)
    env = envs.make(NAME)
    assert env.observation_size == 23 and env.action_size == 7
    # Gymnasium's action space is the ctrlrange [-2, 2]: our action a is Gymnasium's 2a.
    np.testing.assert_array_equal(env.action_low, -2 * np.ones(7)), np.testing.assert_array_equal(env.action_high, 2 * np.ones(7))
    np.testing.assert_array_equal(env.to_env_action(np.full(7, 0.5)), np.ones(7))


@pytest.mark.parametrize("option, value", [("reward_near_weight", float("nan")), ("reward_dist_weight", float("inf")),
                                           ("reward_control_weight", "heavy")])
def test_bad_options_are_refused(option, value):
    with pytest.raises(ValueError, match=option):
        envs.make(NAME, **{option: value})


@pytest.mark.slow
def test_reset_distribution_matches_gymnasium():
    qpos, qvel, obs = reset_samples(NAME, 4000)
    their_qpos, their_qvel, their_obs = gymnasium_reset_samples(GYMNASIUM_ID, 4000)
    assert_resets_match(qpos[:, OBJECT], their_qpos[:, OBJECT], "object position")
    assert_resets_match(qvel[:, ARM], their_qvel[:, ARM], "arm velocities")
    for ours, theirs, what in [(qpos[:, ARM], their_qpos[:, ARM], "arm angles"), (qpos[:, GOAL], their_qpos[:, GOAL], "goal"),
                               (qvel[:, 7:], their_qvel[:, 7:], "object and goal velocities")]:
        np.testing.assert_array_equal(ours, 0.0, err_msg=what), np.testing.assert_array_equal(theirs, 0.0, err_msg=what)
    exact_noise_bounds(qvel[:, ARM], 0.0, 0.005, "arm velocities")
    # The object: U(-0.3, 0) x U(-0.2, 0.2) (qpos[7] is obj_slidey), kept when farther than 0.17 from 0.
    distance = np.linalg.norm(qpos[:, OBJECT], axis=1)
    assert distance.min() > 0.17 and distance.min() < 0.172
    assert qpos[:, 7].min() >= -0.3 and qpos[:, 7].max() <= 0.0 and np.abs(qpos[:, 8]).max() <= 0.2
    # The observation, body positions included: what mj_forward gives at the reset pose.
    assert_resets_match(obs[:, OBJECT_XPOS][:, :2], their_obs[:, OBJECT_XPOS][:, :2], "object's xpos")
    np.testing.assert_allclose(obs[:, OBJECT_XPOS][:, :2], qpos[:, OBJECT][:, ::-1] + [0.45, -0.05], atol=1e-6)
    np.testing.assert_allclose(obs[:, [14, 15, 16, 19, 20, 21, 22]], their_obs[:, [14, 15, 16, 19, 20, 21, 22]],
                               atol=1e-6)  # the fingertips, the object's height and the goal never vary at reset
    np.testing.assert_array_equal(obs[:, :14], np.concatenate([qpos[:, ARM], qvel[:, ARM]], axis=1))


