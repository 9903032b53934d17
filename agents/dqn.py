"""DQN with uniform or prioritized replay, the whole training loop inside `lax.scan`.

Read top to bottom: config -> transition packing -> train state -> acting and collecting -> the
Q-learning update -> greedy evaluation -> one training chunk -> `train`. `train(config, env, key)`
is pure, jittable and vmaps over seeds; the CLI drives the same chunks from the host.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.flatten_util import ravel_pytree

from agents import device_options, evaluation, fused_mlp
from agents.networks import QNetwork
from agents.replay import PrioritizedReplay, UniformReplay, uniform_from_bits
from envs import Env, wrap_for_training
from envs.ranges import (COUNT, FINITE, NON_NEGATIVE, NON_NEGATIVE_COUNT, POSITIVE, PROBABILITY, OneOf, Range, Valid,
                         check_fields)


@dataclasses.dataclass(frozen=True)
class DQNConfig:
    """Every hyperparameter of a run. The defaults solve CartPole-v1 on both backends."""

    total_steps: int = 50_000  # env steps per seed, summed over its envs
    num_envs: int = 1  # envs stepped in parallel by each agent
    learning_starts: int = 1_000  # random-action steps that fill the buffer before learning
    train_every: int = 1  # env steps (per env) between gradient phases
    gradient_steps: int = 1  # updates per gradient phase
    hidden: tuple[int, ...] = (64, 64)  # the Q-network's layer widths, e.g. 64,64
    dueling: bool = False  # a dueling head (value + advantages)
    learning_rate: float = 2e-3  # Adam's
    max_grad_norm: float | None = 10.0  # gradients clipped to this global norm; None: no clipping
    gamma: float = 0.99  # the discount factor
    double_dqn: bool = True  # the online network picks the next action, the target network values it
    loss: str = "mse"  # "mse" or "huber"
    target_update: str = "polyak"  # "polyak" (every update) or "hard" (copy every target_period updates)
    polyak_tau: float = 0.01  # the target network's Polyak step
    target_period: int = 500  # updates between hard target copies
    epsilon_start: float = 1.0  # epsilon-greedy exploration's first epsilon...
    epsilon_end: float = 0.05  # ...and its last
    exploration_steps: int = 5_000  # steps after learning_starts over which epsilon decays
    replay: str = "uniform"  # "uniform" or "prioritized"
    buffer_size: int = 50_000  # transitions per seed
    batch_size: int = 64  # transitions per update
    priority_alpha: float = 0.6  # prioritized replay's exponent of the TD errors
    priority_beta_start: float = 0.4  # importance-sampling exponent, annealed linearly to 1 over the run
    eval_every: int = 1_000  # env steps between greedy evaluations (a training "chunk")
    eval_episodes: int = 64  # episodes per evaluation
    solve_return: float = 475.0  # greedy mean return that counts as solved

    # Validated before anything compiles; schedules need a step at least (optax's zero-step one is constant).
    RANGES: ClassVar[dict[str, Valid]] = {
        "loss": OneOf(("mse", "huber")), "target_update": OneOf(("polyak", "hard")),
        "replay": OneOf(("uniform", "prioritized")),
        "total_steps": COUNT, "num_envs": COUNT, "learning_starts": NON_NEGATIVE_COUNT, "train_every": COUNT,
        "gradient_steps": COUNT, "learning_rate": POSITIVE, "gamma": PROBABILITY,
        "polyak_tau": Range(0.0, 1.0, low_open=True), "target_period": COUNT, "epsilon_start": PROBABILITY,
        "epsilon_end": PROBABILITY, "exploration_steps": COUNT, "buffer_size": COUNT, "batch_size": COUNT,
        "priority_alpha": NON_NEGATIVE, "priority_beta_start": PROBABILITY, "eval_every": COUNT,
        "eval_episodes": COUNT, "solve_return": FINITE}

    def __post_init__(self):
        check_fields(self, self.RANGES)
        for width in self.hidden:
            COUNT.check(f"DQNConfig.hidden (layer widths {self.hidden})", width)
        if self.max_grad_norm is not None:
            POSITIVE.check("DQNConfig.max_grad_norm (None: no clipping)", self.max_grad_norm)
        if self.learning_starts < self.batch_size:
            raise ValueError(f"DQNConfig.learning_starts must be at least batch_size ({self.batch_size}) so every "
                             f"sample is a real transition, got {self.learning_starts}")
        step = self.num_envs * self.train_every
        if self.eval_every % step:
            raise ValueError(f"DQNConfig.eval_every must be a multiple of num_envs * train_every ({step}), "
                             f"got {self.eval_every}; e.g. {max(step, self.eval_every // step * step)}")
        if self.total_steps < self.eval_every:
            raise ValueError(f"DQNConfig.total_steps must be at least eval_every ({self.eval_every}: training runs "
                             f"in chunks of eval_every steps), got {self.total_steps}; lower eval_every or raise total_steps")

    @property
    def iterations_per_chunk(self) -> int:
        return self.eval_every // (self.num_envs * self.train_every)

    @property
    def num_chunks(self) -> int:
        return max(1, math.ceil(self.total_steps / self.eval_every))

    def rounding(self) -> str:
        """How `total_steps` became whole chunks of `eval_every` ("" when it needed no rounding)."""
        steps = self.num_chunks * self.eval_every
        if steps == self.total_steps:
            return ""
        return (f"total_steps {self.total_steps:,} rounded up to {steps:,} env steps: {self.num_chunks} chunks of "
                f"eval_every {self.eval_every:,}")

    @property
    def chunk_work(self) -> tuple[int, int]:
        """(batched env steps, gradient updates) of one chunk: `agents.run_steps.judge_every`'s cost model."""
        return self.iterations_per_chunk * self.train_every, self.iterations_per_chunk * self.gradient_steps


