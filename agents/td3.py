"""FastTD3 (Seo et al. 2025, arXiv 2505.22642): TD3 at GPU scale, the whole loop inside `lax.scan`.

Read top to bottom: config -> networks and C51's projection -> n-step rows -> train state -> acting
and collecting -> the critic's and the actor's losses -> one update -> one training chunk -> `train`.
Built like `agents.sac` (pure, jittable, vmapped over seeds, resumed exactly) from its shared parts.
The recipe (many envs, twin C51 critics with clipped double Q, delayed actor updates without a target
actor, per-env exploration noise, AdamW, optional bf16 matmuls) and where it differs from FastTD3's
code: docs/agents.md, "TD3: FastTD3's recipe". What the networks read and how replay keeps it is the object
`self.inputs` (`agents.td3_inputs`): state vectors, or camera images with DrQ-v2's parts ("TD3 from pixels").
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any, ClassVar

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from agents import evaluation
from agents.dqn import DQN, EPISODE_TOTALS, add_up, copy_where, first_state
from agents.ppo import image_shape, scale_by_adam
from agents.sac import (SAC, ReplayTiming, Transition, check_layer_widths, check_prefill, continuous_setup,
                        example_transition, polyak, prefill, step_envs)
from agents.td3_inputs import COMPUTE_DTYPES, inputs_for
from envs import Env
from envs.ranges import (COUNT, FINITE, NON_NEGATIVE, NON_NEGATIVE_COUNT, POSITIVE, PROBABILITY, OneOf, Range, Valid,
                         check_fields)

SATURATED_ACTION = 0.99  # an action component this near its bound counts as saturated (`actor_saturation`)


@dataclasses.dataclass(frozen=True)
class TD3Config(ReplayTiming):
    """Every hyperparameter of a run, timed as SAC's (`agents.sac.ReplayTiming`). The defaults suit small tasks on a
    CPU; FastTD3's own (for a GPU) are in the comments and in `agents/brax_defaults.py`'s TD3 rows."""

    num_timesteps: int = 100_000  # env steps per seed, summed over its envs, the first fill included
    num_envs: int = 16  # FastTD3: 128 (HumanoidBench), 1,024 (Playground), 4,096 (IsaacLab)
    batch_size: int = 256  # FastTD3: 32,768
    num_updates: int = 4  # gradient steps per iteration; FastTD3: 2
    policy_frequency: int = 2  # critic updates per actor update (TD3's delay)
    actor_learning_rate: float = 3e-4
    critic_learning_rate: float = 3e-4
    weight_decay: float = 0.1  # AdamW's, both networks
    max_grad_norm: float = 0.0  # clip each network's gradient to this global norm; 0: no clipping (FastTD3's default)
    discounting: float = 0.99
    tau: float = 0.1  # the target critics' Polyak step (FastTD3's; TD3's was 0.005)
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    policy_noise: float = 0.001  # target policy smoothing: the next action's noise std
    noise_clip: float = 0.5  # ...clipped to +-noise_clip
    std_min: float = 0.001  # per-env exploration noise std, drawn in [std_min, std_max]
    std_max: float = 0.4
    # Each env's noise as AR(1): c times its last step's plus sqrt(1 - c**2) times a fresh normal (the same std, for about
    # 1 / (1 - c) steps; 0: white, FastTD3's): it explores further ("Pink noise is all you need", ICLR 2023).
    noise_correlation: float = 0.0
    num_atoms: int = 101  # the distributional critic's support
    v_min: float = -250.0
    v_max: float = 250.0
    use_cdq: bool = True  # clipped double Q
    num_steps: int = 1  # n-step returns (FastTD3's num_steps; 3 in its CheetahRun, 8 in its IsaacLab humanoids)
    init_scale: float = 0.01  # std of the actor's last layer at initialisation
    # The actor's loss adds this times its pre-tanh outputs' mean square (rlkit's SAC: 1e-3; FastTD3: 0). At a bound
    # tanh's gradient vanishes, so the critic's cannot pull a saturated actor back; this term can.
    pre_tanh_penalty: float = 0.0
    actor_hidden: tuple[int, ...] = (128, 64, 32)  # FastTD3: (512, 256, 128)
    critic_hidden: tuple[int, ...] = (256, 128, 64)  # FastTD3: (1024, 512, 256)
    critic_layer_norm: bool = False  # LayerNorm before each critic ReLU (FastTD3's authors suggest it for DMC)
    # From camera images (`--env-opt observation=pixels`), DrQ-v2's: each sampled image shifted by up to this many
    # pixels, its edges repeated (0: not shifted), and each network's trunk, the encoder's features to this many.
    augment_pad: int = 4
    feature_size: int = 50
    compute_dtype: str = "float32"  # "bfloat16": the networks' matmuls in bf16 (FastTD3's AMP), params float32
    encoder_dtype: str = "float32"  # from camera images, the encoder's convolutions ("bfloat16": as compute_dtype's)
    min_replay_size: int = 1_024  # env steps with the untrained actor and its noise before learning
    uniform_first_fill: bool = False  # those steps' actions uniform over [-1, 1] instead (DrQ-v2's num_expl_steps)
    max_replay_size: int = 100_000  # transitions per seed
    num_evals: int = 6  # as SACConfig's: one evaluation after each of num_evals - 1 chunks
    num_eval_envs: int = 64  # episodes per evaluation
    solve_return: float | None = None  # an evaluation return that counts as solved; None: never

    RANGES: ClassVar[dict[str, Valid]] = {
        "num_timesteps": COUNT, "num_envs": COUNT, "batch_size": COUNT, "num_updates": COUNT,
        "policy_frequency": COUNT, "num_steps": COUNT, "actor_learning_rate": POSITIVE, "critic_learning_rate": POSITIVE,
        "weight_decay": NON_NEGATIVE, "max_grad_norm": NON_NEGATIVE, "discounting": PROBABILITY,
        "tau": Range(0.0, 1.0, low_open=True), "reward_scaling": POSITIVE, "policy_noise": NON_NEGATIVE,
        "noise_clip": NON_NEGATIVE, "std_min": NON_NEGATIVE, "std_max": NON_NEGATIVE,
        "noise_correlation": Range(0.0, 0.999),
        "num_atoms": Range(2, integer=True), "v_min": FINITE, "v_max": FINITE, "init_scale": POSITIVE,
        "pre_tanh_penalty": NON_NEGATIVE, "augment_pad": NON_NEGATIVE_COUNT, "feature_size": COUNT,
        "compute_dtype": OneOf(COMPUTE_DTYPES), "encoder_dtype": OneOf(COMPUTE_DTYPES),
        "min_replay_size": NON_NEGATIVE_COUNT, "max_replay_size": COUNT, "num_evals": Range(2, integer=True),
        "num_eval_envs": COUNT}

    def __post_init__(self):
        check_fields(self, self.RANGES)
        check_layer_widths(self, "actor_hidden", "critic_hidden")
        if self.std_min > self.std_max:
            raise ValueError(f"TD3Config.std_min ({self.std_min}) must not exceed std_max ({self.std_max}); "
                             "swap them, or set them equal for one noise scale")
        if self.v_min >= self.v_max:
            raise ValueError(f"TD3Config.v_min ({self.v_min}) must be below v_max ({self.v_max}): the critic's "
                             "support; set them around the task's discounted returns (reward_scaling included)")
        if self.solve_return is not None:
            FINITE.check("TD3Config.solve_return (None: no threshold)", self.solve_return)
        check_prefill(self)
        need = max(self.min_replay_size, self.num_envs)
        if self.max_replay_size < need:
            raise ValueError(f"TD3Config.max_replay_size ({self.max_replay_size}) must hold at least "
                             f"min_replay_size ({self.min_replay_size}) and num_envs ({self.num_envs}) "
                             f"transitions; raise it to {need} or more")

    @property
    def actor_updates_per_chunk(self) -> int:
        return self.iterations_per_chunk * self.num_updates // self.policy_frequency


# ---- networks: FastTD3's MLPs (ReLU), the actor's tanh head, the critic's atom logits (DrQ-v2's encoder and
# its trunk from camera images: `agents.td3_inputs`) ----
def _dense(features: int, dtype, **kwargs) -> nn.Dense:
    # PyTorch's default layer init (FastTD3's): U(+-1/sqrt(fan_in)) kernels.
    kwargs.setdefault("kernel_init", nn.initializers.variance_scaling(1 / 3, "fan_in", "uniform"))
    return nn.Dense(features, dtype=dtype, param_dtype=jnp.float32, **kwargs)


def _trunk(features: jax.Array, size: int, dtype) -> jax.Array:
    """DrQ-v2's trunk over the encoder's features (size 0: none, state observations): Dense, LayerNorm, tanh."""
    return jnp.tanh(nn.LayerNorm(dtype=dtype)(_dense(size, dtype)(features))) if size else features


class Actor(nn.Module):
    action_size: int
    hidden: tuple[int, ...]
    init_scale: float
    dtype: Any = jnp.float32
    trunk: int = 0  # `_trunk`'s size

    @nn.compact
    def __call__(self, obs: jax.Array, with_pre_tanh: bool = False) -> jax.Array | tuple[jax.Array, jax.Array]:
        x = _trunk(obs, self.trunk, self.dtype)
        for width in self.hidden:
            x = nn.relu(_dense(width, self.dtype)(x))
        # A small last layer: the untrained actor acts near zero, and exploration is the noise's.
        head = _dense(self.action_size, self.dtype, kernel_init=nn.initializers.normal(self.init_scale))
        pre_tanh = head(x).astype(jnp.float32)
        return (jnp.tanh(pre_tanh), pre_tanh) if with_pre_tanh else jnp.tanh(pre_tanh)


class DistributionalQ(nn.Module):
    num_atoms: int
    hidden: tuple[int, ...]
    dtype: Any = jnp.float32
    layer_norm: bool = False
    trunk: int = 0  # `_trunk`'s size

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([_trunk(obs, self.trunk, self.dtype), action], axis=-1)
        for width in self.hidden:
            x = _dense(width, self.dtype)(x)
            x = nn.relu(nn.LayerNorm(dtype=self.dtype)(x) if self.layer_norm else x)
        return _dense(self.num_atoms, self.dtype)(x).astype(jnp.float32)  # logits over the atoms


def project(probs: jax.Array, reward: jax.Array, discount: jax.Array, support: jax.Array) -> jax.Array:
    """C51's projection (Bellemare et al. 2017) of `probs` (batch, atoms) over `support`, shifted to `reward +
    discount * z` and clipped, back onto the atoms: each mass split between its two neighbours by distance."""
    v_min, v_max, atoms = support[0], support[-1], support.shape[0]
    shifted = jnp.clip(reward[:, None] + discount[:, None] * support[None, :], v_min, v_max)
    position = (shifted - v_min) / ((v_max - v_min) / (atoms - 1))
    lower = jnp.clip(jnp.floor(position), 0, atoms - 1)
    upper_share = position - lower  # 0 on an atom, so the clipped upper neighbour gets nothing there
    lower, upper = lower.astype(jnp.int32), jnp.minimum(lower.astype(jnp.int32) + 1, atoms - 1)

    def one(p, lo, up, share):
        return jnp.zeros(atoms, p.dtype).at[lo].add(p * (1 - share)).at[up].add(p * share)

    return jax.vmap(one)(probs, lower, upper, upper_share)


def n_step_rows(steps: Transition, ended: jax.Array, valid: jax.Array, discounting: float):
    """Each env's n-step transition from its window of one-step transitions (leading axes: n steps, oldest first,
    then envs) and their `ended` and `valid` flags (n, envs): rewards discounted up to the first step that ended
    its episode, that step's next observation and `discounting**k * (1 - terminated)`. Returns the transitions
    and whether each may be stored."""
    alive = jnp.cumprod(jnp.concatenate([jnp.ones_like(ended[:1]), 1.0 - ended[:-1]]), axis=0)  # before an end
    powers = jnp.broadcast_to(discounting ** jnp.arange(ended.shape[0], dtype=ended.dtype)[:, None], ended.shape)
    last = (alive.sum(0) - 1).astype(jnp.int32)  # the step the transition ends with
    pick = jax.vmap(lambda column, k: column[k], in_axes=(1, 0))  # each env's step `last`
    reward = jnp.where(alive > 0, steps.reward, 0.0)  # a step after the end is another episode's: maybe NaN
    row = Transition(obs=steps.obs[0], action=steps.action[0], reward=(powers * reward).sum(0),
                     discount=pick(powers, last) * pick(steps.discount, last), next_obs=pick(steps.next_obs, last))
    return row, (alive * (1.0 - valid)).sum(0) == 0


@struct.dataclass
class TrainState:
    params: Any  # (normalizer state, actor params): what `policy` and checkpoints take (`inputs.split`)
    critic_params: Any  # the twin critics, stacked on a leading axis of 2 (`inputs.split`)
    target_critic_params: Any  # the twins' Polyak averages (the encoder has none: DrQ-v2's)
    actor_opt_state: Any
    critic_opt_state: Any
    noise_scale: jax.Array  # (num_envs,): each env's exploration noise std
    buffer: Any
    env_state: Any
    key: jax.Array
    env_steps: jax.Array  # int32, env steps taken so far (all envs, the first fill included)
    best_params: Any  # `params` with the best evaluation so far
    best_return: jax.Array
    solve_step: jax.Array  # int32, first env step whose evaluation reached solve_return; -1 before
    noise: Any = None  # with noise_correlation > 0: each env's unit-std AR(1) noise, (num_envs, action_size)
    window: Any = None  # with num_steps > 1: each env's last num_steps transitions and flags (`n_step_rows`)
    hyperparams: Any = None  # a sweep's per-agent values, as `DQN`'s; TD3 has none yet


def _adamw(learning_rate: float, weight_decay: float, max_grad_norm: float) -> optax.GradientTransformation:
    """AdamW, its Adam divisions pinned as PPO's (`agents.ppo.scale_by_adam`), so vmapped seeds match."""
    clip = [optax.clip_by_global_norm(max_grad_norm)] if max_grad_norm > 0 else []
    return optax.chain(*clip, scale_by_adam(), optax.add_decayed_weights(weight_decay),
                       optax.scale_by_learning_rate(learning_rate))


class TD3:
    """The pieces of a FastTD3 run for one env and config; all methods are pure."""

    def __init__(self, config: TD3Config, env: Env, platform: str | None = None, agents: int = 1):
        """`platform` and `agents`: as `agents.sac.SAC`'s."""
        continuous_setup(self, config, env)
        dtype = COMPUTE_DTYPES[config.compute_dtype]
        self.image_shape = image_shape(env)  # camera images: `device_options` maps their seeds
        self.inputs = inputs_for(config, env, self.obs_size, self.action_size, platform)  # state or camera images
        self.actor = Actor(self.action_size, tuple(config.actor_hidden), config.init_scale, dtype, self.inputs.trunk)
        self.critic = DistributionalQ(config.num_atoms, tuple(config.critic_hidden), dtype, config.critic_layer_norm,
                                      self.inputs.trunk)
        self.support = jnp.linspace(config.v_min, config.v_max, config.num_atoms, dtype=jnp.float32)
        self.actor_optimizer = _adamw(config.actor_learning_rate, config.weight_decay, config.max_grad_norm)
        self.critic_optimizer = _adamw(config.critic_learning_rate, config.weight_decay, config.max_grad_norm)

    def twin_logits(self, critic_params, obs, action):
        """Both critics' atom logits, (2, batch, atoms)."""
        return jax.vmap(lambda p: self.critic.apply(p, obs, action))(critic_params)

    def twin_values(self, probs):
        return (probs * self.support).sum(-1)

    # ---- acting -------------------------------------------------------------
    def policy(self, params, obs):
        """The actor's action in [-1, 1]; `params` = (normalizer state, actor params)."""
        normalizer, actor_params = params
        actor, encoder = self.inputs.split(actor_params, "actor")
        return self.actor.apply(actor, self.inputs.features(normalizer, encoder, obs))

    def collect(self, ts: TrainState, key: jax.Array, uniform: bool = False) -> tuple[TrainState, dict]:
        """One step of every env with the actor and each env's noise (redrawn as its episode ends), as `SAC.collect`;
        `uniform`: with actions uniform over [-1, 1] instead."""
        cfg = self.config
        noise_key, scale_key = jax.random.split(key)
        (normalizer, actor_params), obs = ts.params, ts.env_state.obs
        if uniform:
            action = jax.random.uniform(noise_key, (cfg.num_envs, self.action_size), minval=-1.0, maxval=1.0)
        else:
            noise = jax.random.normal(noise_key, (cfg.num_envs, self.action_size))
            if ts.noise is not None:
                c = cfg.noise_correlation
                noise = c * ts.noise + (1.0 - c * c) ** 0.5 * noise
                ts = ts.replace(noise=noise)
            action = jnp.clip(self.policy(ts.params, obs) + noise * ts.noise_scale[:, None], -1.0, 1.0)
        env_state, frames, valid, stats = step_envs(self.train_env, ts.env_state, action)
        steps, window = self.inputs.indexed(ts.buffer, frames), ts.window
        if cfg.num_steps > 1:
            newest = (steps, env_state.done.astype(jnp.float32), valid.astype(jnp.float32))
            window = jax.tree.map(lambda old, new: jnp.concatenate([old[1:], new[None]]), window, newest)
            steps, valid = n_step_rows(*window, cfg.discounting)
            valid &= ts.env_steps >= (cfg.num_steps - 1) * cfg.num_envs  # the window holds num_steps steps
        buffer = self.inputs.store(ts.buffer, steps, frames, env_state.done, valid)
        normalizer = self.inputs.observed(normalizer, obs)
        fresh = jax.random.uniform(scale_key, (cfg.num_envs,), minval=cfg.std_min, maxval=cfg.std_max)
        ts = ts.replace(params=(normalizer, actor_params), buffer=buffer, env_state=env_state, window=window,
                        noise_scale=jnp.where(env_state.done > 0, fresh, ts.noise_scale),
                        env_steps=ts.env_steps + cfg.num_envs)
        return ts, stats

    # ---- the losses -----------------------------------------------------------
    def critic_loss(self, critic_params, ts: TrainState, batch: Transition, key: jax.Array):
        """Cross entropy of each critic against the target critics' projected `r + gamma * discount *
        Z(s', a')`, a' the actor's smoothed next action; clipped double Q: the lower mean's projection.
        Aux: (the target's mean value, the features of `batch.obs`, which the actor's step reads)."""
        cfg = self.config
        normalizer, actor_params = ts.params
        twins, encoder = self.inputs.split(critic_params, "twins")
        obs = self.inputs.features(normalizer, encoder, batch.obs)
        next_obs = jax.lax.stop_gradient(self.inputs.features(normalizer, encoder, batch.next_obs))  # DrQ-v2's
        smoothing = jnp.clip(jax.random.normal(key, batch.action.shape) * cfg.policy_noise, -cfg.noise_clip, cfg.noise_clip)
        next_action = jnp.clip(self.actor.apply(self.inputs.split(actor_params, "actor")[0], next_obs) + smoothing, -1, 1)
        next_probs = jax.nn.softmax(self.twin_logits(ts.target_critic_params, next_obs, next_action))
        reward, discount = batch.reward * cfg.reward_scaling, batch.discount * cfg.discounting
        target = jax.vmap(lambda p: project(p, reward, discount, self.support))(next_probs)
        if cfg.use_cdq:
            values = self.twin_values(target)
            lower = jnp.where((values[0] < values[1])[:, None], target[0], target[1])
            target = jnp.stack([lower, lower])
        target = jax.lax.stop_gradient(target)
        log_probs = jax.nn.log_softmax(self.twin_logits(twins, obs, batch.action))
        loss = -(target * log_probs).sum(-1).mean(-1).sum()  # the two critics' losses, summed
        return loss, (self.twin_values(target[0]).mean(), obs)

    def actor_loss(self, actor, ts: TrainState, obs: jax.Array):
        """Minus the mean value of the actor's actions on the features `obs` (the lower twin's with clipped double
        Q), plus its penalty; and the share of the actions' components at their bounds (a saturated actor's
        tanh passes no gradient: such a seed stands still, docs/agents.md)."""
        twins = self.inputs.split(ts.critic_params, "twins")[0]
        action, pre_tanh = self.actor.apply(actor, obs, with_pre_tanh=True)
        values = self.twin_values(jax.nn.softmax(self.twin_logits(twins, obs, action)))
        value = values.min(0) if self.config.use_cdq else values.mean(0)
        penalty = self.config.pre_tanh_penalty  # 0 (the default) leaves the term out of the program
        loss = (penalty * jnp.square(pre_tanh).mean() if penalty else 0.0) - value.mean()
        return loss, jnp.mean(jnp.abs(action) > SATURATED_ACTION)

    # ---- learning -----------------------------------------------------------
    def step_actor(self, ts: TrainState, obs: jax.Array) -> tuple[TrainState, tuple]:
        """The actor's step on the features `obs` of the critics' step (from images: the encoder before it; DrQ-v2's)."""
        normalizer, actor_params = ts.params
        actor, encoder = self.inputs.split(actor_params, "actor")
        loss_and_grads = jax.value_and_grad(self.actor_loss, has_aux=True)
        (loss, saturation), grads = loss_and_grads(actor, ts, jax.lax.stop_gradient(obs))
        updates, opt_state = self.actor_optimizer.update(grads, ts.actor_opt_state, actor)
        actor_params = self.inputs.joined(optax.apply_updates(actor, updates), encoder, "actor")
        return ts.replace(params=(normalizer, actor_params), actor_opt_state=opt_state), (loss, saturation)

    def learn(self, ts: TrainState, batch: Transition, key: jax.Array, actor_turn: jax.Array):
        """One update on `batch`: the critics (and the encoder), the actor on `actor_turn` (the same for every
        seed), the targets. Camera images are shifted first (`agents.td3_inputs.ImageInputs.augmented`)."""
        batch = self.inputs.augmented(batch, jax.random.fold_in(key, 1))
        (critic_loss, (target_q, obs)), grads = jax.value_and_grad(self.critic_loss, has_aux=True)(
            ts.critic_params, ts, batch, key)
        updates, opt_state = self.critic_optimizer.update(grads, ts.critic_opt_state, ts.critic_params)
        critic_params = optax.apply_updates(ts.critic_params, updates)
        actor = self.inputs.split(ts.params[1], "actor")[0]  # acting on the encoder the critics trained
        params = (ts.params[0], self.inputs.joined(actor, self.inputs.split(critic_params, "twins")[1], "actor"))
        ts = ts.replace(params=params, critic_params=critic_params, critic_opt_state=opt_state)
        no_step = lambda ts, _: (ts, (jnp.zeros(()), jnp.zeros(())))  # noqa: E731
        ts, (actor_loss, saturation) = jax.lax.cond(actor_turn, self.step_actor, no_step, ts, obs)
        target = polyak(ts.target_critic_params, self.inputs.split(ts.critic_params, "twins")[0], self.config.tau)
        return ts.replace(target_critic_params=target), {"critic_loss": critic_loss, "actor_loss": actor_loss,
                                                         "actor_saturation": saturation, "target_q": target_q}

    LEARNED = ("params", "critic_params", "target_critic_params", "actor_opt_state", "critic_opt_state")

    def sample(self, ts: TrainState, key: jax.Array) -> tuple[Transition, jax.Array | None]:
        """`num_updates` uniform batches, and whether any draw may be learned from (None: every one may)."""
        cfg = self.config
        bits = jax.random.bits(key, (cfg.num_updates * cfg.batch_size,), jnp.uint32)
        batch, learnable = self.inputs.draw(ts.buffer, bits)
        return jax.tree.map(lambda x: x.reshape(cfg.num_updates, cfg.batch_size, *x.shape[1:]), batch), learnable

    def update(self, ts: TrainState, key: jax.Array, iteration: jax.Array) -> tuple[TrainState, dict]:
        """`num_updates` updates on uniform batches, on the actor's clock by `iteration` (its index in the chunk)."""
        cfg = self.config
        sample_key, noise_key = jax.random.split(key)
        batches, learnable = self.sample(ts, sample_key)
        counts = iteration * cfg.num_updates + jnp.arange(cfg.num_updates)

        def one_update(ts, inputs):
            batch, key, count = inputs
            return self.learn(ts, batch, key, count % cfg.policy_frequency == cfg.policy_frequency - 1)

        learned, stats = jax.lax.scan(one_update, ts, (batches, jax.random.split(noise_key, cfg.num_updates), counts))
        if learnable is not None:  # no draw could be learned from: the networks stay as they were
            kept = {name: getattr(ts, name) for name in self.LEARNED}
            learned = learned.replace(**copy_where(learnable, {name: getattr(learned, name) for name in kept}, kept))
        return learned, {"critic_loss": stats["critic_loss"].mean(), "actor_loss": stats["actor_loss"].sum(),
                         "actor_saturation": stats["actor_saturation"].sum(), "target_q": stats["target_q"].mean()}

    evaluate = SAC.evaluate  # the deterministic policy's returns

    # ---- a training run ---------------------------------------------------------
    def fresh_networks(self, key: jax.Array):
        """`init(key)`'s `params` and critic params, the encoder's in both."""
        actor_key, critic_key = jax.random.split(key, 6)[:2]
        normalizer, encoder, obs0 = self.inputs.init(jax.random.fold_in(key, 1))
        actor = self.actor.init(actor_key, obs0)
        twins = jax.vmap(lambda k: self.critic.init(k, obs0, jnp.zeros((1, self.action_size))))(
            jax.random.split(critic_key))
        return (normalizer, self.inputs.joined(actor, encoder, "actor")), self.inputs.joined(twins, encoder, "twins")

    def fresh_params(self, key: jax.Array):
        """A fresh run's parameters, shaped as `init(key).params`, without envs (`load_policy`'s template)."""
        return self.fresh_networks(key)[0]

    def init(self, key: jax.Array, hyperparams: Any = None) -> TrainState:
        """Fresh networks, optimizers, noise scales and envs, then the first fill; `hyperparams`: none traced yet."""
        if hyperparams is not None:
            raise ValueError("TD3 cannot sweep settings within one program yet (no field of TD3Config is traced); "
                             "run one `mjxsuite train --agent td3` per value instead")
        cfg = self.config
        _, _, noise_key, env_key, fill_key, loop_key = jax.random.split(key, 6)
        (normalizer, actor_params), critic_params = self.fresh_networks(key)
        (actor, _), (twins, _) = self.inputs.split(actor_params, "actor"), self.inputs.split(critic_params, "twins")
        flag = jnp.float32(0)
        env_state = self.train_env.reset(env_key)
        buffer, example = self.inputs.init_buffer(example_transition(env_state, self.action_size))
        window = None if cfg.num_steps == 1 else jax.tree.map(  # each env's last steps, `ended` and `valid`
            lambda x: jnp.zeros((cfg.num_steps, cfg.num_envs, *x.shape), x.dtype), (example, flag, flag))
        ts = TrainState(
            params=(normalizer, actor_params), critic_params=critic_params, target_critic_params=twins,
            actor_opt_state=self.actor_optimizer.init(actor), critic_opt_state=self.critic_optimizer.init(critic_params),
            noise_scale=jax.random.uniform(noise_key, (cfg.num_envs,), minval=cfg.std_min, maxval=cfg.std_max),
            buffer=buffer, window=window, noise=jax.random.normal(jax.random.fold_in(noise_key, 1), (
                cfg.num_envs, self.action_size)) if cfg.noise_correlation > 0 else None,
            **first_state((normalizer, actor_params), env_state, loop_key))
        return prefill(partial(self.collect, uniform=cfg.uniform_first_fill), ts, fill_key, cfg.prefill_iterations)

    chunk = DQN.chunk  # `train_steps`, then `evaluate_and_keep_best`

    CHUNK_TOTALS = {**EPISODE_TOTALS, **dict.fromkeys(("critic_loss", "actor_loss", "actor_saturation", "target_q"),
                                                      jnp.float32)}

    def train_steps(self, ts: TrainState) -> tuple[TrainState, dict, jax.Array]:
        """A chunk's acting and learning: the train state, its metrics and the next evaluation's key."""
        cfg = self.config

        def iteration(ts, inputs):
            key, index = inputs
            act_key, learn_key = jax.random.split(key)
            ts, collected = self.collect(ts, act_key)
            ts, learned = self.update(ts, learn_key, index)
            return ts, {**collected, **learned}

        key, loop_key, eval_key = jax.random.split(ts.key, 3)
        iterations = cfg.iterations_per_chunk
        inputs = (jax.random.split(loop_key, iterations), jnp.arange(iterations))
        ts, totals = add_up(self, iteration, ts.replace(key=key), inputs)
        actor_steps = max(cfg.actor_updates_per_chunk, 1)
        metrics = {"critic_loss": totals["critic_loss"] / iterations, "target_q": totals["target_q"] / iterations,
                   "actor_loss": totals["actor_loss"] / actor_steps,
                   "actor_saturation": totals["actor_saturation"] / actor_steps}
        return ts, {**metrics, **evaluation.episode_metrics(totals)}, eval_key

    evaluate_and_keep_best = SAC.evaluate_and_keep_best  # keeps the best parameters and the step that solved


def train(config: TD3Config, env: Env, key: jax.Array):
    """A whole run as one pure function (`evaluation.whole_run`): `(best_params, metrics)`; vmap it for seeds."""
    return evaluation.whole_run(TD3(config, env), key)
