"""Checks of a Gymnasium MuJoCo v5 task against Gymnasium's own env of the same task (C MuJoCo,
float64), shared by the tests of every such task (a helper module, not a test file).

- The step-for-step proof is the library's (`envs.interop.gymnasium_equality`, public for users'
  tasks): `transitions`, `gymnasium_steps`, `assert_steps_match`, re-exported here.
- `lockstep`: whole short episodes side by side; `through_our_task`: Gymnasium's MjData through
  our task's hooks.
- `reset_samples` / `assert_resets_match`: the reset distributions, by mean and spread.
"""

from __future__ import annotations

import dataclasses
import inspect
from typing import Any

import gymnasium
import jax
import numpy as np

import envs
from envs.interop.gymnasium_equality import (Steps, Transitions, assert_steps_match, gymnasium_env,  # noqa: F401
                                             gymnasium_kwargs, gymnasium_steps, transitions)


def lockstep(name: str, gymnasium_id: str, num_episodes: int = 16, num_steps: int = 20, seed: int = 0,
             **overrides: Any) -> tuple[Steps, Steps, np.ndarray]:
    """Whole short episodes, ours and Gymnasium's side by side: Gymnasium's env is reset, set to our
    reset state, then both take the same random actions for `num_steps` steps (Gymnasium's env
    carries its own state from step to step, as in its own rollouts). Returns our steps, theirs
    (both flattened over episodes and steps) and a mask of the steps up to each episode's first
    termination (later ones are outside both envs' episodes)."""
    env = envs.make(name, **overrides).unwrapped

    def episode(key):
        reset_key, action_key = jax.random.split(key)
        actions = jax.random.uniform(action_key, (num_steps, env.action_size), minval=-1.0, maxval=1.0)

        def step(state, action):
            state = env.step(state, action)
            return state, (state.obs, state.reward, state.done, state.metrics)

        start = env.reset(reset_key)
        _, record = jax.lax.scan(step, start, actions)
        return start.pipeline_state.qpos, start.pipeline_state.qvel, actions, record

    keys = jax.random.split(jax.random.PRNGKey(seed), num_episodes)
    qpos, qvel, actions, (obs, reward, done, metrics) = jax.tree.map(np.asarray, jax.jit(jax.vmap(episode))(keys))
    theirs = gymnasium_env(gymnasium_id, **gymnasium_kwargs(env.params))
    their_steps = []
    for start_qpos, start_qvel, episode_actions in zip(qpos, qvel, actions):
        theirs.reset()  # clears what the last episode left in MuJoCo's data (cfrc_ext, warm start)
        theirs.set_state(start_qpos.astype(np.float64), start_qvel.astype(np.float64))
        their_steps += [theirs.step(env.to_env_action(a.astype(np.float64))) for a in episode_actions]
    flat = lambda x: x.reshape(num_episodes * num_steps, *x.shape[2:])
    ours = Steps(flat(obs), flat(reward), flat(done).astype(bool), {k: flat(v) for k, v in metrics.items()})
    theirs = Steps(np.array([o for o, *_ in their_steps]), np.array([r for _, r, *_ in their_steps]),
                   np.array([t for _, _, t, *_ in their_steps]),
                   {k: np.array([i[k] for *_, i in their_steps]) for k in their_steps[0][4]})
    ended_before = np.cumsum(done, axis=1) - done > 0  # a termination earlier in the episode
    return ours, theirs, ~flat(ended_before)


def select(steps: Steps, mask: np.ndarray) -> Steps:
    """The steps where `mask` is True."""
    return Steps(steps.obs[mask], steps.reward[mask], steps.terminated[mask], {k: v[mask] for k, v in steps.info.items()})


def reset_samples(name: str, count: int, **overrides: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """qpos, qvel and the observation of `count` resets of our env (one jitted vmap)."""
    env = envs.make(name, **overrides).unwrapped
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(1), count))
    return tuple(np.asarray(x) for x in (states.pipeline_state.qpos, states.pipeline_state.qvel, states.obs))


