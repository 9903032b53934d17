"""Checks of a Gymnasium MuJoCo v5 task against Gymnasium's own env of the same task (C MuJoCo,
float64), shared by the tests of every such task (a helper module, not a test file).

- `transitions(name, ...)`: our env (float32, jit + vmap) run from its resets under random
  actions; every step is kept as (state before, action, what our step returned).
- `gymnasium_steps(gymnasium_id, starts, actions)`: Gymnasium's env set to each start state
  (`set_state(qpos, qvel)` and MuJoCo's solver warm start) and stepped with the same action.
- `assert_steps_match(ours, theirs, tolerances)`: observation, reward, every reward term and
  Gymnasium info value our metrics carry, and termination, compared at stated tolerances.
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
from envs.mjx_env import mjx


def gymnasium_env(gymnasium_id: str, **kwargs: Any) -> gymnasium.Env:
    """Gymnasium's env itself (no TimeLimit, order or passive checks around it)."""
    env = gymnasium.make(gymnasium_id, **kwargs).unwrapped
    env.reset(seed=0)
    return env


def gymnasium_kwargs(params: Any) -> dict[str, Any]:
    """A task's params as the keyword arguments of Gymnasium's constructor (v5 uses the same names)."""
    return {field.name: getattr(params, field.name) for field in dataclasses.fields(params)}


@dataclasses.dataclass
class Steps:
    """A batch of env steps: what each returned (arrays with a leading batch axis)."""

    obs: np.ndarray
    reward: np.ndarray
    terminated: np.ndarray
    info: dict[str, np.ndarray]  # Gymnasium's info names (our metrics)
    contacts: np.ndarray | None = None  # Gymnasium's side: MuJoCo's contact count after the step


@dataclasses.dataclass
class Transitions:
    """Our env's steps and the states they started from (float32)."""

    qpos: np.ndarray
    qvel: np.ndarray
    qacc_warmstart: np.ndarray  # MuJoCo's solver starts from it; C MuJoCo is given the same
    actions: np.ndarray  # the env's actions, in [-1, 1]
    env_actions: np.ndarray  # the same actions in Gymnasium's action space (the ctrlrange)
    steps: Steps


def transitions(name: str, num_envs: int = 32, num_steps: int = 40, keep: int = 320, seed: int = 0,
                forward_first: bool = False, **overrides: Any) -> Transitions:
    """`keep` steps of `num_envs` episodes of `num_steps` random actions each (uniform in [-1, 1],
    one jitted scan over a vmapped env; no time limit, no auto-reset), spread evenly over the
    episodes' steps so that early (near the reset) and late states are both in the sample.

    `forward_first`: each step starts from its state after `mjx.forward`, so the positions MuJoCo
    derives (xpos, ...) are those of its qpos, as Gymnasium's `set_state` leaves them; for a task
    whose reward reads the previous step's derived positions (Ant's x_velocity), which after an
    RK4 step are those of RK4's last stage, not of the new qpos (see `lockstep` for rollouts)."""
    env = envs.make(name, **overrides).unwrapped

    def episode(key):
        reset_key, action_key = jax.random.split(key)
        actions = jax.random.uniform(action_key, (num_steps, env.action_size), minval=-1.0, maxval=1.0)

        def step(state, action):
            if forward_first:
                state = state.replace(pipeline_state=env.forward(state.pipeline_state))
            before = state.pipeline_state
            state = env.step(state, action)
            return state, (before.qpos, before.qvel, before.qacc_warmstart, state.obs, state.reward,
                           state.done, state.metrics)

        _, record = jax.lax.scan(step, env.reset(reset_key), actions)
        return actions, record

    keys = jax.random.split(jax.random.PRNGKey(seed), num_envs)
    actions, (qpos, qvel, warmstart, obs, reward, done, metrics) = jax.jit(jax.vmap(episode))(keys)
    flat = lambda x: np.asarray(x).reshape(num_envs * num_steps, *np.shape(x)[2:])
    chosen = np.linspace(0, num_envs * num_steps - 1, keep).round().astype(int)
    pick = lambda x: flat(x)[chosen]
    actions = pick(actions)
    return Transitions(
        qpos=pick(qpos), qvel=pick(qvel), qacc_warmstart=pick(warmstart), actions=actions,
        env_actions=np.stack([env.to_env_action(a) for a in actions.astype(np.float64)]),
        steps=Steps(pick(obs), pick(reward), pick(done).astype(bool), {k: pick(v) for k, v in metrics.items()}),
    )


