"""The Q-network: an MLP with an optional dueling head (Flax linen, params as a plain pytree)."""

from __future__ import annotations

from typing import Sequence

import flax.linen as nn
import jax


class QNetwork(nn.Module):
    num_actions: int
    hidden: Sequence[int] = (64, 64)
    dueling: bool = False

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = obs
        for width in self.hidden:
            x = nn.relu(nn.Dense(width)(x))
        if not self.dueling:
            return nn.Dense(self.num_actions)(x)
        # Dueling head (Wang et al. 2016): Q = V + A - mean(A).
        value = nn.Dense(1)(x)
        advantage = nn.Dense(self.num_actions)(x)
        return value + advantage - advantage.mean(axis=-1, keepdims=True)
