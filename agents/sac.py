"""Soft Actor-Critic, the whole training loop inside `lax.scan`, from Brax's parts.

Read top to bottom: config -> transitions and the parts TD3 shares -> train state -> acting and
collecting -> the SAC update -> one training chunk -> `train`. Built like `agents.dqn`: pure,
jittable, vmapped over seeds; the train state is the whole of one seed, so resuming is exact.
Brax's networks, losses, gradient step, normalizer and optimizers are imported, never copied; the
loop follows `brax.training.agents.sac.train`. Where it differs (truncation bootstraps from the true
final observation, faulty physics never reaches the replay, the first fill is in `init`):
docs/agents.md, "PPO and SAC: Brax's parts, our loop".
"""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from agents import device_options
from agents import evaluation
from agents.dqn import DQN, EPISODE_TOTALS, add_up, first_state
from agents.ppo import PPO, PPOConfig
from agents.replay import UniformReplay
from envs import Env, wrap_for_training
from envs.ranges import COUNT, FINITE, NON_NEGATIVE_COUNT, POSITIVE, PROBABILITY, Range, check_fields

# Brax is imported inside the functions that use it, so `import agents` stays light.

# Brax's trainer: the log temperature's own Adam step size, whatever `learning_rate` is.
ALPHA_LEARNING_RATE = 3e-4


def check_layer_widths(config, *fields: str) -> None:
    """Refuses an empty or non-positive layer width list in each of `fields`."""
    for name in fields:
        widths = getattr(config, name)
        if not widths:
            raise ValueError(f"{type(config).__name__}.{name} needs at least one layer width, got {widths!r}; "
                             "e.g. (64, 64)")
        for width in widths:
            COUNT.check(f"{type(config).__name__}.{name} (layer widths {widths})", width)


def check_prefill(config) -> None:
    """Refuses a first fill that leaves no env steps to train on."""
    if config.prefill_steps >= config.num_timesteps:
        raise ValueError(f"{type(config).__name__}.min_replay_size ({config.min_replay_size}, {config.prefill_steps} "
                         f"env steps over {config.num_envs} envs) must be below num_timesteps "
                         f"({config.num_timesteps}), or no training happens; "
                         "lower min_replay_size or raise num_timesteps")


