"""What one PPO iteration reports: Stable-Baselines3's logged metrics, under SB3's names and
definitions, and the window of finished episodes their episode means are taken over.

Bookkeeping beside the algorithm (:mod:`jaxcart.core.ppo`), not part of it: nothing here
changes what is learned. Everything describes one run; arrays are as in ``ppo.py``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

Array = jax.Array

EPISODE_WINDOW = 100
"""SB3 reports episode return/length means over the last 100 finished episodes."""

METRIC_NAMES = (
    "rollout/ep_rew_mean",
    "rollout/ep_len_mean",
    "rollout/ep_rew_max",
    "train/approx_kl",
    "train/clip_fraction",
    "train/entropy_loss",
    "train/policy_gradient_loss",
    "train/value_loss",
    "train/loss",
    "train/explained_variance",
    "train/learning_rate",
)
"""Per-iteration metrics computed in the compiled step (``time/fps`` is added by the host)."""


@struct.dataclass
class EpisodeBuffer:
    """Returns and lengths of the last ``EPISODE_WINDOW`` finished episodes (``valid`` marks
    filled slots; order inside the window does not matter for the means)."""

    returns: Array  # [EPISODE_WINDOW] float32
    lengths: Array  # [EPISODE_WINDOW] float32
    valid: Array  # [EPISODE_WINDOW] bool


def update_episode_buffer(
    buffer: EpisodeBuffer, done: Array, episode_return: Array, episode_length: Array
) -> EpisodeBuffer:
    """Adds the episodes that ended during a rollout and keeps the most recent window.

    Args:
        buffer: the window so far.
        done: ``[num_steps, num_envs]`` bool, where an episode ended (terminated or truncated).
        episode_return, episode_length: ``[num_steps, num_envs]``, the ended episode's return
            and length (read only where ``done``).
    """
    valid = jnp.concatenate([buffer.valid, done.reshape(-1)])
    returns = jnp.concatenate([buffer.returns, episode_return.reshape(-1).astype(jnp.float32)])
    lengths = jnp.concatenate([buffer.lengths, episode_length.reshape(-1).astype(jnp.float32)])
    # rank 1 = the most recently finished episode (time-major, then env order, as SB3 fills).
    rank = jnp.cumsum(valid[::-1])[::-1]
    slot = jnp.where(valid & (rank <= EPISODE_WINDOW), EPISODE_WINDOW - rank, EPISODE_WINDOW)
    empty = jnp.zeros((EPISODE_WINDOW,), jnp.float32)
    return EpisodeBuffer(
        returns=empty.at[slot].set(returns, mode="drop"),
        lengths=empty.at[slot].set(lengths, mode="drop"),
        valid=jnp.zeros((EPISODE_WINDOW,), bool).at[slot].set(True, mode="drop"),
    )


def explained_variance(y_pred: Array, y_true: Array) -> Array:
    """``1 - Var[y_true - y_pred] / Var[y_true]`` (NaN when ``y_true`` is constant), as SB3."""
    var_y = jnp.var(y_true)
    return jnp.where(
        var_y == 0, jnp.nan, 1.0 - jnp.var(y_true - y_pred) / jnp.where(var_y == 0, 1.0, var_y)
    )


def iteration_metrics(
    episodes: EpisodeBuffer,
    done: Array,
    episode_return: Array,
    losses: dict[str, Array],
    value_pred: Array,
    returns: Array,
    learning_rate: Array,
) -> dict[str, Array]:
    """One iteration's scalar metrics, named as in :data:`METRIC_NAMES`.

    Args:
        episodes: the window after this iteration's rollout.
        done, episode_return: ``[num_steps, num_envs]``, as for :func:`update_episode_buffer`.
        losses: the loss terms of every gradient step, ``[update_epochs, num_minibatches]``.
        value_pred, returns: ``[batch_size]``, the value estimates the returns were built from
            and the returns (for the explained variance).
        learning_rate: the scalar step size used this iteration.
    """
    count = episodes.valid.sum()
    nan = jnp.float32(jnp.nan)
    return {
        "rollout/ep_rew_mean": jnp.where(
            count > 0, (episodes.returns * episodes.valid).sum() / jnp.maximum(count, 1), nan
        ),
        "rollout/ep_len_mean": jnp.where(
            count > 0, (episodes.lengths * episodes.valid).sum() / jnp.maximum(count, 1), nan
        ),
        # Best episode finished during this rollout (not an SB3 metric; sweeps rank by the
        # first time it reaches 500).
        "rollout/ep_rew_max": jnp.nan_to_num(
            jnp.max(jnp.where(done, episode_return, -jnp.inf)), neginf=jnp.nan
        ).astype(jnp.float32),
        # SB3 resets its KL list every epoch, so it logs the last epoch's mean.
        "train/approx_kl": losses["approx_kl"][-1].mean(),
        "train/clip_fraction": losses["clip_fraction"].mean(),
        "train/entropy_loss": losses["entropy_loss"].mean(),
        "train/policy_gradient_loss": losses["policy_gradient_loss"].mean(),
        "train/value_loss": losses["value_loss"].mean(),
        "train/loss": losses["loss"][-1, -1],
        "train/explained_variance": explained_variance(value_pred, returns),
        "train/learning_rate": jnp.asarray(learning_rate, jnp.float32),
    }


__all__ = [
    "EPISODE_WINDOW",
    "METRIC_NAMES",
    "EpisodeBuffer",
    "explained_variance",
    "iteration_metrics",
    "update_episode_buffer",
]
