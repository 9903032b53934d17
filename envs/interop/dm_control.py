"""Prove an MJX task equal to dm_control's own env of the same task, step for step, and its resets
equal in distribution (the twin of `envs.interop.gymnasium_equality`).

    from envs.interop.dm_control import compare_with_dm_control
    report = compare_with_dm_control("dmc-cheetah-run")
    print(report.worst())          # {"obs": 2e-4, "reward": 1e-6, "discount": 0.0}
    report.assert_within({"obs": 1e-3, "reward": 1e-4})

- `load(domain, task)`: dm_control's env (`dm_control.suite.load`), after `shim_mujoco_4`.
- `transitions(env)`: our env (jit + vmap) from its resets under random actions; each kept step is
  (the state before, the action, what our step returned).
- `dm_control_steps(env, starts)`: dm_control's env reset, given the episode's model edits (the
  task's `put_episode`, e.g. reacher's target), its physics put in each start state (qpos, qvel,
  act, `mj_forward`, then MuJoCo's solver warm start) and stepped once with the action.
- `steps_from(env, qpos, qvel, actions)`: our steps from given states (near a task's goal).
- `compare_readings_with_dm_control(env)`: our observation and reward of dm_control's own physics
  states (no MJX physics runs: seconds, for tasks whose physics compiles for minutes).
- `dm_control_rollouts(env)`: dm_control's own states along random-action episodes (start states
  for `steps_from`: the touches and spins its physics reached).
- `Comparison`: both sides, with the error of each step's observation, reward and discount.
- `reset_samples` / `dm_control_reset_samples`: many resets of each, for a comparison of their
  distributions (their random numbers differ: numpy's RandomState there, JAX's here).
- `to_dm_env(env)` (also `envs.to_dm_env`): a task behind dm_control's own `dm_env.Environment`
  interface, so code written for `suite.load(domain, task)` steps it unchanged.
- `returns_on_dm_control(policy, env)` (also `envs.returns_on_dm_control`): a policy's returns on
  dm_control's own env, the judge of a trained run (`python -m benchmarks.gym_training`); from
  dm_control's own pictures for a pixel env (`Camera`).

dm_control is optional (`pip install 'mjxsuite[dmc]'`, with its dm_env); it is imported here only when used
(`load`, with MUJOCO_GL=disable, or egl to render, unless the variable is set).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import sys
from typing import Any, Callable, Mapping

import dm_env
import jax
import mujoco
import numpy as np

from envs.batching import one_after_another
from envs.core import Env, Wrapper
from envs.compile_cache import PROOF_COMPILER_OPTIONS
from envs.registry import make, options

# The fields mujoco 4.0.0 dropped that dm_control 1.0.50's generated `sizes.array_sizes` (built
# against MuJoCo 3.17's headers) still lists; no suite domain uses flex.
MUJOCO_4_DROPPED = {
    "mjmodel": {"flex_vertedge", "flex_vertedgeadr", "flex_vertedgenum", "flex_vertmetric",
                "flexvert_J_colind", "flexvert_J_rowadr", "flexvert_J_rownnz"},
    "mjdata": {"flexvert_J", "flexvert_length"},
}


def shim_mujoco_4() -> None:
    """Let dm_control 1.0.50 run on mujoco 4.0.0 (idempotent). dm_control builds its named index
    (`physics.named`) from `sizes.array_sizes`, a table generated from MuJoCo 3.17's headers; mujoco
    4.0.0 removed nine flex fields from MjModel and MjData, so the first `suite.load` fails with
    "'MjModel' object has no attribute 'flex_vertedge'". The fields the installed mujoco lacks are
    removed from the table; any other missing field raises, naming it (a different break)."""
    from dm_control.mujoco.wrapper.mjbindings import sizes

    structs = {"mjmodel": mujoco.MjModel, "mjdata": mujoco.MjData}
    for struct, cls in structs.items():
        missing = {name for name in sizes.array_sizes[struct] if not hasattr(cls, name)}
        unexpected = missing - MUJOCO_4_DROPPED[struct]
        if unexpected:
            raise RuntimeError(f"dm_control's {struct} fields {sorted(unexpected)} are missing from mujoco "
                               f"{mujoco.__version__}: not the known mujoco 4 break (checked: dm-control==1.0.50)")
        for name in missing:
            del sizes.array_sizes[struct][name]


def load(domain: str, task: str, seed: int = 0, renders: bool = False):
    """dm_control's `suite.load(domain, task)` seeded with `seed`, on the installed mujoco. Where
    dm_control is first imported here and `MUJOCO_GL` is unset, it is imported with
    MUJOCO_GL=disable (without it dm_control tries GLFW, which warns on a machine without a
    display), or with MUJOCO_GL=egl where the env `renders` (headless OpenGL; Mesa's on a CPU), and
    the variable is removed again."""
    if "dm_control.suite" not in sys.modules and "MUJOCO_GL" not in os.environ:
        os.environ["MUJOCO_GL"] = "egl" if renders else "disable"
        try:
            shim_mujoco_4()
            import dm_control.suite  # noqa: F401  (dm_control reads MUJOCO_GL when first imported)
        finally:
            del os.environ["MUJOCO_GL"]
    shim_mujoco_4()
    from dm_control import _render, suite

    if renders and _render.BACKEND in (None, "off"):  # "off": MUJOCO_GL=disable's canonical name
        raise RuntimeError(f"dm_control was imported with MUJOCO_GL={_render.BACKEND}, so its {domain} {task} "
                           "cannot render: set MUJOCO_GL=egl before the process first imports dm_control")
    return suite.load(domain, task, task_kwargs={"random": seed})


load_dm_control = load  # as `envs` offers it (dm_control's own env of a task, for a peer or a judge)


def flatten(observation: Mapping[str, Any]) -> np.ndarray:
    """dm_control's OrderedDict observation as one vector, in its order (`flatten_observation`)."""
    return np.concatenate([np.ravel(value) for value in observation.values()])


@dataclasses.dataclass
class Steps:
    """A batch of env steps: what each returned (arrays with a leading batch axis)."""

    obs: np.ndarray
    reward: np.ndarray
    discount: np.ndarray


@dataclasses.dataclass
class Transitions:
    """Our env's steps and the states they started from."""

    qpos: np.ndarray
    qvel: np.ndarray
    act: np.ndarray
    qacc_warmstart: np.ndarray  # MuJoCo's solver starts from it; dm_control's physics is given the same
    actions: np.ndarray  # in dm_control's action space (the ctrlrange)
    steps: Steps
    episode: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)  # the task's `episode_info` per step
    reset_obs: np.ndarray | None = None  # each episode's first observation (`transitions`)
    reset_qpos: np.ndarray | None = None
    reset_qvel: np.ndarray | None = None
    reset_episode: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)


