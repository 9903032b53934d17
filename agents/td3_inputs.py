"""What TD3's networks read and how its replay keeps it, one object per kind of observation, so `agents.td3.TD3`
never asks which: state vectors (`StateInputs`), or camera images the way of DrQ-v2 (Yarats et al. 2021,
github.com/facebookresearch/drqv2; `ImageInputs`): an encoder trained by the critics' loss alone, each frame stored
once (`agents.frame_replay.FrameReplay`), sampled images shifted (`random_shift`). From images a network's params are
`{name: network, "encoder": encoder}` (`joined`), the actor's encoder a copy of the critics'.
"""

from __future__ import annotations

from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from agents import device_options
from agents.frame_replay import FrameReplay
from agents.networks import canonical_conv
from agents.ppo import image_shape
from agents.replay import UniformReplay
from agents.sac import Transition, pack, unpack

COMPUTE_DTYPES = {"float32": jnp.float32, "bfloat16": jnp.bfloat16}
ENCODER_STRIDES = (2, 1, 1, 1)  # DrQ-v2's four 3x3 convolutions of 32 channels, unpadded
SMALLEST_IMAGE = 15  # pixels a side that leave its last convolution a 1x1 map


class Encoder(nn.Module):
    """DrQ-v2's encoder: uint8 frames to [-0.5, 0.5], `ENCODER_STRIDES`' convolutions with ReLU, flattened;
    convolved in `dtype`, its parameters float32."""

    dtype: Any = jnp.float32
    canonical_gradients: bool = False  # `agents.networks.canonical_conv` (for XLA:CPU); the same values

    @nn.compact
    def __call__(self, frames: jax.Array) -> jax.Array:
        x = (frames.astype(jnp.float32) / 255.0 - 0.5).astype(self.dtype)
        conv = canonical_conv if self.canonical_gradients else None
        for stride in ENCODER_STRIDES:
            x = nn.relu(nn.Conv(32, (3, 3), strides=stride, padding="VALID", dtype=self.dtype, conv_general_dilated=conv,
                                kernel_init=nn.initializers.orthogonal(2 ** 0.5))(x))
        return x.reshape(*x.shape[:-3], -1)


def random_shift(key: jax.Array, frames: jax.Array, pad: int) -> jax.Array:
    """DrQ-v2's augmentation of a batch of images (batch, H, W, C): each padded by `pad` pixels, its edges
    repeated, and cut back to H x W at its own offset, drawn uniformly in [0, 2 pad] on each axis."""
    height, width, channels = frames.shape[-3:]
    padded = jnp.pad(frames, ((0, 0), (pad, pad), (pad, pad), (0, 0)), mode="edge")
    offsets = jax.random.randint(key, (frames.shape[0], 2), 0, 2 * pad + 1)
    crop = lambda image, at: jax.lax.dynamic_slice(image, (at[0], at[1], 0), (height, width, channels))
    return jax.vmap(crop)(padded, offsets)


def inputs_for(config, env, obs_size: int, action_size: int, platform: str | None) -> StateInputs | ImageInputs:
    """`ImageInputs` where `env` observes camera images (`agents.ppo.image_shape`), else `StateInputs`."""
    shape = image_shape(env)
    if shape is None:
        return StateInputs(config, obs_size, action_size, platform)
    return ImageInputs(config, env, shape, device_options.canonical_conv_gradients(platform))


