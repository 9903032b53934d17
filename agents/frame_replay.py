"""Replay of stacked camera frames as DrQ-v2 keeps them: each frame once, the stacks rebuilt when sampled.

An `envs.pixels` observation is k frames, oldest first (a reset fills the stack with its first frame; a step drops
the oldest and adds one), so stored whole a transition's obs and next_obs cost 2k frames. Here a step costs two:
the newest frame of the observation it acted on (`seen`) and of its next observation (`next_frame`: the true final
one where its episode ended); its stacks are rebuilt from its env's earlier steps, back to its episode's first.

Step j of every env lives at slot j % `steps`: its frames written as it happens, its n-step row
(`agents.td3.n_step_rows`: action, reward, discount, and how many steps on its next observation is) once complete.
A sample draws a step and an env uniformly among those whose row is complete and whose frames are still held:
`capacity` transitions. A row that may not be learned from (NaN or MuJoCo Warp's overflow before its episode
ended) is flagged, its values zeroed, and each draw of one replaced by a learnable draw of the same sample
(`valid_first`), so every draw stays uniform over the learnable rows.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp

from agents.sac import Transition


@flax.struct.dataclass
class FrameReplayState:
    seen: jax.Array  # uint8 (steps * envs, height, width, channels): the newest frame each step acted on
    next_frame: jax.Array  # uint8, as `seen`: the newest frame of each step's next observation
    age: jax.Array  # int32 (steps * envs,): each step's index in its episode (0: the episode's first step)
    action: jax.Array  # float32 (steps * envs, action_size): each row's first action
    reward: jax.Array  # float32 (steps * envs,): each row's n-step discounted reward
    discount: jax.Array  # float32 (steps * envs,): discounting**k * (1 - terminated) of its k steps
    last: jax.Array  # int32 (steps * envs,): the row's next observation is that of its step `last` steps on
    valid: jax.Array  # bool (steps * envs,): whether the row may be learned from
    episode_step: jax.Array  # int32 (envs,): the next step's `age`
    written: jax.Array  # int32: steps written, all envs at a time (the next step's index)


@dataclasses.dataclass(frozen=True)
class FrameReplay:
    """Uniform replay of `capacity` transitions of `num_envs` envs observing `frame_stack` stacked frames, whose
    rows span `num_steps` steps. Frames are read with one gather, on every platform: a CPU's loop of slices
    (`agents.replay`'s) reads single frames slower."""

    capacity: int
    num_envs: int
    frame_stack: int
    num_steps: int = 1

    @property
    def steps(self) -> int:
        """Slots of the ring: `capacity` transitions, the rows not yet complete and the frames their oldest need."""
        return -(-self.capacity // self.num_envs) + self.num_steps - 1 + self.frame_stack - 1

    def init(self, frame_shape: tuple[int, ...], action_size: int) -> FrameReplayState:
        """An empty ring for frames of `frame_shape` (height, width, channels of one frame)."""
        slots = self.steps * self.num_envs
        frames = jnp.zeros((slots, *frame_shape), jnp.uint8)
        zeros = jnp.zeros((slots,), jnp.float32)
        return FrameReplayState(seen=frames, next_frame=frames, age=jnp.zeros((slots,), jnp.int32),
                                action=jnp.zeros((slots, action_size), jnp.float32), reward=zeros, discount=zeros,
                                last=jnp.zeros((slots,), jnp.int32), valid=jnp.zeros((slots,), bool),
                                episode_step=jnp.zeros((self.num_envs,), jnp.int32), written=jnp.zeros((), jnp.int32))

    def add(self, state: FrameReplayState, obs: jax.Array, next_obs: jax.Array, ended: jax.Array, row,
            row_valid: jax.Array) -> FrameReplayState:
        """Step `state.written` of every env: its observation and next observation stacks (num_envs, height, width,
        channels * frame_stack), which envs' episodes it `ended`; and the n-step `row` (an `agents.sac.Transition`
        whose obs and next_obs are the indices of its first and last steps) completed by it, with `row_valid`."""
        channels = obs.shape[-1] // self.frame_stack
        slot = (state.written % self.steps) * self.num_envs

        def put(buffer, values, at):
            return jax.lax.dynamic_update_slice_in_dim(buffer, values.astype(buffer.dtype), at, 0)

        row_slot = (row.obs[0] % self.steps) * self.num_envs  # its first step's (slot 0 until a row completes)
        keep = lambda x: jnp.where(row_valid.reshape(-1, *[1] * (x.ndim - 1)), x, 0)  # no NaN is ever stored
        return state.replace(
            seen=put(state.seen, obs[..., -channels:], slot), age=put(state.age, state.episode_step, slot),
            next_frame=put(state.next_frame, next_obs[..., -channels:], slot),
            action=put(state.action, keep(row.action), row_slot), reward=put(state.reward, keep(row.reward), row_slot),
            discount=put(state.discount, keep(row.discount), row_slot), valid=put(state.valid, row_valid, row_slot),
            last=put(state.last, row.next_obs - row.obs, row_slot),
            episode_step=jnp.where(ended > 0, 0, state.episode_step + 1), written=state.written + 1)

    def size(self, state: FrameReplayState) -> jax.Array:
        """Transitions a sample draws from (the learnable ones and those flagged)."""
        return self.sampled_steps(state)[1] * self.num_envs

    def sampled_steps(self, state: FrameReplayState) -> tuple[jax.Array, jax.Array]:
        """(the oldest step a sample may draw, how many steps from it on): those whose row is complete and whose
        oldest frame is still held."""
        oldest = jnp.maximum(state.written - self.steps + self.frame_stack - 1, 0)
        return oldest, jnp.maximum(state.written - self.num_steps + 1 - oldest, 0)

    def sample_from_bits(self, state: FrameReplayState, bits: jax.Array):
        """A uniform sample, one draw per uint32 of `bits`: (an `agents.sac.Transition` of stacked frames, whether
        any draw was learnable; if none was, the sample must not be learned from)."""
        oldest, count = self.sampled_steps(state)
        drawn = (bits % jnp.maximum(count * self.num_envs, 1).astype(jnp.uint32)).astype(jnp.int32)
        step, env = oldest + drawn // self.num_envs, drawn % self.num_envs
        valid = state.valid[self.slot(step, env)]
        learnable = valid_first(valid)
        step, env = step[learnable], env[learnable]
        row = self.slot(step, env)
        last = step + state.last[row]
        frames_seen = self.frames_back(state, step, env, range(self.frame_stack - 1, -1, -1))
        frames_seen += self.frames_back(state, last, env, range(self.frame_stack - 2, -1, -1))
        seen = state.seen[jnp.concatenate(frames_seen)]
        newest = state.next_frame[self.slot(last, env)]
        stacks = jnp.split(seen, 2 * self.frame_stack - 1)
        batch = Transition(obs=jnp.concatenate(stacks[:self.frame_stack], -1), action=state.action[row],
                           reward=state.reward[row], discount=state.discount[row],
                           next_obs=jnp.concatenate([*stacks[self.frame_stack:], newest], -1))
        return batch, valid.any()

    def slot(self, step: jax.Array, env: jax.Array) -> jax.Array:
        return (step % self.steps) * self.num_envs + env

    def frames_back(self, state: FrameReplayState, step: jax.Array, env: jax.Array, backs) -> list[jax.Array]:
        """The slots of the seen frames each of `backs` steps before `step`, no earlier than its episode's first
        (a reset fills the stack with its first frame)."""
        first = step - state.age[self.slot(step, env)]
        return [self.slot(jnp.maximum(step - back, first), env) for back in backs]


def valid_first(valid: jax.Array) -> jax.Array:
    """Indices of the draws to keep: each where `valid` holds itself, each other a valid one, cycling through them."""
    order = jnp.argsort(~valid, stable=True)
    position = jnp.arange(valid.shape[0])
    return jnp.where(valid, position, order[position % jnp.maximum(valid.sum(), 1)])