def transitions(env: Env | str, num_envs: int = 16, num_steps: int = 20, keep: int = 160,
                seed: int = 0) -> Transitions:
    """`keep` steps of `num_envs` episodes of `num_steps` random actions each (uniform in [-1, 1],
    one jitted scan over a vmapped env; no time limit), spread evenly over the episodes' steps."""
    env = (make(env) if isinstance(env, str) else env).unwrapped

    def episode(key):
        reset_key, action_key = jax.random.split(key)
        actions = jax.random.uniform(action_key, (num_steps, env.action_size), minval=-1.0, maxval=1.0)

        def step(state, action):
            before = state.pipeline_state
            state = env.step(state, action)
            return state, (before.qpos, before.qvel, before.act, before.qacc_warmstart, state.obs, state.reward,
                           1.0 - state.done, episode_info(env, state))

        start = env.reset(reset_key)
        _, record = jax.lax.scan(step, start, actions)
        return actions, record, (start.obs, start.pipeline_state.qpos, start.pipeline_state.qvel,
                                 episode_info(env, start))

    keys = jax.random.split(jax.random.PRNGKey(seed), num_envs)
    program = jax.jit(jax.vmap(episode), compiler_options=PROOF_COMPILER_OPTIONS)
    actions, record, resets = jax.tree.map(np.asarray, program(keys))
    chosen = np.linspace(0, num_envs * num_steps - 1, keep).round().astype(int)
    pick = lambda x: x.reshape(num_envs * num_steps, *x.shape[2:])[chosen]
    qpos, qvel, act, warmstart, obs, reward, discount, episode = jax.tree.map(pick, record)
    env_actions = np.stack([env.to_env_action(a) for a in pick(actions).astype(np.float64)])
    reset_obs, reset_qpos, reset_qvel, reset_episode = resets
    return Transitions(qpos, qvel, act, warmstart, env_actions, Steps(obs, reward, discount), episode, reset_obs,
                       reset_qpos, reset_qvel, reset_episode)