class StateInputs:
    """State observations: normalized (`normalize_observations`), no encoder (`trunk` 0), packed rows of uniform
    replay. Each method's docstring holds for `ImageInputs`' too."""

    trunk = 0

    def __init__(self, config, obs_size: int, action_size: int, platform: str | None):
        self.config, self.obs_size, self.action_size = config, obs_size, action_size
        self.buffer = UniformReplay(config.max_replay_size, vectorized=device_options.vectorized_replay(platform))

    def init(self, key: jax.Array) -> tuple[Any, Any, jax.Array]:
        """(the normalizer's state, the encoder's params from `key`, the networks' example input)."""
        from brax.training.acme import running_statistics, specs
        normalizer = running_statistics.init_state(specs.Array((self.obs_size,), jnp.dtype("float32")))
        return normalizer, None, jnp.zeros((1, self.obs_size))

    def features(self, normalizer, encoder, obs: jax.Array) -> jax.Array:
        """What the actor and critics read."""
        from brax.training.acme import running_statistics
        return running_statistics.normalize(obs, normalizer) if self.config.normalize_observations else obs

    def observed(self, normalizer, obs: jax.Array):
        """The normalizer after the observations a step acted on."""
        from brax.training.acme import running_statistics
        return running_statistics.update(normalizer, obs)

    def split(self, params, name: str):
        """(a network's params, the encoder's or None) from `joined`'s."""
        return params, None

    def joined(self, network, encoder, name: str):
        return network

    def init_buffer(self, example: Transition) -> tuple[Any, Transition]:
        """The empty replay, and the transition that the n-step window holds (`agents.td3.n_step_rows`)."""
        return self.buffer.init(pack(example)), example

    def indexed(self, buffer, steps: Transition) -> Transition:
        """A step's transitions as the n-step window holds them."""
        return steps

    def store(self, buffer, row: Transition, step: Transition, ended: jax.Array, valid: jax.Array):
        """The replay with each env's n-step `row` where `valid`, completed by `step` (which `ended` episodes)."""
        return self.buffer.add(buffer, pack(row), mask=valid)

    def draw(self, buffer, bits: jax.Array) -> tuple[Transition, jax.Array | None]:
        """One stored transition per uint32 of `bits`, and whether any may be learned from (None: all may)."""
        rows, _ = self.buffer.sample_from_bits(buffer, bits)
        return unpack(rows, self.obs_size, self.action_size), None

    def augmented(self, batch: Transition, key: jax.Array) -> Transition:
        """The batch as the losses read it."""
        return batch


class ImageInputs:
    """Camera images (uint8 frames stacked on the channel axis): DrQ-v2's encoder and trunk (`feature_size`), no
    normalizer, each frame stored once, the sampled images shifted by up to `augment_pad` pixels."""

    def __init__(self, config, env, shape: tuple[int, int, int], canonical_gradients: bool = False):
        if min(shape[:2]) < SMALLEST_IMAGE:
            raise ValueError(f"TD3 from camera images needs at least {SMALLEST_IMAGE}x{SMALLEST_IMAGE} pixels for "
                             f"DrQ-v2's encoder; {env!r} renders {shape[0]}x{shape[1]}: raise --env-opt width= and "
                             "height= (DrQ-v2's: 84)")
        self.config, self.shape, self.trunk = config, shape, config.feature_size
        self.encoder = Encoder(COMPUTE_DTYPES[config.encoder_dtype], canonical_gradients)
        self.frame_shape = (*shape[:2], getattr(env, "channels", shape[2]))
        self.buffer = FrameReplay(config.max_replay_size, config.num_envs, shape[2] // self.frame_shape[2],
                                  config.num_steps)

    def init(self, key: jax.Array) -> tuple[Any, Any, jax.Array]:
        frames = jnp.zeros((1, *self.shape), jnp.uint8)
        encoder = self.encoder.init(key, frames)
        return None, encoder, self.encoder.apply(encoder, frames)

    def features(self, normalizer, encoder, obs: jax.Array) -> jax.Array:
        return self.encoder.apply(encoder, obs)

    def observed(self, normalizer, obs: jax.Array):
        return normalizer

    def split(self, params, name: str):
        return params[name], params["encoder"]

    def joined(self, network, encoder, name: str):
        return {name: network, "encoder": encoder}

    def init_buffer(self, example: Transition) -> tuple[Any, Transition]:
        buffer = self.buffer.init(self.frame_shape, example.action.shape[-1])
        return buffer, example._replace(obs=jnp.int32(0), next_obs=jnp.int32(0))  # step indices for observations

    def indexed(self, buffer, steps: Transition) -> Transition:
        index = jnp.full(steps.reward.shape, buffer.written)  # the frames are stored apart (`store`)
        return steps._replace(obs=index, next_obs=index)

    def store(self, buffer, row: Transition, step: Transition, ended: jax.Array, valid: jax.Array):
        return self.buffer.add(buffer, step.obs, step.next_obs, ended, row, valid)

    def draw(self, buffer, bits: jax.Array) -> tuple[Transition, jax.Array | None]:
        return self.buffer.sample_from_bits(buffer, bits)  # stacks rebuilt, flagged draws replaced

    def augmented(self, batch: Transition, key: jax.Array) -> Transition:
        obs_key, next_key = jax.random.split(key)  # observations and next observations shifted apart
        pad = self.config.augment_pad
        return batch._replace(obs=random_shift(obs_key, batch.obs, pad),
                              next_obs=random_shift(next_key, batch.next_obs, pad))
