"""Separate actor and critic MLPs with Stable-Baselines3's orthogonal initialisation."""

from __future__ import annotations

import math
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

ACTIVATIONS = {"tanh": nn.tanh, "relu": nn.relu}


def orthogonal(scale: float = 1.0):
    """Orthogonal initialiser (a Haar-random orthogonal matrix times ``scale``), as
    ``flax.linen.initializers.orthogonal`` but computed with Gram-Schmidt in plain ``jnp``.

    Flax's version calls LAPACK's QR through jaxlib's FFI kernel, whose parallel batch loop can
    deadlock on CPU when two such kernels run at once (vmapped seeds, two devices; seen with
    jaxlib 0.10.2). Gram-Schmidt, orthogonalising twice for accuracy, gives the same
    distribution: Q of a Gaussian matrix with R's diagonal made positive.
    """

    def init(key: jax.Array, shape: tuple[int, ...], dtype=jnp.float32) -> jax.Array:
        n_rows, n_cols = shape
        rows, cols = max(n_rows, n_cols), min(n_rows, n_cols)
        a = jax.random.normal(key, (rows, cols), jnp.float32)

        def column(j: int, q: jax.Array) -> jax.Array:
            v = a[:, j]
            for _ in range(2):  # classical Gram-Schmidt, twice (CGS2)
                v = v - q @ (q.T @ v)
            return q.at[:, j].set(v / jnp.linalg.norm(v))

        q = jax.lax.fori_loop(0, cols, column, jnp.zeros((rows, cols), jnp.float32))
        if n_rows < n_cols:
            q = q.T
        return (scale * q).astype(dtype)

    return init


class MLP(nn.Module):
    """Dense layers ``hidden_0 .. hidden_{n-1}`` then a linear ``out`` layer.

    Hidden kernels are orthogonal with gain sqrt(2), the output kernel orthogonal with
    ``out_gain``; biases start at zero (SB3's ``ortho_init``).
    """

    hidden_sizes: Sequence[int]
    out_dim: int
    out_gain: float
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        act = ACTIVATIONS[self.activation]
        for i, size in enumerate(self.hidden_sizes):
            x = nn.Dense(
                size,
                kernel_init=orthogonal(math.sqrt(2.0)),
                bias_init=nn.initializers.zeros,
                name=f"hidden_{i}",
            )(x)
            x = act(x)
        return nn.Dense(
            self.out_dim,
            kernel_init=orthogonal(self.out_gain),
            bias_init=nn.initializers.zeros,
            name="out",
        )(x)


class ActorCritic(nn.Module):
    """Policy logits and state value from two independent MLPs.

    Maps observations ``(..., obs_dim)`` to ``(logits (..., num_actions), value (...))``.
    The policy head starts at gain 0.01 (near-uniform initial policy), the value head at 1.0.
    """

    hidden_sizes: Sequence[int] = (64, 64)
    activation: str = "tanh"
    num_actions: int = 2

    def setup(self) -> None:
        self.actor = MLP(self.hidden_sizes, self.num_actions, 0.01, self.activation)
        self.critic = MLP(self.hidden_sizes, 1, 1.0, self.activation)

    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        return self.actor(obs), self.critic(obs)[..., 0]

    def value(self, obs: jax.Array) -> jax.Array:
        """State value only, shape ``obs.shape[:-1]``."""
        return self.critic(obs)[..., 0]

    def logits(self, obs: jax.Array) -> jax.Array:
        """Policy logits only, shape ``(..., num_actions)``."""
        return self.actor(obs)


def init_params(key: jax.Array, network: ActorCritic, obs_dim: int = 4):
    """Initial parameters ``{"params": {"actor": ..., "critic": ...}}``."""
    return network.init(key, jnp.zeros((obs_dim,), jnp.float32))