def episode_info(env: Env, state) -> dict:
    """The `state.info` entries that hold a task's per-episode model edits (its `episode_info`:
    reacher's target), which dm_control's physics must be given too (`put_episode`)."""
    return {name: state.info[name] for name in getattr(env, "episode_info", ())}


def _episode_at(episode: Mapping[str, np.ndarray], index: int) -> dict:
    return {name: np.asarray(values[index], np.float64) for name, values in episode.items()}


def steps_from(env: Env | str, qpos: np.ndarray, qvel: np.ndarray, actions: np.ndarray,
               episode: Mapping[str, np.ndarray] | None = None, seed: int = 0,
               act: np.ndarray | None = None) -> Transitions:
    """Our env stepped once from each given state (qpos, qvel, `act` where given; everything else as after a reset,
    `mjx.forward` of it; `episode`: the task's `episode_info` entries, e.g. reacher's target, in place
    of the reset's) with each action in [-1, 1] (one jitted program, `_batched`): for states that random rollouts
    from resets rarely reach (a hopper standing, a cheetah running, a fingertip on its target), or
    states taken from dm_control's own rollouts. The resets each step started from (one per state,
    keys from `seed`) come back too (`reset_obs`, `reset_qpos`, ...), from the same compiled program."""
    env = (make(env) if isinstance(env, str) else env).unwrapped
    episode = {name: np.asarray(values) for name, values in (episode or {}).items()}
    given_act = act is not None
    act = np.asarray(act) if given_act else np.zeros((len(qpos), env.mj_model.na), np.float32)

    def step(key, q, v, a, action, given):
        reset = state = env.reset(key)
        state = state.replace(info={**state.info, **{k: value.astype(state.info[k].dtype) for k, value in given.items()}})
        data = state.pipeline_state.replace(qpos=q.astype(state.pipeline_state.qpos.dtype),
                                            qvel=v.astype(state.pipeline_state.qvel.dtype))
        data = data.replace(act=a.astype(data.act.dtype)) if given_act else data
        # With the episode's model where the physics sees its edits (manipulator insert_ball's cup)
        # and its markers placed (point_mass hard's tendons, which its step reads).
        before = env.with_episode(env.compute_derived(data, env.episode_model(env.mjx_model, state.info)), state.info)
        after = env.step(state.replace(pipeline_state=before), action)
        resets = (reset.obs, reset.pipeline_state.qpos, reset.pipeline_state.qvel, episode_info(env, reset))
        return (before.act, before.qacc_warmstart, after.obs, after.reward, 1.0 - after.done, episode_info(env, state),
                resets)

    keys = jax.random.split(jax.random.PRNGKey(seed), len(qpos))
    program = jax.jit(_batched(step), compiler_options=PROOF_COMPILER_OPTIONS)
    act, warmstart, obs, reward, discount, episode, resets = jax.tree.map(
        np.asarray, program(keys, qpos, qvel, act, actions, episode))
    env_actions = np.stack([env.to_env_action(a) for a in np.asarray(actions, np.float64)])
    return Transitions(np.asarray(qpos), np.asarray(qvel), act, warmstart, env_actions, Steps(obs, reward, discount),
                       episode, *resets)


def _batched(fn: Callable) -> Callable:
    """`fn` over a leading axis of its arguments: vmapped, but one after another on the CPU, where two batched
    Cholesky factorizations at once (the reset's and the step's Newton solves) may wait forever."""
    return jax.vmap(fn) if jax.default_backend() != "cpu" else one_after_another(fn)


def action_bounds(env: Env, spec) -> tuple[np.ndarray, np.ndarray]:
    """Where random actions are drawn on dm_control's env: its action spec, but our Box's [-1, 1] where
    the spec is unbounded (lqr's motors have no ctrlrange: +-mjMAXVAL, forces no state survives)."""
    unbounded = (spec.minimum <= -mujoco.mjMAXVAL) | (spec.maximum >= mujoco.mjMAXVAL)
    return (np.where(unbounded, env.action_low, spec.minimum), np.where(unbounded, env.action_high, spec.maximum))


