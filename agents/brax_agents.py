"""Brax's PPO and SAC as agents of the suite: their settings, checked like `DQNConfig`, and the
few calls into Brax that the driver (`agents.brax_run`) and `load_policy` make.

The trainers are Brax's own (`brax.training.agents.ppo.train`, `.sac.train`), never rewritten:
a config's fields are the trainer's keyword arguments (`num_timesteps` is `--steps` on the
command line), except the network widths, which become Brax's `network_factory`, and
`solve_return`, which only the driver reads. Brax is imported inside the functions, so
`import agents` stays light. Per-task defaults live in `agents/brax_defaults.py`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any, Callable, ClassVar

import jax
import jax.numpy as jnp

from envs.ranges import COUNT, FINITE, NON_NEGATIVE, NON_NEGATIVE_COUNT, POSITIVE, PROBABILITY, Range, check_fields

# Brax's evaluator runs one episode per eval env, with the policy's mode (tanh of the mean):
# the same deterministic policy that the checkpoint keeps and `load_policy` acts with.
DETERMINISTIC_EVAL = True


def _check_widths(config: Any, field: str) -> None:
    widths = getattr(config, field)
    if not widths:
        raise ValueError(f"{type(config).__name__}.{field} needs at least one layer width, got {widths!r}")
    for width in widths:
        COUNT.check(f"{type(config).__name__}.{field} (layer widths {widths})", width)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """The settings of a `brax.training.agents.ppo.train` run (Brax's names and meanings).

    Each training step collects `batch_size * num_minibatches * unroll_length` env steps
    (`batch_size * num_minibatches` must be a multiple of `num_envs`) and makes
    `num_updates_per_batch * num_minibatches` gradient steps on them."""

    num_timesteps: int = 1_000_000
    num_envs: int = 64
    unroll_length: int = 16
    batch_size: int = 64
    num_minibatches: int = 16
    num_updates_per_batch: int = 4
    learning_rate: float = 1e-3
    entropy_cost: float = 1e-3
    discounting: float = 0.97
    gae_lambda: float = 0.95
    clipping_epsilon: float = 0.3
    max_grad_norm: float | None = None  # None: no clipping
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    num_resets_per_eval: int = 0
    num_evals: int = 11  # Brax's evaluations, the first before any training
    num_eval_envs: int = 64  # episodes per evaluation
    policy_hidden: tuple[int, ...] = (64, 64)
    value_hidden: tuple[int, ...] = (64, 64)
    solve_return: float | None = None  # an evaluation return that counts as solved (eval.json); not Brax's

    RANGES: ClassVar[dict[str, Range]] = {
        "num_timesteps": COUNT, "num_envs": COUNT, "unroll_length": COUNT, "batch_size": COUNT,
        "num_minibatches": COUNT, "num_updates_per_batch": COUNT, "learning_rate": POSITIVE,
        "entropy_cost": NON_NEGATIVE, "discounting": PROBABILITY, "gae_lambda": PROBABILITY,
        "clipping_epsilon": POSITIVE, "reward_scaling": POSITIVE, "num_resets_per_eval": NON_NEGATIVE_COUNT,
        "num_evals": Range(2, integer=True), "num_eval_envs": COUNT,
    }

    def __post_init__(self):
        check_fields(self, self.RANGES)
        _check_widths(self, "policy_hidden")
        _check_widths(self, "value_hidden")
        if self.max_grad_norm is not None:
            POSITIVE.check("PPOConfig.max_grad_norm (None: no clipping)", self.max_grad_norm)
        if self.solve_return is not None:
            FINITE.check("PPOConfig.solve_return (None: no threshold)", self.solve_return)
        if self.batch_size * self.num_minibatches % self.num_envs:
            raise ValueError(f"PPOConfig: batch_size * num_minibatches ({self.batch_size} * {self.num_minibatches}) "
                             f"must be a multiple of num_envs ({self.num_envs}), as Brax's PPO requires")

    @property
    def steps_per_epoch(self) -> int:
        """Env steps between two evaluations, as Brax's PPO rounds `num_timesteps` up."""
        per_training_step = self.batch_size * self.unroll_length * self.num_minibatches * max(self.num_resets_per_eval, 1)
        training_steps = -(-self.num_timesteps // ((self.num_evals - 1) * per_training_step))
        return training_steps * per_training_step

    @property
    def prefill_steps(self) -> int:
        return 0


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """The settings of a `brax.training.agents.sac.train` run (Brax's names and meanings).

    It first fills its replay buffer with `min_replay_size` env steps, then makes
    `grad_updates_per_step` gradient steps every `num_envs` env steps."""

    num_timesteps: int = 100_000
    num_envs: int = 16
    batch_size: int = 256
    grad_updates_per_step: int = 8
    learning_rate: float = 1e-3
    discounting: float = 0.99
    tau: float = 0.005
    reward_scaling: float = 1.0
    normalize_observations: bool = True
    min_replay_size: int = 2_000
    max_replay_size: int = 100_000
    num_evals: int = 6
    num_eval_envs: int = 64
    hidden: tuple[int, ...] = (64, 64)  # the policy's and both Q networks' layers
    solve_return: float | None = None

    RANGES: ClassVar[dict[str, Range]] = {
        "num_timesteps": COUNT, "num_envs": COUNT, "batch_size": COUNT, "grad_updates_per_step": COUNT,
        "learning_rate": POSITIVE, "discounting": PROBABILITY, "tau": Range(0.0, 1.0, low_open=True),
        "reward_scaling": POSITIVE, "min_replay_size": NON_NEGATIVE_COUNT, "max_replay_size": COUNT,
        "num_evals": Range(2, integer=True), "num_eval_envs": COUNT,
    }

    def __post_init__(self):
        check_fields(self, self.RANGES)
        _check_widths(self, "hidden")
        if self.solve_return is not None:
            FINITE.check("SACConfig.solve_return (None: no threshold)", self.solve_return)
        if self.prefill_steps >= self.num_timesteps:
            raise ValueError(f"SACConfig: min_replay_size ({self.min_replay_size}, {self.prefill_steps} env steps "
                             f"over {self.num_envs} envs) must be below num_timesteps ({self.num_timesteps}), "
                             "or no training happens")
        if self.max_replay_size < max(self.batch_size, self.min_replay_size):
            raise ValueError(f"SACConfig.max_replay_size ({self.max_replay_size}) must hold at least batch_size "
                             f"({self.batch_size}) and min_replay_size ({self.min_replay_size}) transitions")

    @property
    def prefill_steps(self) -> int:
        """Env steps of the buffer's first fill, as Brax's SAC rounds `min_replay_size` up."""
        return -(-self.min_replay_size // self.num_envs) * self.num_envs

    @property
    def steps_per_epoch(self) -> int:
        """Env steps between two evaluations after the first fill, as Brax's SAC rounds them up."""
        actor_steps = -(-(self.num_timesteps - self.prefill_steps) // ((self.num_evals - 1) * self.num_envs))
        return actor_steps * self.num_envs


CONFIGS = {"ppo": PPOConfig, "sac": SACConfig}
NOT_BRAX_ARGUMENTS = ("policy_hidden", "value_hidden", "hidden", "solve_return")


def trainer_kwargs(config: PPOConfig | SACConfig) -> dict:
    """The keyword arguments of Brax's `train` for `config` (the network widths as `network_factory`)."""
    kwargs = {f.name: getattr(config, f.name) for f in dataclasses.fields(config) if f.name not in NOT_BRAX_ARGUMENTS}
    return {**kwargs, "network_factory": network_factory(config), "deterministic_eval": DETERMINISTIC_EVAL}


def network_factory(config: PPOConfig | SACConfig) -> Callable:
    """Brax's network factory with the config's layer widths."""
    if isinstance(config, PPOConfig):
        from brax.training.agents.ppo import networks as ppo_networks

        return functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=config.policy_hidden,
                                 value_hidden_layer_sizes=config.value_hidden)
    from brax.training.agents.sac import networks as sac_networks

    return functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=config.hidden)


def trainer(config: PPOConfig | SACConfig) -> Callable:
    """Brax's `train` function for `config`."""
    if isinstance(config, PPOConfig):
        from brax.training.agents.ppo import train as ppo

        return ppo.train
    from brax.training.agents.sac import train as sac

    return sac.train


def _networks(config: PPOConfig | SACConfig, observation_size: int, action_size: int):
    """The networks Brax's trainer builds for `config`, built the same way (normalizer included)."""
    from brax.training import types
    from brax.training.acme import running_statistics

    preprocess = running_statistics.normalize if config.normalize_observations else types.identity_observation_preprocessor
    return network_factory(config)(observation_size, action_size, preprocess_observations_fn=preprocess)


def params_template(config: PPOConfig | SACConfig, observation_size: int, action_size: int) -> Any:
    """The shapes of the parameters Brax's trainer returns (PPO: normalizer, policy, value; SAC:
    normalizer, policy), without running anything: what a checkpoint is read against."""
    from brax.training.acme import running_statistics, specs

    networks = _networks(config, observation_size, action_size)

    def init(key):
        normalizer = running_statistics.init_state(specs.Array((observation_size,), jnp.dtype("float32")))
        if isinstance(config, PPOConfig):
            policy_key, value_key = jax.random.split(key)
            return normalizer, networks.policy_network.init(policy_key), networks.value_network.init(value_key)
        return normalizer, networks.policy_network.init(key)

    return jax.eval_shape(init, jax.random.PRNGKey(0))


def deterministic_policy(config: PPOConfig | SACConfig, observation_size: int, action_size: int) -> Callable:
    """`(params, obs, key) -> action in [-1, 1]`, jittable: the mode of Brax's policy, as its
    deterministic evaluation acts (the key is unused)."""
    networks = _networks(config, observation_size, action_size)
    if isinstance(config, PPOConfig):
        from brax.training.agents.ppo import networks as ppo_networks

        make_inference = ppo_networks.make_inference_fn(networks)
    else:
        from brax.training.agents.sac import networks as sac_networks

        make_inference = sac_networks.make_inference_fn(networks)
    return lambda params, obs, key: make_inference(params, deterministic=True)(obs, key)[0]