# ---- what `mjxsuite sweep` may vary within one program: fields only used as numbers, never as shapes ----
SWEEPABLE = ("learning_rate", "gamma", "polyak_tau", "epsilon_start", "epsilon_end", "priority_beta_start")


def stack_hyperparams(cls, configs: list):
    """`cls` (an agent's Hyperparams) of one float32 array per field, one entry per config: a sweep's values."""
    rows = [cls.of(c) for c in configs]
    return cls(*(jnp.asarray([getattr(r, f) for r in rows], jnp.float32) for f in cls._fields))


class Hyperparams(NamedTuple):
    """The numbers `DQN` reads from `SWEEPABLE` fields: floats for one config, float32 arrays in a sweep, with
    optax's double-precision differences precomputed, so a swept agent is bit for bit a run of its config."""

    neg_learning_rate: Any  # optax.scale(-learning_rate)
    gamma: Any
    polyak_tau: Any
    polyak_keep: Any  # 1 - polyak_tau
    epsilon_span: Any  # epsilon_start - epsilon_end
    epsilon_end: Any
    beta_span: Any  # priority_beta_start - 1 (its schedule ends at 1)

    @classmethod
    def of(cls, config: "DQNConfig") -> "Hyperparams":
        return cls(neg_learning_rate=-config.learning_rate, gamma=config.gamma, polyak_tau=config.polyak_tau,
                   polyak_keep=1.0 - config.polyak_tau, epsilon_span=config.epsilon_start - config.epsilon_end,
                   epsilon_end=config.epsilon_end, beta_span=config.priority_beta_start - 1.0)

    stacked = classmethod(stack_hyperparams)


def linear_schedule(span, end, steps: int, count):
    """optax.linear_schedule(end + span, end, steps)(count), its `span` precomputed (`Hyperparams`)."""
    frac = 1 - jnp.clip(count, 0, steps) / steps
    return span * frac + end