def dm_control_rollouts(env: Env, episodes: int = 4, num_steps: int = 250, seed: int = 0) -> Transitions:
    """States of dm_control's own env of `env`'s task along `episodes` episodes of `num_steps` random
    actions (uniform in its action spec, `action_bounds`; C MuJoCo, float64): each step's start state (qpos, qvel,
    act, warm start, the task's per-episode edits read back by `get_episode`), its action and what
    it returned. Start states for `steps_from` that dm_control itself reached (touches, spins)."""
    theirs = load(env.domain, env.task, seed)
    rng, (low, high) = np.random.default_rng(seed), action_bounds(env, theirs.action_spec())
    record = {name: [] for name in ("qpos", "qvel", "act", "qacc_warmstart", "actions", "obs", "reward", "discount")}
    episode = []
    for _ in range(episodes):
        theirs.reset()
        for _ in range(num_steps):
            physics = theirs.physics
            for name in ("qpos", "qvel", "act", "qacc_warmstart"):
                record[name].append(getattr(physics.data, name).copy())
            episode.append(env.get_episode(physics))
            action = rng.uniform(low, high)
            step = theirs.step(action)
            record["actions"].append(action), record["obs"].append(flatten(step.observation))
            record["reward"].append(step.reward), record["discount"].append(step.discount)
    arrays = {name: np.array(values) for name, values in record.items()}
    return Transitions(arrays["qpos"], arrays["qvel"], arrays["act"], arrays["qacc_warmstart"], arrays["actions"],
                       Steps(arrays["obs"], arrays["reward"], arrays["discount"]),
                       {name: np.array([e[name] for e in episode]) for name in getattr(env, "episode_info", ())})


def put_state(physics, qpos, qvel, act=None, qacc_warmstart=None) -> None:
    """dm_control's physics in the state (qpos, qvel, act) with everything derived from it
    (`mj_forward`, as after dm_control's reset), then the solver's warm start."""
    physics.data.qpos[:] = qpos
    physics.data.qvel[:] = qvel
    if act is not None and physics.model.na:
        physics.data.act[:] = act
    physics.forward()
    if qacc_warmstart is not None:
        physics.data.qacc_warmstart[:] = qacc_warmstart


def dm_control_steps(env: Env, starts: Transitions, seed: int = 0) -> Steps:
    """dm_control's env of `env`'s task, reset (the task's per-episode edits made), put in each
    start state and stepped once with the same action."""
    theirs = load(env.domain, env.task, seed)
    obs, rewards, discounts = [], [], []
    for index, (qpos, qvel, act, warmstart, action) in enumerate(zip(starts.qpos, starts.qvel, starts.act,
                                                                     starts.qacc_warmstart, starts.actions)):
        theirs.reset()
        if starts.episode:
            env.put_episode(theirs.physics, _episode_at(starts.episode, index))
        put_state(theirs.physics, qpos.astype(np.float64), qvel.astype(np.float64), act, warmstart)
        step = theirs.step(action)
        obs.append(flatten(step.observation)), rewards.append(step.reward), discounts.append(step.discount)
    return Steps(np.array(obs), np.array(rewards), np.array(discounts))


def dm_control_observations(env: Env, qpos: np.ndarray, qvel: np.ndarray, episode: Mapping | None = None,
                            seed: int = 0) -> np.ndarray:
    """dm_control's observation of each state (qpos, qvel; `episode`: the task's per-episode edits)
    after its reset's `mj_forward`: what our reset observes must be dm_control's observation of the
    same state."""
    theirs = load(env.domain, env.task, seed)
    found = []
    for index, (q, v) in enumerate(zip(qpos, qvel)):
        theirs.reset()
        if episode:
            env.put_episode(theirs.physics, _episode_at(episode, index))
        put_state(theirs.physics, q.astype(np.float64), v.astype(np.float64))
        found.append(flatten(theirs.task.get_observation(theirs.physics)))
    return np.array(found)


@dataclasses.dataclass
class Comparison:
    """Our steps and dm_control's from the same states and actions, and the error of each step."""

    ours: Steps
    theirs: Steps

    def errors(self) -> dict[str, np.ndarray]:
        """Per step: the largest absolute difference of the observation ("obs"), of the reward and of
        the discount. ValueError if the observations' shapes differ."""
        if self.ours.obs.shape != self.theirs.obs.shape:
            raise ValueError(f"observations of shape {self.ours.obs.shape[1:]} here, {self.theirs.obs.shape[1:]} "
                             "in dm_control's env")
        return {"obs": np.abs(self.ours.obs - self.theirs.obs).max(axis=-1),
                "reward": np.abs(self.ours.reward - self.theirs.reward),
                "discount": np.abs(self.ours.discount - self.theirs.discount)}

    def worst(self) -> dict[str, float]:
        return {name: float(error.max(initial=0.0)) for name, error in self.errors().items()}

    def assert_within(self, atol: Mapping[str, float], rtol: float = 1e-4) -> None:
        """Every observation element and the reward within `atol[name]` (+ `rtol` relative), the
        discount equal."""
        self.errors()
        np.testing.assert_allclose(self.ours.obs, self.theirs.obs, atol=atol["obs"], rtol=rtol, err_msg="observation")
        np.testing.assert_allclose(self.ours.reward, self.theirs.reward, atol=atol["reward"], rtol=rtol,
                                   err_msg="reward")
        np.testing.assert_array_equal(self.ours.discount, self.theirs.discount, err_msg="discount")