def gymnasium_steps(gymnasium_id: str, starts: Transitions, opt: dict[str, Any] | None = None, **kwargs: Any) -> Steps:
    """Gymnasium's env stepped once from each start state with the same action. `opt`: MjOption
    fields set on Gymnasium's model first (humanoid: the solver our task steps its model with)."""
    env = gymnasium_env(gymnasium_id, **kwargs)
    for field, value in (opt or {}).items():
        setattr(env.model.opt, field, value)
    obs, rewards, terminated, infos, contacts = [], [], [], [], []
    for qpos, qvel, warmstart, action in zip(starts.qpos, starts.qvel, starts.qacc_warmstart, starts.env_actions):
        env.set_state(qpos.astype(np.float64), qvel.astype(np.float64))
        env.data.qacc_warmstart[:] = warmstart
        o, r, term, _, info = env.step(action)
        obs.append(o), rewards.append(r), terminated.append(term), infos.append(info), contacts.append(env.data.ncon)
    info = {key: np.array([i[key] for i in infos]) for key in infos[0]}
    return Steps(np.array(obs), np.array(rewards), np.array(terminated), info, np.array(contacts))


def assert_steps_match(ours: Steps, theirs: Steps, atol: dict[str, float], rtol: float = 1e-4) -> None:
    """Every observation element, the reward and each metric within `atol[name]` (+ rtol relative;
    "obs" and "reward" name those two, a missing metric name falls back to atol["reward"]) and
    termination equal. Every metric of ours must be one of Gymnasium's info values."""
    assert ours.obs.shape == theirs.obs.shape, (ours.obs.shape, theirs.obs.shape)
    np.testing.assert_allclose(ours.obs, theirs.obs, atol=atol["obs"], rtol=rtol, err_msg="observation")
    np.testing.assert_allclose(ours.reward, theirs.reward, atol=atol["reward"], rtol=rtol, err_msg="reward")
    missing = sorted(set(ours.info) - set(theirs.info))
    assert not missing, f"metrics {missing} are not in Gymnasium's info ({sorted(theirs.info)})"
    for name, value in ours.info.items():
        np.testing.assert_allclose(value, theirs.info[name], atol=atol.get(name, atol["reward"]), rtol=rtol,
                                   err_msg=f"info[{name!r}]")
    np.testing.assert_array_equal(ours.terminated, theirs.terminated, err_msg="terminated")


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
        return data._impl.cfrc_ext, env.observation(data), reward, terms, env.terminated(data)

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


def assert_passes_check_env(name: str, gymnasium_id: str) -> None:
    """`envs.to_gymnasium(name)` passes Gymnasium's env checker with Gymnasium's action space."""
    from test_gym_interop import NORMALIZED_ACTION_WARNING, check_env_warnings, warns_of_action_space

    env = envs.to_gymnasium(name)
    their_space = gymnasium.make(gymnasium_id).action_space
    assert env.action_space == their_space
    # check_env_warnings leaves out the unbounded-observation warnings. check_env recommends a symmetric
    # Box inside [-1, 1]; Gymnasium's own InvertedPendulum-v5 ([-3, 3]) gets that warning too.
    found = check_env_warnings(env, skip_render_check=True)
    assert [NORMALIZED_ACTION_WARNING in w for w in found] == ([True] if warns_of_action_space(their_space) else []), found