def gymnasium_reset_samples(gymnasium_id: str, count: int, **kwargs: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """qpos, qvel and the observation of `count` resets of Gymnasium's env (seeded once)."""
    env = gymnasium_env(gymnasium_id, **kwargs)
    qpos, qvel, obs = [], [], []
    for _ in range(count):
        o, _ = env.reset()
        qpos.append(env.data.qpos.copy()), qvel.append(env.data.qvel.copy()), obs.append(o)
    return np.array(qpos), np.array(qvel), np.array(obs)


def assert_resets_match(ours: np.ndarray, theirs: np.ndarray, what: str) -> None:
    """Per coordinate: means within 5 standard errors of their difference, spreads within 10%
    (at 4,000 samples each a spread is known to about 1.1% for a normal, 0.6% for a uniform)."""
    spread = np.sqrt(ours.var(0) / len(ours) + theirs.var(0) / len(theirs))
    np.testing.assert_array_less(np.abs(ours.mean(0) - theirs.mean(0)), 5 * spread + 1e-7, err_msg=f"{what}: mean")
    np.testing.assert_allclose(ours.std(0), theirs.std(0), rtol=0.1, atol=1e-7, err_msg=f"{what}: spread")
    np.testing.assert_array_less(ours.min(0), theirs.mean(0) + 1e-7, err_msg=f"{what}: min")  # not one-sided
    np.testing.assert_array_less(theirs.mean(0) - 1e-7, ours.max(0), err_msg=f"{what}: max")


def exact_noise_bounds(ours: np.ndarray, centre: np.ndarray, scale: float, what: str) -> None:
    """A uniform U(-scale, scale) around `centre`: nothing outside, and both ends reached."""
    noise = ours - centre
    assert np.all(np.abs(noise) <= scale * (1 + 1e-6) + 1e-7), f"{what}: noise beyond +-{scale}"
    assert np.all(noise.max(0) > 0.95 * scale) and np.all(noise.min(0) < -0.95 * scale), f"{what}: ends not reached"


# Gymnasium's constructor arguments that are not the task's rules: the model file and frame skip
# (a task's own, fixed), rendering, and MujocoEnv's pass-through keywords.
NOT_RULES = {"self", "xml_file", "frame_skip", "default_camera_config", "kwargs"}


def through_our_task(env, before: list, after: list) -> tuple:
    """Gymnasium's `MjData` before and after each of its steps (`mjx.put_data`), through our task's
    post_step, reward and observation: (cfrc_ext, observation, reward, reward terms, terminated), each
    stacked over the steps (ant and humanoid: our task reads MuJoCo's data as Gymnasium does)."""
    stack = lambda datas: jax.tree.map(lambda *x: np.stack(x), *datas)

    @jax.jit
    @jax.vmap
    def task(prev, data):
        data = env.post_step(prev, data)
        reward, terms = env.reward(data, None, prev)
        return env.cfrc_ext(data), env.observation(data), reward, terms, env.terminated(data)

    return jax.tree.map(np.asarray, task(stack(before), stack(after)))


def assert_same_options(name: str, gymnasium_id: str) -> None:
    """`envs.make(name)`'s task options are v5's constructor arguments, with the same defaults,
    and the time limit is Gymnasium's max_episode_steps."""
    spec = gymnasium.spec(gymnasium_id)
    constructor = inspect.signature(gymnasium.envs.registration.load_env_creator(spec.entry_point).__init__)
    theirs = {p.name: p.default for p in constructor.parameters.values() if p.name not in NOT_RULES}
    options = envs.options(name)
    params = options["params"]
    ours = {field.name: getattr(params, field.name) for field in dataclasses.fields(params)}
    assert ours == theirs
    assert options["episode_length"] == spec.max_episode_steps