def compare_with_dm_control(env: Env | str, num_envs: int = 16, num_steps: int = 20, keep: int = 160,
                            seed: int = 0) -> Comparison:
    """`env` (a `DmControlEnv` task or its registered name) and dm_control's env of the same task
    stepped from the same `keep` states with the same actions (`transitions`, `dm_control_steps`)."""
    env = (make(env) if isinstance(env, str) else env).unwrapped
    starts = transitions(env, num_envs, num_steps, keep, seed)
    return Comparison(starts.steps, dm_control_steps(env, starts, seed))


def compare_readings_with_dm_control(env: Env | str, episodes: int = 8, num_steps: int = 12, seed: int = 0,
                                     perturb: Callable[[Any, np.random.Generator], None] | None = None) -> Comparison:
    """Our observation and reward of dm_control's own physics after each of its steps (its data put on
    the device as it is, `mjx.put_data`: no MJX physics runs, nothing heavy compiles) against what
    dm_control's step returned, along `episodes` episodes of `num_steps` random actions;
    `perturb(physics, rng)`, where given, edits dm_control's state before every third step (spins,
    pushes: states random actions rarely reach) and runs its forward pass. It proves the task's
    readings (sensors, frames, thresholds) on their own, in seconds, for tasks whose physics takes
    minutes to compile; the physics is proven by `steps_from` and `dm_control_steps`."""
    from envs.mjx_env import mjx

    env = (make(env) if isinstance(env, str) else env).unwrapped
    theirs, rng = load(env.domain, env.task, seed), np.random.default_rng(seed)
    low, high = action_bounds(env, theirs.action_spec())
    datas, obs, rewards, discounts = [], [], [], []
    for _ in range(episodes):
        theirs.reset()
        for step in range(num_steps):
            if perturb is not None and step % 3 == 0:
                perturb(theirs.physics, rng)
                theirs.physics.forward()
            result = theirs.step(rng.uniform(low, high))
            # dm_control's step ends in mj_step1, which sizes the constraint rows afresh: their solver-stage fields
            # (efc_b, efc_force, the island arrays) hold the arena's leftovers until the next step computes them,
            # and put_data casts every field. None of them is read here.
            with np.errstate(over="ignore"):
                datas.append(mjx.put_data(env.mj_model, theirs.physics.data.ptr, impl="jax"))
            obs.append(flatten(result.observation)), rewards.append(result.reward), discounts.append(result.discount)
    batch = jax.tree.map(lambda *leaves: np.stack(leaves), *datas)
    ours_obs, ours_reward = jax.jit(jax.vmap(lambda d: (env.observation(d), env.reward(d, None, d))))(batch)
    ours = Steps(np.asarray(ours_obs), np.asarray(ours_reward), np.ones(len(datas)))
    return Comparison(ours, Steps(np.array(obs), np.array(rewards), np.array(discounts)))


def assert_spec_is_dm_controls(name: str):
    """The task `name`'s action bounds (the model's float32 ctrlrange: dm_control's rounded), control
    timestep, substeps, episode length and observation layout are those of dm_control's env of its
    task. Returns (our task, dm_control's env) for further checks."""
    env = make(name).unwrapped
    theirs = load(env.domain, env.task)
    spec = theirs.action_spec()
    np.testing.assert_array_equal(env.action_low, spec.minimum.astype(np.float32))
    np.testing.assert_array_equal(env.action_high, spec.maximum.astype(np.float32))
    assert env.n_substeps == theirs._n_sub_steps
    assert abs(env.dt - theirs.control_timestep()) <= 1e-12 * theirs.control_timestep()
    assert options(name)["episode_length"] == theirs._step_limit == 1000
    observation = theirs.reset().observation
    assert [(key, np.size(value)) for key, value in observation.items()] == list(env.observation_shapes)
    assert env.observation_size == flatten(observation).size
    return env, theirs