# Named configs for `mjxsuite train --preset NAME` (fields set after it still apply).
PRESETS = {
    "default": DQNConfig(),
    # One seed on a CPU, CartPole solved soonest: a larger step, shorter random phase and exploration.
    "quick": DQNConfig(learning_rate=4e-3, learning_starts=500, exploration_steps=2_000, eval_every=500),
    # On a GPU an iteration of 32 envs costs about one env's, so it solves sooner (docs/results.md).
    "many-envs": DQNConfig(num_envs=32, batch_size=512, gradient_steps=4, learning_rate=2e-3, learning_starts=4096,
                           exploration_steps=16_384, eval_every=4096, total_steps=300_000, polyak_tau=0.02),
}


# ---- transitions: one packed float row, so the buffer does one gather per sample ----
class Transition(NamedTuple):
    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    terminated: jax.Array  # 1.0 only when the MDP ended; truncation still bootstraps


def pack(t: Transition) -> jax.Array:
    scalars = jnp.stack([t.action.astype(jnp.float32), t.reward, t.terminated], axis=-1)
    return jnp.concatenate([t.obs, t.next_obs, scalars.astype(t.obs.dtype)], axis=-1)


def unpack(rows: jax.Array, obs_size: int) -> Transition:
    obs, next_obs = rows[:, :obs_size], rows[:, obs_size : 2 * obs_size]
    action, reward, terminated = rows[:, 2 * obs_size], rows[:, 2 * obs_size + 1], rows[:, 2 * obs_size + 2]
    return Transition(obs, action.astype(jnp.int32), reward, next_obs, terminated)


def greedy(q: jax.Array) -> tuple[jax.Array, jax.Array]:
    """`jnp.argmax(q, axis=-1)` and `q` there, as one comparison per action (ties and NaNs as `jnp.argmax`): on
    a GPU XLA's argmax does not vectorise over a short axis, comparisons fuse (docs/bench-gpu.json, "dqn-greedy")."""
    best_action = jnp.zeros(q.shape[:-1], jnp.int32)
    best = q[..., 0]
    for action in range(1, q.shape[-1]):
        value = q[..., action]
        better = (value > best) | (jnp.isnan(value) & ~jnp.isnan(best))
        best_action = jnp.where(better, action, best_action)
        best = jnp.where(better, value, best)
    return best_action, best


class StepNoise(NamedTuple):
    """Random bits (uint32) for one iteration, drawn for a whole chunk at once (XLA:CPU loops per call)."""

    act: jax.Array  # (train_every, 2, num_envs): explore-or-not coin, random action
    sample: jax.Array  # (gradient_steps, batch_size): one per replayed transition


@struct.dataclass
class TrainState:
    params: Any
    target_params: Any
    opt_state: Any  # per parameter leaf, or of the parameters flattened into one vector (`DQN.flat_optimizer`)
    buffer: Any
    env_state: Any
    key: jax.Array
    env_steps: jax.Array  # int32, env steps taken so far (all envs)
    updates: jax.Array  # int32, gradient updates so far
    best_params: Any  # parameters with the best greedy evaluation so far
    best_return: jax.Array
    solve_step: jax.Array  # int32, first env step whose evaluation reached solve_return; -1 before
    hyperparams: Hyperparams | None = None  # a sweep's per-agent values; None: the config's constants


def first_state(params, env_state, key: jax.Array) -> dict:
    """The train-state fields every agent's run starts with: no steps, `params` the best so far, typed as chunks leave them."""
    return dict(env_state=env_state, key=key, env_steps=jnp.zeros((), jnp.int32), best_params=params,
                best_return=jnp.full((), -jnp.inf, jnp.float32), solve_step=jnp.full((), -1, jnp.int32))


# What every agent's chunk adds up (its `CHUNK_TOTALS`), typed so the loop needs no extra trace to learn them.
EPISODE_TOTALS = {"episodes": jnp.float32, "return_sum": jnp.float32, "nan_episodes": jnp.float32,
                  "overflow_contacts": jnp.int32, "overflow_constraints": jnp.int32}


