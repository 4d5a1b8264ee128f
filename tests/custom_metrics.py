"""Metric functions a user might pass to ``PPOConfig(metrics=...)``, importable by name so that
a run directory records them and a fresh process rebuilds them."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def mean_abs_pole_angle(rollout, batch, losses) -> jax.Array:
    """Mean |pole angle| over the rollout's observations ``[num_steps, num_envs, 4]``."""
    return jnp.abs(rollout.obs[..., 2]).mean()


def value_loss_again(rollout, batch, losses) -> jax.Array:
    """The built-in ``train/value_loss`` recomputed: the mean over every gradient step."""
    return losses["value_loss"].mean()


def not_a_scalar(rollout, batch, losses) -> jax.Array:
    """A mistake: one value per step, not one number."""
    return rollout.reward.mean(axis=1)