def c_mujoco_contacts(mj_model: mujoco.MjModel, qpos: np.ndarray) -> np.ndarray:
    """C MuJoCo's contact count (`mj_forward`'s `ncon`) at each row of `qpos`."""
    data = mujoco.MjData(mj_model)
    counts = []
    for q in qpos:
        data.qpos[:] = q
        mujoco.mj_forward(mj_model, data)
        counts.append(data.ncon)
    return np.array(counts)


def assert_resets_touch_nothing(env: Env, reset_qpos: np.ndarray, raw_qpos: np.ndarray, raw_touching: float = 0.05):
    """dm_control's resets by rejection: C MuJoCo finds no contact at any of our reset states, while
    more than `raw_touching` of the randomiser's raw draws touch (so the loop had draws to reject)."""
    assert c_mujoco_contacts(env.mj_model, reset_qpos).max() == 0
    assert (c_mujoco_contacts(env.mj_model, raw_qpos) > 0).mean() > raw_touching, "the raw draws must touch"


def reset_samples(env: Env | str, count: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """qpos, qvel and the observation of `count` resets of our env (one jitted vmap)."""
    env = (make(env) if isinstance(env, str) else env).unwrapped
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(seed), count))
    return tuple(np.asarray(x) for x in (states.pipeline_state.qpos, states.pipeline_state.qvel, states.obs))