def copy_where(copy: jax.Array, new: Any, old: Any, batch_skips: bool = False) -> Any:
    """`new` where the scalar `copy` is true, else `old`, per leaf. With `batch_skips`, vmapped, a batch where
    no agent copies returns `old` as it is (one `lax.cond`), not rewriting it (hard target updates)."""

    def select(copy, new, old):
        return jax.tree.map(lambda n, o: jnp.where(copy, n, o), new, old)

    if not batch_skips:
        return select(copy, new, old)

    @jax.custom_batching.custom_vmap
    def copied(copy, new, old):
        return select(copy, new, old)

    @copied.def_vmap
    def copied_batched(axis_size, in_batched, copy, new, old):
        copy, new, old = jax.tree.map(lambda x, batched: x if batched else jnp.broadcast_to(x, (axis_size,) + x.shape),
                                      (copy, new, old), tuple(in_batched))
        out = jax.lax.cond(copy.any(), lambda: jax.vmap(select)(copy, new, old), lambda: old)
        return out, jax.tree.map(lambda _: True, out)

    return copied(copy, new, old)


class DQN:
    """The pieces of a DQN run for one env and config; all methods are pure."""

    def __init__(self, config: DQNConfig, env: Env, platform: str | None = None, agents: int = 1):
        """`platform`: whose program shapes to use (`agents.device_options`); `agents`: how many run vmapped."""
        if env.num_actions is None:
            raise ValueError(f"DQN needs a discrete-action env; {env!r} has continuous actions")
        self.config = config
        self.env = env
        self.train_env = wrap_for_training(env, config.num_envs, under_vmap=True)  # train_run vmaps seeds
        self.network = QNetwork(env.num_actions, tuple(config.hidden), config.dueling,
                                transposed_kernel_gradient=device_options.transposed_kernel_gradient(platform))
        # A dueling head (not one MLP) and networks too wide for the kernels (`fused_mlp.fits`) stay in Flax.
        self.fused_network = (device_options.fused_q_network(platform, agents) and not config.dueling
                              and fused_mlp.fits(env.observation_size, config.hidden, env.num_actions))
        self.flat_optimizer = device_options.flat_optimizer(platform)
        self.unroll = device_options.unrolled_inner_loops(platform)
        self.batch_skips_idle_copies = device_options.batch_skips_idle_target_copies(platform)
        clip = [optax.clip_by_global_norm(config.max_grad_norm)] if config.max_grad_norm else []
        # Adam's direction only, scaled by `hyper.neg_learning_rate` as optax.adam would: a sweep traces it.
        self.optimizer = optax.chain(*clip, optax.scale_by_adam())
        vectorized = device_options.vectorized_replay(platform)
        if config.replay == "uniform":
            self.buffer = UniformReplay(config.buffer_size, vectorized=vectorized)
        else:
            self.buffer = PrioritizedReplay(config.buffer_size, alpha=config.priority_alpha, vectorized=vectorized)
        self.hyper = Hyperparams.of(config)

    def with_hyperparams(self, hyper: Hyperparams | None) -> "DQN":
        """This agent (DQN, PPO) reading `hyper` (a sweep agent's traced values) instead of its config's."""
        if hyper is None or hyper is self.hyper:
            return self
        bound = copy.copy(self)
        bound.hyper = hyper
        return bound

    def epsilon(self, count):
        return linear_schedule(self.hyper.epsilon_span, self.hyper.epsilon_end, self.config.exploration_steps, count)

    def beta(self, count):
        return linear_schedule(self.hyper.beta_span, 1.0, self.config.total_steps, count)

    # ---- acting -------------------------------------------------------------
    def q_values(self, params, obs):
        return self.network.apply(params, obs)

    def policy(self, params, obs):
        """The greedy action (one observation or a batch): what `load_policy` acts with."""
        return greedy(self.q_values(params, obs))[0]

    def batch_q_values(self, params, obs):
        """Q-values of many rows per agent (a replayed batch, the judge's episodes): `fused_mlp`'s kernels
        where `fused_network`. Acting, one row per env, keeps Flax (docs/results.md, "Concurrent kernels")."""
        return (fused_mlp.q_values(params, obs, interpret=device_options.on_cpu()) if self.fused_network
                else self.q_values(params, obs))

    def act(self, params, obs, epsilon, bits):
        """Epsilon-greedy actions; `bits` (uint32, `(2, batch)`): whether to explore, and the random action."""
        greedy_action, _ = greedy(self.q_values(params, obs))
        explore = uniform_from_bits(bits[0]) < epsilon
        random = (bits[1] % self.env.num_actions).astype(jnp.int32)
        return jnp.where(explore, random, greedy_action)

    def collect(self, ts: TrainState, epsilon, bits=None) -> tuple[TrainState, dict]:
        """One step of every env into the buffer (faulty steps never); `bits`: `StepNoise.act`, or from `ts.key`."""
        key = ts.key
        if bits is None:
            key, act_key = jax.random.split(key)
            bits = jax.random.bits(act_key, (2, self.config.num_envs), jnp.uint32)
        obs = ts.env_state.obs
        action = self.act(ts.params, obs, epsilon, bits)
        env_state = self.train_env.step(ts.env_state, action)
        info = env_state.info
        terminated = env_state.done * (1.0 - info["truncation"])
        rows = pack(Transition(obs, action, env_state.reward, info["final_obs"], terminated))
        overflow, stats = evaluation.step_stats(info)
        buffer = self.buffer.add(ts.buffer, rows, mask=(info["nan"] == 0) & (overflow == 0))
        ts = ts.replace(buffer=buffer, env_state=env_state, key=key, env_steps=ts.env_steps + self.config.num_envs)
        return ts, stats

    # ---- learning -----------------------------------------------------------
    def td_targets(self, params, target_params, batch: Transition):
        next_q_target = self.batch_q_values(target_params, batch.next_obs)
        if self.config.double_dqn:  # the online net picks, the target net evaluates
            next_action, _ = greedy(self.batch_q_values(params, batch.next_obs))
            next_q = self.taken(next_q_target, next_action)
        else:  # the target net's greedy value: what `taken` of its greedy action gives, for finite values
            _, next_q = greedy(next_q_target)
        return batch.reward + self.hyper.gamma * (1.0 - batch.terminated) * next_q

    def taken(self, q, action):
        """`q[i, action[i]]` as a one-hot product: its gradient a multiply, not a scatter (slow on XLA:CPU)."""
        return (q * jax.nn.one_hot(action, self.env.num_actions, dtype=q.dtype)).sum(-1)

    def loss(self, params, batch: Transition, targets, weights):
        q = self.taken(self.batch_q_values(params, batch.obs), batch.action)
        td_error = q - targets
        per_item = optax.huber_loss(td_error) if self.config.loss == "huber" else td_error**2
        return jnp.mean(weights * per_item), (td_error, q)

    def update(self, ts: TrainState, learning, bits) -> tuple[TrainState, dict]:
        """One gradient step on the batch `bits` (`StepNoise.sample`) picks; with `learning` False (before
        `learning_starts`) computed and thrown away, cheaper than a `lax.cond` on XLA:CPU and under vmap."""
        cfg = self.config
        if cfg.replay == "uniform":
            rows, indices = self.buffer.sample_from_bits(ts.buffer, bits)
            weights = jnp.ones((cfg.batch_size,), jnp.float32)
        else:
            rows, indices, weights = self.buffer.sample_from_bits(ts.buffer, bits, self.beta(ts.env_steps))
        batch = unpack(rows, self.env.observation_size)
        targets = self.td_targets(ts.params, ts.target_params, batch)
        grads, (td_error, q) = jax.grad(self.loss, has_aux=True)(ts.params, batch, targets, weights)

        def keep_unless_learning(new, old):
            return jnp.where(learning, new, old)

        if self.flat_optimizer:  # one flat vector: a few large elementwise kernels (see `agents.device_options`)
            flat_params, unravel = ravel_pytree(ts.params)
            direction, opt_state = self.optimizer.update(ravel_pytree(grads)[0], ts.opt_state, flat_params)
            step = self.hyper.neg_learning_rate * direction
            params = unravel(keep_unless_learning(flat_params + step, flat_params))
        else:
            direction, opt_state = self.optimizer.update(grads, ts.opt_state, ts.params)
            step = jax.tree.map(lambda d: self.hyper.neg_learning_rate * d, direction)
            params = jax.tree.map(lambda p, s: keep_unless_learning(p + s, p), ts.params, step)
        opt_state = jax.tree.map(keep_unless_learning, opt_state, ts.opt_state)
        updates = ts.updates + jnp.asarray(learning, jnp.int32)
        if cfg.target_update == "polyak":
            hyper = self.hyper  # optax.incremental_update's arithmetic, its 1 - tau precomputed
            target_params = jax.tree.map(lambda new, old: hyper.polyak_tau * new + hyper.polyak_keep * old,
                                         params, ts.target_params)
            target_params = jax.tree.map(keep_unless_learning, target_params, ts.target_params)
        else:  # a select (off the CPU, one lax.cond per vmapped batch), not optax.periodic_update's lax.cond
            copy_now = learning & (updates % cfg.target_period == 0)
            target_params = copy_where(copy_now, params, ts.target_params, self.batch_skips_idle_copies)
        buffer = ts.buffer
        if cfg.replay == "prioritized":  # only the priorities change; the stored transitions stay
            new = self.buffer.update_priorities(buffer, indices, jnp.abs(td_error))
            buffer = buffer.replace(**{f: keep_unless_learning(getattr(new, f), getattr(buffer, f))
                                       for f in ("tree", "min_tree", "max_priority")})
        ts = ts.replace(params=params, target_params=target_params, opt_state=opt_state, buffer=buffer, updates=updates)
        return ts, {"loss": jnp.mean(weights * td_error**2), "q": q.mean()}

    # ---- evaluation -----------------------------------------------------------
    def evaluate(self, params, key, num_episodes: int | None = None, record: bool = False):
        """Greedy return of each of `num_episodes` fresh episodes; with `record`, also the first step by step."""
        act = lambda obs: greedy(self.batch_q_values(params, obs))[0]  # noqa: E731
        return evaluation.evaluate(self.env, act, key, num_episodes or self.config.eval_episodes,
                                   jax.ShapeDtypeStruct((), jnp.int32), record)

    # ---- a training run ---------------------------------------------------------
    def fresh_params(self, key: jax.Array):
        """A fresh run's parameters, shaped as `init(key).params`, without envs (`load_policy`'s template)."""
        return self.network.init(jax.random.split(key, 3)[0], jnp.zeros((1, self.env.observation_size)))

    def init(self, key: jax.Array, hyperparams: Hyperparams | None = None) -> TrainState:
        """Fresh parameters, optimizer, buffer and envs; `hyperparams`: a sweep agent's own values."""
        _, env_key, loop_key = jax.random.split(key, 3)
        env_state = self.train_env.reset(env_key)
        params = self.fresh_params(key)
        example = pack(Transition(env_state.obs[0], jnp.int32(0), env_state.reward[0], env_state.obs[0], env_state.reward[0]))
        return TrainState(
            params=params, target_params=params,
            opt_state=self.optimizer.init(ravel_pytree(params)[0] if self.flat_optimizer else params),
            buffer=self.buffer.init(example), updates=jnp.zeros((), jnp.int32), hyperparams=hyperparams,
            **first_state(params, env_state, loop_key))

    def draw_noise(self, key: jax.Array) -> StepNoise:
        """The random bits of every iteration of one chunk (leading axis: iteration)."""
        cfg = self.config
        act_key, sample_key = jax.random.split(key)
        iterations = cfg.iterations_per_chunk
        act = jax.random.bits(act_key, (iterations, cfg.train_every, 2, cfg.num_envs), jnp.uint32)
        return StepNoise(act, jax.random.bits(sample_key, (iterations, cfg.gradient_steps, cfg.batch_size), jnp.uint32))

    def chunk(self, ts: TrainState, record: bool = True) -> tuple[TrainState, dict]:
        """`train_steps`, then `evaluate_and_keep_best`; `record`: its first episode in `metrics["eval_episode"]`."""
        ts, trained, eval_key = self.train_steps(ts)
        ts, judged = self.evaluate_and_keep_best(ts, eval_key, record)
        return ts, {**judged, **trained}

    CHUNK_TOTALS = {**EPISODE_TOTALS, "loss": jnp.float32, "q": jnp.float32, "epsilon": jnp.float32}

    def train_steps(self, ts: TrainState) -> tuple[TrainState, dict, jax.Array]:
        """A chunk's acting and learning: the train state, its metrics and the next evaluation's key."""
        if ts.hyperparams is not None and ts.hyperparams is not self.hyper:  # a sweep agent: its own values
            return self.with_hyperparams(ts.hyperparams).train_steps(ts)
        cfg = self.config

        def iteration(ts, noise: StepNoise):
            epsilon = jnp.where(ts.env_steps < cfg.learning_starts, 1.0, self.epsilon(ts.env_steps - cfg.learning_starts))
            ts, collected = repeat(lambda ts, bits: self.collect(ts, epsilon, bits), ts, noise.act, self.unroll)
            learning = ts.env_steps >= cfg.learning_starts
            ts, learned = repeat(lambda ts, bits: self.update(ts, learning, bits), ts, noise.sample, self.unroll)
            return ts, {**jax.tree.map(jnp.sum, collected), **jax.tree.map(jnp.mean, learned), "epsilon": epsilon}

        key, noise_key, eval_key = jax.random.split(ts.key, 3)
        ts, totals = add_up(self, iteration, ts.replace(key=key), self.draw_noise(noise_key), last=("epsilon",))
        iterations = cfg.iterations_per_chunk
        metrics = {"loss": totals["loss"] / iterations, "q": totals["q"] / iterations,
                   "epsilon": totals["epsilon"], **evaluation.episode_metrics(totals)}  # epsilon: the last one
        return ts, metrics, eval_key

    def evaluate_and_keep_best(self, ts: TrainState, eval_key: jax.Array,
                               record: bool = True) -> tuple[TrainState, dict]:
        """A chunk's greedy evaluation: keeps the best parameters and the step that solved the task."""
        return evaluation.evaluate_and_keep_best(self.with_hyperparams(ts.hyperparams), ts, eval_key, record)


