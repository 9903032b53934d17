"""Prove an MJX task equal to Gymnasium's env of the same task, step for step.

Your task (an `envs.GymnasiumMujocoEnv`, or any `envs.MjxEnv` whose action is Gymnasium's scaled to
the ctrlrange) and Gymnasium's env (C MuJoCo, float64) are given the same states and the same actions;
what each step returns is compared, and the error of every step comes back:

    from envs.interop.gymnasium_equality import compare_with_gymnasium
    report = compare_with_gymnasium(MyStandup(), "HumanoidStandup-v5")
    print(report.worst())          # {"obs": 3e-5, "reward": 1e-4, "reward_linup": ..., ...}
    report.assert_within({"obs": 1e-3, "reward": 1e-3})

- `transitions(env)`: your env (float32, jit + vmap) from its resets under random actions; each
  kept step is (state before, action, what your step returned).
- `gymnasium_steps(gymnasium_id, starts)`: Gymnasium's env set to each start state (`set_state(qpos,
  qvel)` and MuJoCo's solver warm start) and stepped once with the same action.
- `Comparison`: both sides and the error per step of the observation, the reward, termination and
  every metric of yours (each must be one of Gymnasium's `info` names).

The suite's own tests prove its Gymnasium tasks with these functions (tests/gymnasium_mujoco.py).
"""

from __future__ import annotations

import dataclasses
from typing import Any, Mapping

import gymnasium
import jax
import numpy as np

from envs.core import Env
from envs.compile_cache import PROOF_COMPILER_OPTIONS
from envs.registry import make


def gymnasium_env(gymnasium_id: str, **kwargs: Any) -> gymnasium.Env:
    """Gymnasium's env itself (no TimeLimit, order or passive checks around it), reset once."""
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


def transitions(env: Env | str, num_envs: int = 32, num_steps: int = 40, keep: int = 320, seed: int = 0,
                forward_first: bool = False, **overrides: Any) -> Transitions:
    """`keep` steps of `num_envs` episodes of `num_steps` random actions each (uniform in [-1, 1],
    one jitted scan over a vmapped env; no time limit, no auto-reset), spread evenly over the
    episodes' steps so that early (near the reset) and late states are both in the sample.
    `env`: an MJX task, or a registered name made with `overrides`.

    `forward_first`: each step starts from its state after `mjx.forward`, so the positions MuJoCo
    derives (xpos, ...) are those of its qpos, as Gymnasium's `set_state` leaves them; for a task
    whose reward reads the previous step's derived positions (Ant's x_velocity), which after an
    RK4 step are those of RK4's last stage, not of the new qpos."""
    env = (make(env, **overrides) if isinstance(env, str) else env).unwrapped

    def episode(key):
        reset_key, action_key = jax.random.split(key)
        actions = jax.random.uniform(action_key, (num_steps, env.action_size), minval=-1.0, maxval=1.0)

        def step(state, action):
            if forward_first:
                state = state.replace(pipeline_state=env.compute_derived(state.pipeline_state))
            before = state.pipeline_state
            state = env.step(state, action)
            return state, (before.qpos, before.qvel, before.qacc_warmstart, state.obs, state.reward,
                           state.done, state.metrics)

        _, record = jax.lax.scan(step, env.reset(reset_key), actions)
        return actions, record

    keys = jax.random.split(jax.random.PRNGKey(seed), num_envs)
    program = jax.jit(jax.vmap(episode), compiler_options=PROOF_COMPILER_OPTIONS)
    actions, (qpos, qvel, warmstart, obs, reward, done, metrics) = program(keys)
    flat = lambda x: np.asarray(x).reshape(num_envs * num_steps, *np.shape(x)[2:])
    chosen = np.linspace(0, num_envs * num_steps - 1, keep).round().astype(int)
    pick = lambda x: flat(x)[chosen]
    actions = pick(actions)
    return Transitions(
        qpos=pick(qpos), qvel=pick(qvel), qacc_warmstart=pick(warmstart), actions=actions,
        env_actions=np.stack([env.to_env_action(a) for a in actions.astype(np.float64)]),
        steps=Steps(pick(obs), pick(reward), pick(done).astype(bool), {k: pick(v) for k, v in metrics.items()}),
    )