class ReplayTiming:
    """A replay agent's run in env steps, from its config's num_timesteps, num_envs, min_replay_size and
    num_evals: a first fill, then chunks of iterations that step every env once (SAC's and TD3's)."""

    @property
    def prefill_steps(self) -> int:
        """Env steps of the first fill: `min_replay_size` rounded up to whole batches, as Brax's SAC."""
        return self.prefill_iterations * self.num_envs

    @property
    def prefill_iterations(self) -> int:
        return -(-self.min_replay_size // self.num_envs)

    @property
    def iterations_per_chunk(self) -> int:
        """Brax's `num_training_steps_per_epoch`: the steps after the first fill over the chunks, rounded up."""
        return -(-(self.num_timesteps - self.prefill_steps) // (self.num_chunks * self.num_envs))

    @property
    def eval_every(self) -> int:
        """Env steps per seed in one chunk (so `total_steps >= num_timesteps`)."""
        return self.iterations_per_chunk * self.num_envs

    num_chunks = PPOConfig.num_chunks  # one evaluation after each chunk, as PPO's
    eval_episodes = PPOConfig.eval_episodes

    @property
    def total_steps(self) -> int:
        """Env steps per seed of the whole run: the first fill and every chunk."""
        return self.prefill_steps + self.num_chunks * self.eval_every

    def rounding(self) -> str:
        """How `num_timesteps` became `total_steps` ("" when it needed no rounding)."""
        if self.total_steps == self.num_timesteps:
            return ""
        return (f"num_timesteps {self.num_timesteps:,} rounded up to {self.total_steps:,} env steps: a first fill of "
                f"{self.prefill_steps:,} (min_replay_size over {self.num_envs} envs), then {self.num_chunks} chunks of "
                f"{self.iterations_per_chunk:,} steps of every env")


@dataclasses.dataclass(frozen=True)
class SACConfig(ReplayTiming):
    """Every hyperparameter of a run, named as in `brax.training.agents.sac.train`. After the first fill, each
    iteration steps every env once; the run is `num_evals - 1` chunks, each ended by an evaluation."""

    num_timesteps: int = 100_000  # env steps per seed, summed over its envs, the first fill included
    num_envs: int = 16
    batch_size: int = 256
    grad_updates_per_step: int = 8  # gradient steps per iteration (one step of every env)
    learning_rate: float = 1e-3  # the policy's and the Q networks' Adam
    discounting: float = 0.99
    tau: float = 0.005  # the target Q networks' Polyak step
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    min_replay_size: int = 2_000  # env steps with the untrained policy before learning
    max_replay_size: int = 100_000
    num_evals: int = 6  # Brax's: an evaluation before training, then one after each chunk
    num_eval_envs: int = 64  # episodes per evaluation
    hidden: tuple[int, ...] = (64, 64)  # the policy's and both Q networks' layers
    solve_return: float | None = None  # an evaluation return that counts as solved; None: never

    RANGES: ClassVar[dict[str, Range]] = {
        "num_timesteps": COUNT, "num_envs": COUNT, "batch_size": COUNT, "grad_updates_per_step": COUNT,
        "learning_rate": POSITIVE, "discounting": PROBABILITY, "tau": Range(0.0, 1.0, low_open=True),
        "reward_scaling": POSITIVE, "min_replay_size": NON_NEGATIVE_COUNT, "max_replay_size": COUNT,
        "num_evals": Range(2, integer=True), "num_eval_envs": COUNT}

    def __post_init__(self):
        check_fields(self, self.RANGES)
        check_layer_widths(self, "hidden")
        if self.solve_return is not None:
            FINITE.check("SACConfig.solve_return (None: no threshold)", self.solve_return)
        check_prefill(self)
        need = max(self.batch_size, self.min_replay_size, self.num_envs)
        if self.max_replay_size < need:
            raise ValueError(f"SACConfig.max_replay_size ({self.max_replay_size}) must hold at least batch_size "
                             f"({self.batch_size}), min_replay_size ({self.min_replay_size}) and num_envs "
                             f"({self.num_envs}) transitions; raise it to {need} or more")


# ---- transitions: one packed float row, so the buffer does one gather per sample ----
class Transition(NamedTuple):
    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    discount: jax.Array  # 1 - terminated: truncation still bootstraps, from `next_obs`
    next_obs: jax.Array  # the true final observation at the end of an episode


def pack(t: Transition) -> jax.Array:
    scalars = jnp.stack([t.reward, t.discount], axis=-1).astype(t.obs.dtype)
    return jnp.concatenate([t.obs, t.action.astype(t.obs.dtype), scalars, t.next_obs], axis=-1)


def unpack(rows: jax.Array, obs_size: int, action_size: int) -> Transition:
    a = obs_size + action_size
    return Transition(obs=rows[..., :obs_size], action=rows[..., obs_size:a], reward=rows[..., a],
                      discount=rows[..., a + 1], next_obs=rows[..., a + 2:])


def continuous_setup(agent, config, env: Env) -> None:
    """What SAC and TD3 set up alike: the config, the env (refused without continuous actions), its
    training batch (train_run vmaps seeds) and the observation and action sizes."""
    if env.action_size is None:
        raise ValueError(f"{type(agent).__name__} needs a continuous-action env; {env!r} has {env.num_actions} "
                         "discrete actions (train it with --agent dqn)")
    agent.config, agent.env = config, env
    agent.train_env = wrap_for_training(env, config.num_envs, under_vmap=True)
    agent.obs_size, agent.action_size = env.observation_size, env.action_size


def example_transition(env_state, action_size: int) -> Transition:
    """One transition shaped as the envs' (the first env's): what the buffer is allocated from."""
    obs, reward = env_state.obs[0], env_state.reward[0]
    return Transition(obs, jnp.zeros((action_size,), jnp.float32), reward, reward, obs)


def step_envs(train_env, env_state, action):
    """One step of every env: its new state, the transitions, which may be stored, and the episode stats."""
    obs = env_state.obs
    env_state = train_env.step(env_state, action)
    info = env_state.info
    terminated = env_state.done * (1.0 - info["truncation"])
    steps = Transition(obs, action, env_state.reward, 1.0 - terminated, info["final_obs"])
    overflow, stats = evaluation.step_stats(info)
    return env_state, steps, (info["nan"] == 0) & (overflow == 0), stats


def sample_batches(agent, ts, key: jax.Array, count: int) -> Transition:
    """`count` uniform batches of the config's `batch_size` from `agent`'s buffer (packed rows, or transitions
    as stored), leading axis: batch."""
    batch_size = agent.config.batch_size
    rows, _ = agent.buffer.sample_from_bits(ts.buffer, jax.random.bits(key, (count * batch_size,), jnp.uint32))
    rows = jax.tree.map(lambda x: x.reshape(count, batch_size, *x.shape[1:]), rows)
    return rows if isinstance(rows, Transition) else unpack(rows, agent.obs_size, agent.action_size)


def polyak(target, online, tau: float):
    """The target's Polyak step towards the online parameters."""
    return jax.tree.map(lambda old, new: old * (1 - tau) + new * tau, target, online)


def prefill(collect, ts, key: jax.Array, iterations: int):
    """The replay's first fill, `iterations` steps of every env (`collect`); the first evaluation's baseline."""
    if iterations:
        ts, _ = jax.lax.scan(collect, ts, jax.random.split(key, iterations))
    return ts.replace(best_params=ts.params)


def brax_transitions(t: Transition):
    """`t` as Brax's losses read it; `truncation` 0, as the next observation is the true one."""
    from brax.training import types
    return types.Transition(observation=t.obs, action=t.action, reward=t.reward, discount=t.discount,
                            next_observation=t.next_obs,
                            extras={"state_extras": {"truncation": jnp.zeros_like(t.reward)}, "policy_extras": {}})


@struct.dataclass
class TrainState:
    params: Any  # (normalizer state, policy params): Brax's inference params, what `policy` and checkpoints take
    q_params: Any
    target_q_params: Any
    log_alpha: jax.Array  # log of the entropy temperature
    policy_opt_state: Any
    q_opt_state: Any
    alpha_opt_state: Any
    buffer: Any
    env_state: Any
    key: jax.Array
    env_steps: jax.Array  # int32, env steps taken so far (all envs, the first fill included)
    best_params: Any  # `params` with the best evaluation so far
    best_return: jax.Array
    solve_step: jax.Array  # int32, first env step whose evaluation reached solve_return; -1 before
    hyperparams: Any = None  # a sweep's per-agent values, as `DQN`'s; SAC has none yet


class SAC:
    """The pieces of a SAC run for one env and config; all methods are pure."""

    def __init__(self, config: SACConfig, env: Env, platform: str | None = None, agents: int = 1):
        """`platform`: whose program shapes to use (`agents.device_options`); `agents`: unused."""
        from brax.training import gradients, types
        from brax.training.acme import running_statistics
        from brax.training.agents.sac import losses as sac_losses
        from brax.training.agents.sac import networks as sac_networks
        continuous_setup(self, config, env)
        # As Brax's trainer builds them (`benchmarks.brax_trainers.network_factory`): `params` is Brax's SAC's.
        normalize = running_statistics.normalize if config.normalize_observations else types.identity_observation_preprocessor
        self.networks = sac_networks.make_sac_networks(self.obs_size, self.action_size,
                                                       preprocess_observations_fn=normalize,
                                                       hidden_layer_sizes=tuple(config.hidden))
        self.make_policy = sac_networks.make_inference_fn(self.networks)
        self.policy_optimizer = optax.adam(config.learning_rate)
        self.q_optimizer = optax.adam(config.learning_rate)
        self.alpha_optimizer = optax.adam(ALPHA_LEARNING_RATE)
        alpha_loss, critic_loss, actor_loss = sac_losses.make_losses(
            self.networks, reward_scaling=config.reward_scaling, discounting=config.discounting,
            action_size=self.action_size)
        self.alpha_update = gradients.gradient_update_fn(alpha_loss, self.alpha_optimizer, pmap_axis_name=None)
        self.critic_update = gradients.gradient_update_fn(critic_loss, self.q_optimizer, pmap_axis_name=None)
        self.actor_update = gradients.gradient_update_fn(actor_loss, self.policy_optimizer, pmap_axis_name=None)
        self.buffer = UniformReplay(config.max_replay_size, vectorized=device_options.vectorized_replay(platform))

    # ---- acting -------------------------------------------------------------
    def policy(self, params, obs):
        """The deterministic policy (tanh of the mean); `params` = (normalizer state, policy params)."""
        return self.make_policy(params, deterministic=True)(obs, None)[0]

    def collect(self, ts: TrainState, key: jax.Array) -> tuple[TrainState, dict]:
        """One step of every env with the stochastic policy into the buffer; the normalizer sees its observations."""
        from brax.training.acme import running_statistics
        normalizer, policy_params = ts.params
        obs = ts.env_state.obs
        action, _ = self.make_policy(ts.params)(obs, key)
        env_state, steps, valid, stats = step_envs(self.train_env, ts.env_state, action)
        buffer = self.buffer.add(ts.buffer, pack(steps), mask=valid)
        normalizer = running_statistics.update(normalizer, obs)
        ts = ts.replace(params=(normalizer, policy_params), buffer=buffer, env_state=env_state,
                        env_steps=ts.env_steps + self.config.num_envs)
        return ts, stats

    # ---- learning -----------------------------------------------------------
    def learn(self, ts: TrainState, batch: Transition, keys: tuple[jax.Array, jax.Array, jax.Array]):
        """One gradient step on `batch` (Brax's `sgd_step`), `keys` the temperature's, the critic's and
        the actor's: each from the parameters before this step, then the target's Polyak average."""
        key_alpha, key_critic, key_actor = keys
        normalizer, policy_params = ts.params
        transitions = brax_transitions(batch)
        alpha_loss, log_alpha, alpha_opt_state = self.alpha_update(
            ts.log_alpha, policy_params, normalizer, transitions, key_alpha, optimizer_state=ts.alpha_opt_state)
        alpha = jnp.exp(ts.log_alpha)
        critic_loss, q_params, q_opt_state = self.critic_update(
            ts.q_params, policy_params, normalizer, ts.target_q_params, alpha, transitions, key_critic,
            optimizer_state=ts.q_opt_state)
        actor_loss, policy_params, policy_opt_state = self.actor_update(
            policy_params, normalizer, ts.q_params, alpha, transitions, key_actor,
            optimizer_state=ts.policy_opt_state)
        target_q_params = polyak(ts.target_q_params, q_params, self.config.tau)
        ts = ts.replace(params=(normalizer, policy_params), q_params=q_params, target_q_params=target_q_params,
                        log_alpha=log_alpha, policy_opt_state=policy_opt_state, q_opt_state=q_opt_state,
                        alpha_opt_state=alpha_opt_state)
        return ts, {"critic_loss": critic_loss, "actor_loss": actor_loss, "alpha_loss": alpha_loss,
                    "alpha": jnp.exp(log_alpha)}

    def update(self, ts: TrainState, key: jax.Array) -> tuple[TrainState, dict]:
        """`grad_updates_per_step` gradient steps, each on its own uniform batch from the buffer."""
        cfg = self.config
        sample_key, sgd_key = jax.random.split(key)
        batches = sample_batches(self, ts, sample_key, cfg.grad_updates_per_step)

        def sgd_step(carry, batch):
            ts, key = carry
            key, key_alpha, key_critic, key_actor = jax.random.split(key, 4)  # as Brax's sgd_step
            ts, stats = self.learn(ts, batch, (key_alpha, key_critic, key_actor))
            return (ts, key), stats

        if cfg.grad_updates_per_step == 1:
            (ts, _), stats = sgd_step((ts, sgd_key), jax.tree.map(lambda x: x[0], batches))
            return ts, stats
        (ts, _), stats = jax.lax.scan(sgd_step, (ts, sgd_key), batches)
        return ts, jax.tree.map(jnp.mean, stats)

    evaluate = PPO.evaluate  # the deterministic policy's returns

    # ---- a training run ---------------------------------------------------------
    def fresh_params(self, key: jax.Array):
        """A fresh run's parameters, shaped as `init(key).params`, without envs (`load_policy`'s template)."""
        from brax.training.acme import running_statistics, specs
        return (running_statistics.init_state(specs.Array((self.obs_size,), jnp.dtype("float32"))),
                self.networks.policy_network.init(jax.random.split(key, 5)[0]))

    def init(self, key: jax.Array, hyperparams: Any = None) -> TrainState:
        """Fresh networks (as Brax's), optimizers, temperature 1, envs, and the replay's first fill
        (Brax's `prefill_replay_buffer`). `hyperparams`: DQN's sweep argument; SAC traces none yet."""
        if hyperparams is not None:
            raise ValueError("SAC cannot sweep settings within one program yet (no field of SACConfig is traced); "
                             "run one `mjxsuite train --agent sac` per value instead")
        _, q_key, env_key, fill_key, loop_key = jax.random.split(key, 5)
        normalizer, policy_params = self.fresh_params(key)
        q_params = self.networks.q_network.init(q_key)
        log_alpha = jnp.asarray(0.0, jnp.float32)
        env_state = self.train_env.reset(env_key)
        ts = TrainState(
            params=(normalizer, policy_params), q_params=q_params, target_q_params=q_params, log_alpha=log_alpha,
            policy_opt_state=self.policy_optimizer.init(policy_params), q_opt_state=self.q_optimizer.init(q_params),
            alpha_opt_state=self.alpha_optimizer.init(log_alpha),
            buffer=self.buffer.init(pack(example_transition(env_state, self.action_size))),
            **first_state((normalizer, policy_params), env_state, loop_key))
        return prefill(self.collect, ts, fill_key, self.config.prefill_iterations)

    chunk = DQN.chunk  # `train_steps`, then `evaluate_and_keep_best`

    CHUNK_TOTALS = {**EPISODE_TOTALS, "critic_loss": jnp.float32, "actor_loss": jnp.float32,
                    "alpha_loss": jnp.float32, "alpha": jnp.float32}

    def train_steps(self, ts: TrainState) -> tuple[TrainState, dict, jax.Array]:
        """A chunk's acting and learning: the train state, its metrics and the next evaluation's key."""
        cfg = self.config

        def iteration(ts, key):
            act_key, learn_key = jax.random.split(key)
            ts, collected = self.collect(ts, act_key)
            ts, learned = self.update(ts, learn_key)
            return ts, {**collected, **learned}

        key, loop_key, eval_key = jax.random.split(ts.key, 3)
        ts, totals = add_up(self, iteration, ts.replace(key=key), jax.random.split(loop_key, cfg.iterations_per_chunk))
        iterations = cfg.iterations_per_chunk
        losses = {name: totals[name] / iterations for name in ("critic_loss", "actor_loss", "alpha_loss", "alpha")}
        return ts, {**losses, **evaluation.episode_metrics(totals)}, eval_key

    def evaluate_and_keep_best(self, ts: TrainState, eval_key: jax.Array,
                               record: bool = False) -> tuple[TrainState, dict]:
        """A chunk's deterministic evaluation: keeps the best parameters and the step that solved the task."""
        return evaluation.evaluate_and_keep_best(self, ts, eval_key, record)


def train(config: SACConfig, env: Env, key: jax.Array):
    """A whole run as one pure function (`evaluation.whole_run`): `(best_params, metrics)`; vmap it for seeds."""
    return evaluation.whole_run(SAC(config, env), key)