def add_up(agent, iteration, ts, xs, last: tuple[str, ...] = ()):
    """`iteration: (ts, x) -> (ts, stats)` once per row of `xs`, its stats summed (those in `last`: the last)
    into `agent.CHUNK_TOTALS`: running totals, as on a GPU a stacked metric is a kernel per iteration."""

    def step(carry, x):
        ts, totals = carry
        ts, stats = iteration(ts, x)
        if stats.keys() != totals.keys():
            raise KeyError(f"{type(agent).__name__}.CHUNK_TOTALS {sorted(totals)} must name every iteration stat "
                           f"{sorted(stats)}")
        return (ts, {name: (stats[name] if name in last else total + stats[name]).astype(total.dtype)
                     for name, total in totals.items()}), None

    totals = {name: jnp.zeros((), dtype) for name, dtype in agent.CHUNK_TOTALS.items()}
    return jax.lax.scan(step, (ts, totals), xs)[0]


def repeat(step, ts, xs, unroll: bool = False):
    """`step: (ts, x) -> (ts, stats)` once per row of `xs`; stats stacked. No loop for one row, nor with `unroll`."""
    if xs.shape[0] == 1:
        ts, stats = step(ts, xs[0])
        return ts, jax.tree.map(lambda x: x[None], stats)
    return jax.lax.scan(step, ts, xs, unroll=unroll)


def train(config: DQNConfig, env: Env, key: jax.Array):
    """A whole run as one pure function (`evaluation.whole_run`): `(best_params, metrics)`; vmap it for seeds."""
    return evaluation.whole_run(DQN(config, env), key)