def gymnasium_steps(gymnasium_id: str, starts: Transitions, opt: Mapping[str, Any] | None = None,
                    **kwargs: Any) -> Steps:
    """Gymnasium's env stepped once from each start state with the same action. `opt`: MjOption
    fields set on Gymnasium's model first (humanoid: the solver our task steps its model with);
    `kwargs`: Gymnasium's constructor arguments."""
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


@dataclasses.dataclass
class Comparison:
    """Our steps and Gymnasium's from the same states and actions, and the error of each step."""

    ours: Steps
    theirs: Steps

    def errors(self) -> dict[str, np.ndarray]:
        """Per step: the largest absolute difference of the observation ("obs"), of the reward and of
        each of our metrics; "terminated": 1.0 where the two disagree. ValueError if the shapes differ
        or a metric of ours is not among Gymnasium's info values."""
        if self.ours.obs.shape != self.theirs.obs.shape:
            raise ValueError(f"observations of shape {self.ours.obs.shape[1:]} here, {self.theirs.obs.shape[1:]} "
                             "in Gymnasium's env")
        missing = sorted(set(self.ours.info) - set(self.theirs.info))
        if missing:
            raise ValueError(f"metrics {missing} are not in Gymnasium's info ({sorted(self.theirs.info)})")
        errors = {"obs": np.abs(self.ours.obs - self.theirs.obs).max(axis=-1),
                  "reward": np.abs(self.ours.reward - self.theirs.reward),
                  "terminated": (self.ours.terminated != self.theirs.terminated).astype(float)}
        for name, value in self.ours.info.items():
            errors[name] = np.abs(value - self.theirs.info[name]).reshape(len(value), -1).max(axis=-1)
        return errors

    def worst(self) -> dict[str, float]:
        """The largest error of each quantity over all steps."""
        return {name: float(error.max(initial=0.0)) for name, error in self.errors().items()}

    def assert_within(self, atol: Mapping[str, float], rtol: float = 1e-4) -> None:
        """Every observation element, the reward and each metric within `atol[name]` (+ `rtol`
        relative; a metric without its own entry falls back to atol["reward"]), termination equal."""
        ours, theirs = self.ours, self.theirs
        self.errors()  # the shapes and names first, with their clear errors
        np.testing.assert_allclose(ours.obs, theirs.obs, atol=atol["obs"], rtol=rtol, err_msg="observation")
        np.testing.assert_allclose(ours.reward, theirs.reward, atol=atol["reward"], rtol=rtol, err_msg="reward")
        for name, value in ours.info.items():
            np.testing.assert_allclose(value, theirs.info[name], atol=atol.get(name, atol["reward"]), rtol=rtol,
                                       err_msg=f"info[{name!r}]")
        np.testing.assert_array_equal(ours.terminated, theirs.terminated, err_msg="terminated")


def compare_with_gymnasium(env: Env | str, gymnasium_id: str, num_envs: int = 32, num_steps: int = 40,
                           keep: int = 320, seed: int = 0, opt: Mapping[str, Any] | None = None,
                           gymnasium_kwargs_: Mapping[str, Any] | None = None,
                           forward_first: bool = False) -> Comparison:
    """`env` (an MJX task or a registered name) and Gymnasium's `gymnasium_id` stepped from the same
    `keep` states with the same actions (`transitions`, `gymnasium_steps`). Gymnasium's env is built
    with `gymnasium_kwargs_`, by default the task's params (`gymnasium_kwargs`) where it has them;
    `opt`: MjOption fields set on Gymnasium's model (e.g. the solver the task steps with)."""
    env = (make(env) if isinstance(env, str) else env).unwrapped
    if gymnasium_kwargs_ is None:
        params = getattr(env, "params", None)
        gymnasium_kwargs_ = gymnasium_kwargs(params) if dataclasses.is_dataclass(params) else {}
    starts = transitions(env, num_envs, num_steps, keep, seed, forward_first)
    return Comparison(starts.steps, gymnasium_steps(gymnasium_id, starts, opt, **gymnasium_kwargs_))


def assert_steps_match(ours: Steps, theirs: Steps, atol: Mapping[str, float], rtol: float = 1e-4) -> None:
    """`Comparison(ours, theirs).assert_within(atol, rtol)`."""
    Comparison(ours, theirs).assert_within(atol, rtol)
