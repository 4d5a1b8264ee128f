"""Flax actor-critics a user might pass to ``PPOConfig(network=...)``, importable by name so
that a run directory can rebuild them in a fresh process."""

from __future__ import annotations

import flax.linen as nn
import jax


class GeluLayerNorm(nn.Module):
    """Shared torso: ``depth`` x (Dense ``width``, LayerNorm, GELU); then a policy and a value
    head. ``obs [..., obs_dim] -> (logits [..., num_actions], value [...])``."""

    width: int = 128
    depth: int = 2
    num_actions: int = 2

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        x = obs
        for _ in range(self.depth):
            x = nn.gelu(nn.LayerNorm()(nn.Dense(self.width)(x)))
        logits = nn.Dense(self.num_actions, kernel_init=nn.initializers.orthogonal(0.01))(x)
        return logits, nn.Dense(1)(x)[..., 0]


class ReluMLP(nn.Module):
    """Separate actor and critic MLPs of ``width`` with ReLU (another network of the same
    config's shapes, to tell programs apart)."""

    width: int = 32
    num_actions: int = 2

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        actor = nn.relu(nn.Dense(self.width)(obs))
        critic = nn.relu(nn.Dense(self.width)(obs))
        return nn.Dense(self.num_actions)(actor), nn.Dense(1)(critic)[..., 0]