def dm_control_reset_samples(domain: str, task: str, count: int,
                             seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """qpos, qvel and the flattened observation of `count` resets of dm_control's env (seeded once)."""
    theirs = load(domain, task, seed)
    qpos, qvel, obs = [], [], []
    for _ in range(count):
        step = theirs.reset()
        qpos.append(theirs.physics.data.qpos.copy()), qvel.append(theirs.physics.data.qvel.copy())
        obs.append(flatten(step.observation))
    return np.array(qpos), np.array(qvel), np.array(obs)


# The judge's episodes are dm_control's seeds from here on: seeds that neither training (JAX keys)
# nor the proof (dm_control seeds 0 and 1) uses, so a judged policy meets episodes it never saw.
JUDGE_FIRST_SEED = 1_000
# dm_control's lqr tasks have no time limit (their episodes end only at the goal): the judge stops
# them where our TimeLimit does (their rows of `envs.TASKS`), the length of every other task's episode.
ENDLESS_EPISODE_STEPS = 1_000


def returns_on_dm_control(policy, env: Env | str, episodes: int = 10, first_seed: int = JUDGE_FIRST_SEED,
                          max_steps: int | None = None, camera: "Camera | None" = None) -> list[float]:
    """The returns of `policy` on dm_control's own env of `env`'s task (the twin of judging a
    Gymnasium task on Gymnasium's env): episode i is `suite.load(domain, task)` seeded with
    `first_seed + i`, reset, then stepped with `policy(observation)` (the action in the actuators'
    ctrlrange, as `agents.load_policy` gives it) until dm_control's episode ends (1,000 control
    steps; lqr, which has no time limit: at its goal or after `ENDLESS_EPISODE_STEPS`) or after
    `max_steps` control steps. The return sums dm_control's rewards. The observation is dm_control's
    flattened in its order, as our task observes it; for a pixel env (`observation="pixels"`) it is
    dm_control's own picture (`Camera`, or `camera` where given: a subclass that shows other pictures), each
    action held for the env's `action_repeat` steps."""
    env = make(env) if isinstance(env, str) else env
    camera = camera or Camera.of(env)
    repeat = 1 if camera is None else camera.action_repeat
    returns = []
    for episode in range(episodes):
        renders = camera is not None and camera.renders
        theirs = load(env.unwrapped.domain, env.unwrapped.task, first_seed + episode, renders=renders)
        step, total, steps = theirs.reset(), 0.0, 0
        limit = ENDLESS_EPISODE_STEPS if max_steps is None and np.isinf(theirs._step_limit) else max_steps
        observation = flatten(step.observation) if camera is None else camera.reset(theirs.physics)
        while not step.last() and (limit is None or steps < limit):
            action = np.asarray(policy(observation), np.float64)
            for _ in range(repeat):
                step = theirs.step(action)
                total, steps = total + float(step.reward), steps + 1
                if step.last() or steps == limit:
                    break
            observation = flatten(step.observation) if camera is None else camera.observe(theirs.physics)
        returns.append(total)
    return returns


@dataclasses.dataclass
class Camera:
    """A pixel env's observation made by dm_control's renderer (`physics.render`, OpenGL: its
    textures, lights and shadows), as `envs.pixels.Pixels` makes ours: uint8 RGB frames of its camera,
    the last `frame_stack` of them oldest first, a reset's frame repeated."""

    camera: int
    width: int
    height: int
    frame_stack: int
    action_repeat: int
    frames: list = dataclasses.field(default_factory=list)
    renders = True  # whether its pictures are dm_control's (the judge's env is then loaded to render)

    @classmethod
    def of(cls, env: Env) -> "Camera | None":
        """The camera of `env`'s `Pixels` wrapper; None for an env observed by its state."""
        from envs.pixels import Pixels

        while isinstance(env, Wrapper) and not isinstance(env, Pixels):
            env = env.env
        if not isinstance(env, Pixels):
            return None
        if env.depth:
            raise ValueError("returns_on_dm_control: a pixel env with depth=True; dm_control's judge draws RGB "
                             "frames only (train with depth=False to judge on dm_control)")
        return cls(env.cam, env.width, env.height, env.frame_stack, env.action_repeat)

    def picture(self, physics) -> np.ndarray:
        return physics.render(self.height, self.width, camera_id=self.camera)

    def reset(self, physics) -> np.ndarray:
        self.frames = [self.picture(physics)] * self.frame_stack
        return np.concatenate(self.frames, -1)

    def observe(self, physics) -> np.ndarray:
        self.frames = [*self.frames[1:], self.picture(physics)]
        return np.concatenate(self.frames, -1)


DmControlCamera = Camera  # as `envs` offers it (a judge that shows other pictures subclasses it)


class DmEnv(dm_env.Environment):
    """dm_control's TimeSteps from an MJX task: observations as its ordered dicts (keys, shapes, float64),
    actions within its action spec, its time limit a LAST step with discount 1, a termination (lqr at its
    goal) one with discount 0; a step after a LAST one starts the next episode, as dm_control's does.
    Episode i starts from the key `fold_in(PRNGKey(seed), i)`."""

    def __init__(self, env: Env, seed: int = 0):
        task = env.unwrapped
        if not hasattr(task, "domain"):
            raise ValueError(f"to_dm_env: {type(task).__name__} is not a DeepMind Control Suite task; give a dmc-* "
                             "name (envs.names()), or use envs.to_gymnasium for the others")
        self.env, self._key, self._episodes, self._state = env, jax.random.PRNGKey(seed), 0, None
        theirs = load(task.domain, task.task)  # its specs
        self._observation_spec, self._action_spec = theirs.observation_spec(), theirs.action_spec()
        self._reset, self._step = jax.jit(env.reset), jax.jit(env.step)

    def reset(self) -> dm_env.TimeStep:
        self._state = self._reset(jax.random.fold_in(self._key, self._episodes))
        self._episodes += 1
        return dm_env.restart(self._observation())

    def step(self, action) -> dm_env.TimeStep:
        if self._state is None or bool(self._state.done):
            return self.reset()
        unit_action = self.env.from_env_action(np.asarray(action, np.float64))  # in dm_control's bounds, as given
        self._state = self._step(self._state, np.asarray(unit_action, np.float32))
        reward, observation = float(self._state.reward), self._observation()
        if not bool(self._state.done):
            return dm_env.transition(reward, observation)
        if float(self._state.info["truncation"]) > 0:
            return dm_env.truncation(reward, observation)
        return dm_env.termination(reward, observation)

    def _observation(self) -> collections.OrderedDict:
        flat, observation, start = np.asarray(self._state.obs, np.float64), collections.OrderedDict(), 0
        for key, spec in self._observation_spec.items():
            size = int(np.prod(spec.shape))
            observation[key] = flat[start:start + size].reshape(spec.shape).astype(spec.dtype)
            start += size
        return observation

    def observation_spec(self):
        return self._observation_spec

    def action_spec(self):
        return self._action_spec


def to_dm_env(env: Env | str, seed: int = 0, **options) -> DmEnv:
    """A `dmc-*` task (a name, with `envs.make`'s `options`, or an env) as a `dm_env.Environment`."""
    return DmEnv(make(env, **options) if isinstance(env, str) else env, seed)
