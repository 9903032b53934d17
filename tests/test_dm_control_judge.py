"""The judge of a trained DeepMind Control Suite policy on dm_control's own env
(`envs.interop.dm_control.returns_on_dm_control`, reached by `python -m benchmarks.gym_training`): a fixed
policy's return there equals its return on our env from the same initial states (dm_control's resets
of the judge's seeds), within the one-step proof's bounds grown over a short horizon; the same
comparison fails when the judge hands the policy the observation in another order."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs

pytest.importorskip("dm_control", reason="the judge runs dm-control==1.0.50 (pip install 'mjxsuite[dmc]')")

from envs.interop.dm_control import JUDGE_FIRST_SEED, load, returns_on_dm_control  # noqa: E402

HORIZON = 100  # control steps: 1 s of the cart-pole, 2 s of the reacher
EPISODES = 3
# Summed over HORIZON steps: the proof's per-step reward bound (1e-5) grown by the rollouts' float32
# drift (the falling pole is unstable), far below the returns' spread between episodes.
RETURN_BOUND = 1e-3


def fixed_gain(env) -> np.ndarray:
    """A fixed linear policy's gain (observation -> action, then clipped to [-1, 1]): every
    observation entry moves the action, so an entry out of place changes the return."""
    return np.random.default_rng(7).uniform(-1.0, 1.0, (env.observation_size, env.action_size))


def dm_control_starts(env, episodes: int):
    """qpos, qvel and the per-episode edits of dm_control's resets of the judge's seeds."""
    qpos, qvel, targets = [], [], []
    for episode in range(episodes):
        theirs = load(env.domain, env.task, JUDGE_FIRST_SEED + episode)
        theirs.reset()
        qpos.append(theirs.physics.data.qpos.copy()), qvel.append(theirs.physics.data.qvel.copy())
        if "target" in env.episode_info:
            targets.append(theirs.physics.named.model.geom_pos["target", :2].copy())
    episode = {"target": np.array(targets, np.float32)} if targets else {}
    return np.array(qpos, np.float32), np.array(qvel, np.float32), episode


def our_returns(env, gain: np.ndarray, qpos, qvel, episode) -> np.ndarray:
    """The fixed policy's return on our env over HORIZON steps from each given start (one jitted vmap)."""
    gain = jnp.asarray(gain, jnp.float32)

    def rollout(q, v, given):
        state = env.reset(jax.random.PRNGKey(0))
        info = {**state.info, **given}
        data = env.with_episode(env.compute_derived(state.pipeline_state.replace(qpos=q, qvel=v)), info)
        state = state.replace(pipeline_state=data, obs=env.observation(data), info=info)

        def step(state, _):
            state = env.step(state, jnp.clip(state.obs @ gain, -1.0, 1.0))
            return state, state.reward

        return jax.lax.scan(step, state, None, length=HORIZON)[1].sum()

    return np.asarray(jax.jit(jax.vmap(rollout))(qpos, qvel, episode))


def check_judge(name: str) -> None:
    env = envs.make(name).unwrapped
    gain = fixed_gain(env)
    ours = our_returns(env, gain, *dm_control_starts(env, EPISODES))
    judged = returns_on_dm_control(lambda obs: np.clip(obs @ gain, -1.0, 1.0), name, EPISODES, max_steps=HORIZON)
    np.testing.assert_allclose(judged, ours, atol=RETURN_BOUND, rtol=0)
    assert np.ptp(ours) > 100 * RETURN_BOUND  # the episodes differ: the starts were the judge's own
    # The observation in reverse order: the same policy is judged on another input.
    reversed_order = returns_on_dm_control(lambda obs: np.clip(obs[::-1] @ gain, -1.0, 1.0), name, EPISODES,
                                    max_steps=HORIZON)
    assert np.abs(np.asarray(reversed_order) - ours).max() > 100 * RETURN_BOUND


# Each compiles a rollout of its own (tens of seconds on two cores): the slow run. Reacher's target
# is a per-episode model edit that the judge's resets draw.
@pytest.mark.slow
@pytest.mark.parametrize("name", ["dmc-cartpole-balance", "dmc-reacher-easy"])
def test_a_fixed_policy_scores_on_dm_control_what_it_scores_here(name):
    check_judge(name)


def test_full_episodes_and_the_judges_seeds():
    """A whole episode is dm_control's 1,000 steps, and each episode is its own seed's reset (no
    compile: the fast suite's check of the judge)."""
    still = lambda obs: np.zeros(1)  # noqa: E731
    first = returns_on_dm_control(still, "dmc-cartpole-swingup", 2)
    assert first[0] != first[1]
    theirs = load("cartpole", "swingup", JUDGE_FIRST_SEED)
    step, steps, total = theirs.reset(), 0, 0.0
    while not step.last():
        step = theirs.step(np.zeros(1))
        steps, total = steps + 1, total + step.reward
    assert steps == 1000 and total == first[0]


def test_gym_training_judges_each_task_on_its_reference_env(tmp_path, capsys):
    """`python -m benchmarks.gym_training` picks the judge by task (no training here): Gymnasium's env
    for Gymnasium's tasks, dm_control's for dmc-*, none for our own; `--judge` marks a run directory
    that is not here instead of failing, and refuses --run with --judge."""
    from benchmarks import gym_training

    assert gym_training.reference_of("hopper") == "gymnasium"
    assert gym_training.reference_of("dmc-walker-walk") == "dm_control"
    assert gym_training.reference_of("cartpole-mjx") is None
    records = tmp_path / "records.json"
    records.write_text('[{"kind": "gym-training", "command": "mjxsuite train --env dmc-cartpole-balance", '
                       f'"out": "{tmp_path / "elsewhere"}", "env": "dmc-cartpole-balance"}}]')
    gym_training.main(["--judge", str(records), "--json", str(tmp_path / "judged.json")])
    assert "not found here" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        gym_training.main(["--judge", str(records), "--run", "--env dmc-cartpole-balance"])


def test_solver_options_other_than_dm_controls_say_so():
    """Playground's fewer solver iterations are allowed on a dmc task, with a warning: the proof and
    the judge assume dm_control's settings."""
    env = envs.make("dmc-pendulum-swingup").unwrapped
    with pytest.warns(UserWarning, match="no longer dm_control's physics"):
        fast = envs.make("dmc-pendulum-swingup", opt={"iterations": 4}).unwrapped
    assert fast.mj_model.opt.iterations == 4 and env.mj_model.opt.iterations == 100
