"""PPO as the suite's own agent: Brax's PPO, its loop ours and its parts Brax's (docs/agents.md).

Read top to bottom: config -> train state -> acting -> learning -> evaluation -> one training chunk
-> `train`. The training step is Brax's, its keys split the same way, so from the same state it gives
Brax's parameters; around it, a seed's whole state is one pytree, so a run advances chunk by chunk
inside `jit`, vmaps over seeds and resumes exactly. The interface is `agents.dqn.DQN`'s.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
from typing import Any, Callable, ClassVar, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import struct

from agents import device_options, evaluation
from agents.dqn import DQN, EPISODE_TOTALS, first_state, stack_hyperparams
from agents.networks import canonical_convs
from envs import Env, wrap_for_training
from envs.ranges import COUNT, FINITE, NON_NEGATIVE, POSITIVE, PROBABILITY, Range, check_fields


CNN_FIELDS = ("cnn_output_channels", "cnn_kernel_size", "cnn_stride")


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Every hyperparameter of a run, named as in `brax.training.agents.ppo.train`. The `num_evals - 1` chunks
    split `num_timesteps`, rounded up to whole training steps of `batch_size * num_minibatches *
    unroll_length` env steps. The defaults suit small tasks on a CPU (agents/brax_defaults.py)."""

    num_timesteps: int = 1_000_000  # env steps per seed, rounded up (see `total_steps`)
    num_envs: int = 64  # envs stepped in parallel by each agent
    unroll_length: int = 16  # env steps per unroll
    batch_size: int = 64  # unrolls per minibatch
    num_minibatches: int = 16  # minibatches per collected batch
    num_updates_per_batch: int = 4  # passes over each collected batch
    learning_rate: float = 1e-3  # Adam's
    entropy_cost: float = 1e-3  # the entropy bonus's weight in the loss
    discounting: float = 0.97  # the discount factor
    gae_lambda: float = 0.95  # GAE's lambda
    clipping_epsilon: float = 0.3  # the policy ratio's clip
    max_grad_norm: float | None = None  # None: no clipping
    reward_scaling: float = 1.0  # rewards are multiplied by this in the loss
    normalize_observations: bool = True  # state vectors only: camera images are scaled to [0, 1] instead
    num_evals: int = 11  # Brax's count, its evaluation of the untrained policy included
    num_eval_envs: int = 64  # episodes per evaluation
    policy_hidden: tuple[int, ...] = (64, 64)  # the policy network's layer widths, e.g. 64,64
    value_hidden: tuple[int, ...] = (64, 64)  # the value network's layer widths
    # On camera images, the convolutions before each MLP, one entry per layer (default: Nature DQN's, for 64x64).
    cnn_output_channels: tuple[int, ...] = (32, 64, 64)  # camera images: each convolution's channels
    cnn_kernel_size: tuple[int, ...] = (8, 4, 3)  # ...kernel size
    cnn_stride: tuple[int, ...] = (4, 2, 1)  # ...and stride
    solve_return: float | None = None  # a deterministic mean return that counts as solved; not Brax's

    RANGES: ClassVar[dict[str, Range]] = {
        "num_timesteps": COUNT, "num_envs": COUNT, "unroll_length": COUNT, "batch_size": COUNT,
        "num_minibatches": COUNT, "num_updates_per_batch": COUNT, "learning_rate": POSITIVE,
        "entropy_cost": NON_NEGATIVE, "discounting": PROBABILITY, "gae_lambda": PROBABILITY,
        "clipping_epsilon": POSITIVE, "reward_scaling": POSITIVE, "num_evals": Range(2, integer=True),
        "num_eval_envs": COUNT}

    def __post_init__(self):
        check_fields(self, self.RANGES)
        for field in ("policy_hidden", "value_hidden", *CNN_FIELDS):
            widths = getattr(self, field)
            if not widths:
                raise ValueError(f"PPOConfig.{field} needs at least one layer's value, got {widths!r}")
            for width in widths:
                COUNT.check(f"PPOConfig.{field} (one value per layer: {widths})", width)
        layers = {field: len(getattr(self, field)) for field in CNN_FIELDS}
        if len(set(layers.values())) > 1:
            raise ValueError(f"PPOConfig's convolution layers disagree: {layers}; give "
                             f"{', '.join(CNN_FIELDS)} one value per layer each, e.g. --cnn_output_channels 32,64 "
                             "--cnn_kernel_size 8,4 --cnn_stride 4,2")
        if not isinstance(self.normalize_observations, bool):
            raise ValueError(f"PPOConfig.normalize_observations must be True or False, got {self.normalize_observations!r}")
        if self.max_grad_norm is not None:
            POSITIVE.check("PPOConfig.max_grad_norm (None: no clipping)", self.max_grad_norm)
        if self.solve_return is not None:
            FINITE.check("PPOConfig.solve_return (None: no threshold)", self.solve_return)
        unrolls = self.batch_size * self.num_minibatches
        if unrolls % self.num_envs:
            fits = [n for n in range(1, unrolls + 1) if unrolls % n == 0 and n <= self.num_envs]
            raise ValueError(f"PPOConfig.num_envs ({self.num_envs}) must divide batch_size * num_minibatches "
                             f"({self.batch_size} * {self.num_minibatches} = {unrolls}): each training step unrolls "
                             f"every env the same number of times, as Brax's PPO requires; e.g. num_envs={fits[-1]}")

    @property
    def env_steps_per_training_step(self) -> int:
        return self.batch_size * self.num_minibatches * self.unroll_length

    @property
    def unrolls_per_training_step(self) -> int:
        return self.batch_size * self.num_minibatches // self.num_envs

    @property
    def num_chunks(self) -> int:
        return self.num_evals - 1

    @property
    def training_steps_per_chunk(self) -> int:
        """Brax's `num_training_steps_per_epoch`: num_timesteps split over the chunks, rounded up."""
        return -(-self.num_timesteps // (self.num_chunks * self.env_steps_per_training_step))

    @property
    def eval_every(self) -> int:
        return self.training_steps_per_chunk * self.env_steps_per_training_step

    @property
    def total_steps(self) -> int:
        return self.num_chunks * self.eval_every

    @property
    def eval_episodes(self) -> int:
        return self.num_eval_envs

    def rounding(self) -> str:
        """How `num_timesteps` became `total_steps` ("" when it needed no rounding)."""
        if self.total_steps == self.num_timesteps:
            return ""
        return (f"num_timesteps {self.num_timesteps:,} rounded up to {self.total_steps:,} env steps: "
                f"{self.num_chunks} chunks of {self.training_steps_per_chunk} training steps of "
                f"{self.env_steps_per_training_step:,} env steps (batch_size {self.batch_size} x num_minibatches "
                f"{self.num_minibatches} x unroll_length {self.unroll_length})")


# Brax's vision networks convolve each observation entry whose key starts with "pixels/": ours goes under this key.
PIXELS_KEY = "pixels/camera"


def one_seed_at_a_time(policy: Callable) -> Callable:
    """`policy(params, obs)`, whose vmap (the judge's over seeds, `judge_seed_axis`) runs one seed after another:
    vmapped, image networks' convolutions would be grouped ones, which a GPU runs slowly (`default_seed_axis`)."""

    def act(params, obs):
        leaves, treedef = jax.tree.flatten(params)  # the rule's batch mask of Brax's `UInt64` count holds no booleans

        @jax.custom_batching.custom_vmap
        def on_leaves(leaves, obs):
            return policy(jax.tree.unflatten(treedef, leaves), obs)

        @on_leaves.def_vmap
        def per_seed(axis_size, in_batched, leaves, obs):
            spread = lambda x, batched: x if batched else jnp.broadcast_to(x, (axis_size, *jnp.shape(x)))  # noqa: E731
            leaves, obs = [spread(*pair) for pair in zip(leaves, in_batched[0])], spread(obs, in_batched[1])
            return jax.lax.map(lambda args: on_leaves(*args), (leaves, obs)), True

        return on_leaves(leaves, obs)

    return act


def image_shape(env: Env) -> tuple[int, int, int] | None:
    """(height, width, channels) where `env` observes camera images (`envs.pixels.Pixels`), else None."""
    shape = getattr(env, "observation_shape", None)
    return tuple(shape) if shape is not None and len(shape) == 3 else None


def check_image_fits(config: PPOConfig, shape: tuple[int, int, int]) -> None:
    """Refuse convolutions that shrink `shape`'s images to nothing (they run without padding)."""
    height, width = shape[:2]
    for layer, (kernel, stride) in enumerate(zip(config.cnn_kernel_size, config.cnn_stride)):
        if min(height, width) < kernel:
            raise ValueError(
                f"PPOConfig.cnn_kernel_size {config.cnn_kernel_size}: the {kernel}x{kernel} kernel of convolution "
                f"{layer + 1} does not fit the {height}x{width} map that {shape[0]}x{shape[1]} images leave it "
                f"(cnn_stride {config.cnn_stride}, no padding); use larger images (--env-opt width=64 --env-opt "
                "height=64) or fewer, smaller kernels (e.g. --cnn_output_channels 16 --cnn_kernel_size 3 --cnn_stride 1)")
        height, width = (height - kernel) // stride + 1, (width - kernel) // stride + 1


def make_vision_networks(shape: tuple[int, int, int], action_size: int, config: PPOConfig, canonical: bool = False):
    """Brax's vision PPO networks for uint8 images of `shape`: each network's own convolutions, flattened
    rather than pooled (where things are matters), initialised as MuJoCo Playground's CartpoleBalance
    vision recipe; frames go to [0, 1] inside the networks, so rollouts store uint8 (docs/agents.md).
    `canonical`: applied through `agents.networks.canonical_convs` (for XLA:CPU)."""
    from brax.training import networks as brax_networks
    from brax.training.agents.ppo import networks_vision
    check_image_fits(config, shape)
    orthogonal = jax.nn.initializers.orthogonal
    vision = networks_vision.make_ppo_networks_vision(
        {PIXELS_KEY: shape}, action_size, policy_hidden_layer_sizes=config.policy_hidden,
        value_hidden_layer_sizes=config.value_hidden, cnn_output_channels=config.cnn_output_channels,
        cnn_kernel_size=config.cnn_kernel_size, cnn_stride=config.cnn_stride, cnn_padding="valid",
        cnn_global_pool="none", cnn_kernel_init_fn=orthogonal, cnn_kernel_init_kwargs={"scale": math.sqrt(2)},
        output_kernel_init_fn=orthogonal, output_kernel_init_kwargs={"scale": 0.01})

    def on_frames(network):
        def apply(normalizer_params, params, frames):
            with canonical_convs() if canonical else contextlib.nullcontext():
                return network.apply(normalizer_params, params, {PIXELS_KEY: frames.astype(jnp.float32) / 255.0})

        return brax_networks.FeedForwardNetwork(init=network.init, apply=apply)

    return vision.replace(policy_network=on_frames(vision.policy_network), value_network=on_frames(vision.value_network))


# ---- what a sweep may vary within one program, as `agents.dqn.SWEEPABLE` ----
# A swept agent equals a separate run up to float rounding (XLA simplifies around a constant
# differently). clipping_epsilon is left out: Brax's `1 - clipping_epsilon` rounds differently in float32.
SWEEPABLE = ("learning_rate", "entropy_cost", "discounting", "gae_lambda", "reward_scaling")


class Hyperparams(NamedTuple):
    """The numbers `PPO` reads from `SWEEPABLE` fields, as `agents.dqn.Hyperparams`."""

    neg_learning_rate: Any  # optax.adam's last step, scale(-learning_rate)
    entropy_cost: Any
    discounting: Any
    gae_lambda: Any
    reward_scaling: Any

    @classmethod
    def of(cls, config: PPOConfig) -> "Hyperparams":
        return cls(neg_learning_rate=-config.learning_rate, entropy_cost=config.entropy_cost,
                   discounting=config.discounting, gae_lambda=config.gae_lambda, reward_scaling=config.reward_scaling)

    stacked = classmethod(stack_hyperparams)


def scale_by_adam(b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> optax.GradientTransformation:
    """`optax.scale_by_adam()`, its divisions pinned behind an optimization barrier: XLA rewrites them differently
    when vmapped, so seed i of a vmapped run is a one-seed run bit for bit only so (test_ppo.py)."""
    adam = optax.scale_by_adam(b1, b2, eps)

    def update(grads, state, params=None):
        del params
        mu = optax.tree.update_moment(grads, state.mu, b1, 1)
        nu = optax.tree.update_moment_per_elem_norm(grads, state.nu, b2, 2)
        count = optax.safe_increment(state.count)
        c1, c2 = 1 - b1**count, 1 - b2**count

        def direction(m, v):
            d1, d2 = jax.lax.optimization_barrier((jnp.broadcast_to(c1, m.shape), jnp.broadcast_to(c2, v.shape)))
            return m / (d1 * (jnp.sqrt(v / d2) + eps))

        return jax.tree.map(direction, mu, nu), optax.ScaleByAdamState(count=count, mu=mu, nu=nu)

    return optax.GradientTransformation(adam.init, update)


@struct.dataclass
class TrainState:
    """The whole state of one seed: saving this pytree and loading it back resumes exactly."""

    params: Any  # (normalizer state, policy params, value params): the tuple Brax's ppo.train returns
    opt_state: Any  # Adam's, over PPONetworkParams(policy, value)
    env_state: Any  # the `num_envs` training envs, mid-episode
    key: jax.Array
    env_steps: jax.Array  # int32, env steps taken so far (all envs)
    best_params: Any  # the params with the best deterministic evaluation so far
    best_return: jax.Array
    solve_step: jax.Array  # int32, first env step whose evaluation reached solve_return; -1 before
    hyperparams: Hyperparams | None = None  # a sweep's per-agent values; None: the config's constants


# Env info entries an unroll keeps beside Brax's `truncation`: episode statistics and physics faults.
STAT_FIELDS = ("episode_done", "last_return", "nan")


class PPO:
    """The pieces of a PPO run for one env and config; all methods are pure."""

    def __init__(self, config: PPOConfig, env: Env, platform: str | None = None, agents: int = 1):
        """`env`: one env with its time limit (`envs.make`); `platform` and `agents`: DQN's, unused."""
        from brax.training.acme import running_statistics
        from brax.training.agents.ppo import networks as ppo_networks
        if env.action_size is None:
            raise ValueError(f"PPO acts with a tanh-Gaussian policy and needs a continuous-action env; "
                             f"{env!r} has {env.num_actions} discrete actions (train it with DQN)")
        self.config = config
        self.env = env
        self.train_env = wrap_for_training(env, config.num_envs, under_vmap=True)  # train_run vmaps seeds
        self.image_shape = image_shape(env)  # None: a state vector
        if self.image_shape is None:
            preprocess = running_statistics.normalize if config.normalize_observations else (lambda obs, _: obs)
            # As Brax's trainer makes them (`benchmarks.brax_trainers.network_factory`): the params are Brax's.
            self.networks = ppo_networks.make_ppo_networks(
                env.observation_size, env.action_size, preprocess_observations_fn=preprocess,
                policy_hidden_layer_sizes=config.policy_hidden, value_hidden_layer_sizes=config.value_hidden)
        else:
            self.networks = make_vision_networks(self.image_shape, env.action_size, config,
                                                 device_options.canonical_conv_gradients(platform))
        self.make_policy = ppo_networks.make_inference_fn(self.networks)
        # Adam's direction only, scaled by `hyper.neg_learning_rate` (as `agents.dqn.DQN`'s).
        clip = [optax.clip_by_global_norm(config.max_grad_norm)] if config.max_grad_norm is not None else []
        self.optimizer = optax.chain(*clip, scale_by_adam())
        self.hyper = Hyperparams.of(config)

    with_hyperparams = DQN.with_hyperparams  # this PPO reading a sweep agent's traced values

    # ---- acting -------------------------------------------------------------
    def policy(self, params, obs) -> jax.Array:
        """The deterministic action in [-1, 1] (tanh of the Gaussian's mean), as Brax's `deterministic_eval`."""
        return self.make_policy(params, deterministic=True)(obs, None)[0]

    def collect(self, ts: TrainState, key: jax.Array):
        """One training step's unrolls of every env with the stochastic policy, as Brax's: the envs' new
        state and the transitions, leading axes (unrolls * num_envs, unroll_length)."""
        from brax.training import acting
        cfg = self.config
        policy = self.make_policy(ts.params)
        fields = ("truncation", *STAT_FIELDS) + (("overflow",) if "overflow" in ts.env_state.info else ())

        def unroll(carry, _):
            env_state, key = carry
            key, next_key = jax.random.split(key)
            env_state, data = acting.generate_unroll(self.train_env, env_state, policy, key, cfg.unroll_length,
                                                     extra_fields=fields)
            return (env_state, next_key), data

        (env_state, _), data = jax.lax.scan(unroll, (ts.env_state, key), None, length=cfg.unrolls_per_training_step)
        # (unrolls, time, envs) -> (unrolls * envs, time): one row per unroll of one env, as in Brax.
        data = jax.tree.map(lambda x: jnp.swapaxes(x, 1, 2), data)
        return env_state, jax.tree.map(lambda x: jnp.reshape(x, (-1,) + x.shape[2:]), data)

    def without_faults(self, data):
        """The transitions for the learner and their episode statistics. A step whose physics failed is
        marked a truncation, so Brax's GAE never teaches the value that its state is terminal."""
        extras = data.extras["state_extras"]
        overflow, stats = evaluation.step_stats(extras)
        fault = (extras["nan"] > 0) | (overflow > 0)
        truncation = jnp.where(fault, 1.0, extras["truncation"]).astype(extras["truncation"].dtype)
        return data._replace(extras={**data.extras, "state_extras": {"truncation": truncation}}), stats

    # ---- learning -----------------------------------------------------------
    def loss_and_grad(self, nets, normalizer, minibatch, key):
        """Brax's PPO loss (`compute_ppo_loss`) and its gradient with respect to `nets` (PPONetworkParams)."""
        from brax.training import gradients
        from brax.training.agents.ppo import losses as ppo_losses
        loss = functools.partial(
            ppo_losses.compute_ppo_loss, ppo_network=self.networks, entropy_cost=self.hyper.entropy_cost,
            discounting=self.hyper.discounting, reward_scaling=self.hyper.reward_scaling,
            gae_lambda=self.hyper.gae_lambda, clipping_epsilon=self.config.clipping_epsilon)
        return gradients.loss_and_pgrad(loss, pmap_axis_name=None, has_aux=True)(nets, normalizer, minibatch, key)

    def minibatch_step(self, carry, minibatch, normalizer):
        opt_state, nets, key = carry
        key, key_loss = jax.random.split(key)
        (_, metrics), grads = self.loss_and_grad(nets, normalizer, minibatch, key_loss)
        direction, opt_state = self.optimizer.update(grads, opt_state)
        nets = optax.apply_updates(nets, jax.tree.map(lambda d: self.hyper.neg_learning_rate * d, direction))
        return (opt_state, nets, key), metrics

    def sgd_step(self, carry, _, data, normalizer):
        """One pass over the batch in `num_minibatches` shuffled minibatches."""
        opt_state, nets, key = carry
        key, key_perm, key_grad = jax.random.split(key, 3)
        minibatches = jax.tree.map(
            lambda x: jnp.reshape(jax.random.permutation(key_perm, x), (self.config.num_minibatches, -1) + x.shape[1:]),
            data)
        (opt_state, nets, _), metrics = jax.lax.scan(
            functools.partial(self.minibatch_step, normalizer=normalizer), (opt_state, nets, key_grad), minibatches)
        return (opt_state, nets, key), metrics

    def training_step(self, ts: TrainState) -> tuple[TrainState, dict]:
        """Brax's training step, its keys split as Brax's: collect, update the normalizer, then
        `num_updates_per_batch` passes of minibatch SGD."""
        from brax.training.acme import running_statistics
        from brax.training.agents.ppo import losses as ppo_losses
        cfg = self.config
        key_sgd, key_unroll, key = jax.random.split(ts.key, 3)
        env_state, data = self.collect(ts, key_unroll)
        data, stats = self.without_faults(data)
        normalizer, policy, value = ts.params
        if self.image_shape is None:  # images have no normalizer (`make_vision_networks`)
            normalizer = running_statistics.update(normalizer, data.observation)  # before SGD, as Brax does
        nets = ppo_losses.PPONetworkParams(policy=policy, value=value)
        (opt_state, nets, _), metrics = jax.lax.scan(
            functools.partial(self.sgd_step, data=data, normalizer=normalizer), (ts.opt_state, nets, key_sgd),
            None, length=cfg.num_updates_per_batch)
        ts = ts.replace(params=(normalizer, nets.policy, nets.value), opt_state=opt_state, env_state=env_state,
                        key=key, env_steps=ts.env_steps + cfg.env_steps_per_training_step)
        losses = {name: jnp.mean(metrics[name]) for name in ("total_loss", "policy_loss", "v_loss", "entropy_loss")}
        return ts, {**stats, **losses}

    # ---- evaluation -----------------------------------------------------------
    def evaluate(self, params, key, num_episodes: int | None = None, record: bool = False):
        """The deterministic policy's return of each of `num_episodes` fresh episodes (default: the
        config's); with `record`, also the first episode step by step (`agents.evaluation.evaluate`)."""
        policy = one_seed_at_a_time(self.policy) if device_options.learns_from_images(self) else self.policy
        return evaluation.evaluate(self.env, lambda obs: policy(params, obs), key,
                                   num_episodes or self.config.eval_episodes,
                                   jax.ShapeDtypeStruct((self.env.action_size,), jnp.float32), record)

    # ---- a training run ---------------------------------------------------------
    def init_params(self, policy_key: jax.Array, value_key: jax.Array):
        """Fresh (normalizer, policy, value) params, as Brax's; on images the normalizer stays empty."""
        from brax.training.acme import running_statistics, specs
        normalized = 0 if self.image_shape is not None else self.env.observation_size
        obs_spec = specs.Array((normalized,), jnp.dtype("float32"))
        return (running_statistics.init_state(obs_spec), self.networks.policy_network.init(policy_key),
                self.networks.value_network.init(value_key))

    def fresh_params(self, key: jax.Array):
        """A fresh run's parameters, shaped as `init(key).params`, without envs (`load_policy`'s template)."""
        return self.init_params(*jax.random.split(jax.random.split(key, 3)[0]))

    def init(self, key: jax.Array, hyperparams: Hyperparams | None = None) -> TrainState:
        """Fresh parameters, optimizer and envs; `hyperparams`: a sweep agent's own values."""
        from brax.training.agents.ppo import losses as ppo_losses
        _, env_key, loop_key = jax.random.split(key, 3)
        params = self.fresh_params(key)
        return TrainState(
            params=params, opt_state=self.optimizer.init(ppo_losses.PPONetworkParams(policy=params[1], value=params[2])),
            hyperparams=hyperparams, **first_state(params, self.train_env.reset(env_key), loop_key))

    chunk = DQN.chunk  # `train_steps`, then `evaluate_and_keep_best`

    def train_steps(self, ts: TrainState) -> tuple[TrainState, dict, jax.Array]:
        """A chunk's training steps: the train state, its metrics and the following evaluation's key."""
        return evaluation.whole_chunk(self.chunk_loop(ts), ts)

    CHUNK_TOTALS = {**EPISODE_TOTALS, "total_loss": jnp.float32, "policy_loss": jnp.float32, "v_loss": jnp.float32,
                    "entropy_loss": jnp.float32}

    def chunk_loop(self, ts: TrainState) -> evaluation.ChunkLoop:
        """A chunk's training steps as pieces (`evaluation.ChunkLoop`), which `agents.run` may split."""
        if ts.hyperparams is not None and ts.hyperparams is not self.hyper:
            return self.with_hyperparams(ts.hyperparams).chunk_loop(ts)
        steps = self.config.training_steps_per_chunk

        def start(ts):
            key, steps_key, eval_key = jax.random.split(ts.key, 3)
            return ts.replace(key=steps_key), {"key": key, "eval_key": eval_key}

        def finish(ts, pending, totals):
            metrics = {"loss": totals["total_loss"] / steps,
                       **{name: totals[name] / steps for name in ("policy_loss", "v_loss", "entropy_loss")},
                       **evaluation.episode_metrics(totals)}
            return ts.replace(key=pending["key"]), metrics

        return evaluation.ChunkLoop(steps, start, self.training_step, finish, self.CHUNK_TOTALS)

    evaluate_and_keep_best = DQN.evaluate_and_keep_best  # keeps the best parameters and the step that solved


def train(config: PPOConfig, env: Env, key: jax.Array):
    """A whole run as one pure function (`evaluation.whole_run`): `(best_params, metrics)`; vmap it for seeds."""
    return evaluation.whole_run(PPO(config, env), key)
