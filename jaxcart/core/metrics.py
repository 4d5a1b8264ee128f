"""What one PPO iteration reports: Stable-Baselines3's logged metrics, under SB3's names and
definitions, and the window of finished episodes their episode means are taken over.

Bookkeeping beside the algorithm (:mod:`jaxcart.core.ppo`), not part of it: nothing here
changes what is learned. Everything describes one run; arrays are as in ``ppo.py``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from jaxcart.core import pytree

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
EVAL_METRICS = ("eval/mean_return", "eval/min_return")
"""The columns a periodic evaluation (``PPOConfig.eval_every``) adds: NaN on the iterations
between evaluations."""


@pytree.dataclass
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

    Slot ``EPISODE_WINDOW - r`` of the new window holds the episode finished r-th most recently
    (time-major, then env order, as SB3 fills its buffer; the buffer's episodes count as
    earlier than the rollout's, in slot order); slots with no episode hold 0 and are not
    ``valid``. The ranking is one ``top_k`` of the positions of the ended episodes. Plain
    version: a reversed cumulative count of the ended episodes as each one's rank, and a
    scatter per field. Why: the same window (``tests/test_ppo.py`` checks it bit for bit) in
    9 fewer compiled kernels of the default step.

    Args:
        buffer: the window so far.
        done: ``[num_steps, num_envs]`` bool, where an episode ended (terminated or truncated).
        episode_return, episode_length: ``[num_steps, num_envs]``, the ended episode's return
            and length (read only where ``done``).
    """
    window, done = EPISODE_WINDOW, done.reshape(-1)
    if window + done.size >= 2**24:  # the positions below are exact float32 integers
        raise ValueError(f"a rollout of {done.size} transitions is too large (max 2**24)")
    # position + 1 of every ended episode (buffer, then rollout), 0 elsewhere: the largest are
    # the most recent
    position = jnp.arange(1, window + done.size + 1, dtype=jnp.float32)
    keys = jnp.where(jnp.concatenate([buffer.valid, done]), position, 0.0)
    top, index = jax.lax.top_k(keys, window)
    filled, index = top[::-1] > 0, index[::-1]  # slot s <- the (window - s)-th latest
    from_buffer = index < window

    def take(old: Array, new: Array) -> Array:
        new = new.reshape(-1).astype(jnp.float32)
        picked = jnp.where(
            from_buffer,
            jnp.take(old, index, mode="clip"),
            jnp.take(new, index - window, mode="clip"),
        )
        return jnp.where(filled, picked, 0.0)

    return EpisodeBuffer(
        returns=take(buffer.returns, episode_return),
        lengths=take(buffer.lengths, episode_length),
        valid=filled,
    )


def explained_variance(y_pred: Array, y_true: Array) -> Array:
    """``1 - Var[y_true - y_pred] / Var[y_true]`` (NaN when ``y_true`` is constant), as SB3."""
    var_y = jnp.var(y_true)
    return jnp.where(
        var_y == 0, jnp.nan, 1.0 - jnp.var(y_true - y_pred) / jnp.where(var_y == 0, 1.0, var_y)
    )


LOSS_NAMES = ("approx_kl", "clip_fraction", "entropy_loss", "policy_gradient_loss", "value_loss")


def _early_stopped_losses(losses: dict[str, Array]) -> dict[str, Array]:
    """The loss metrics as SB3 logs them when ``target_kl`` stops the epochs: means over the
    gradient steps computed (``losses["computed"]``, ``[epochs, minibatches]``), approx KL
    over the last epoch that ran, the loss of the last step computed."""
    computed = losses["computed"].astype(jnp.float32)

    def mean(x: Array, mask: Array) -> Array:
        return (x * mask).sum() / jnp.maximum(mask.sum(), 1.0)

    last_epoch = jnp.max(jnp.where(computed.any(axis=1), jnp.arange(computed.shape[0]), 0))
    flat = computed.reshape(-1)
    last_step = jnp.max(jnp.where(flat > 0, jnp.arange(flat.shape[0]), 0))
    out = {f"train/{n}": mean(losses[n], computed) for n in LOSS_NAMES}
    out["train/approx_kl"] = mean(losses["approx_kl"][last_epoch], computed[last_epoch])
    out["train/loss"] = losses["loss"].reshape(-1)[last_step]
    return out


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
    if "computed" in losses:  # target_kl may have stopped the epochs: computed steps count
        loss_metrics = _early_stopped_losses(losses)
    else:
        loss_metrics = {f"train/{n}": losses[n].mean() for n in LOSS_NAMES}
        # SB3 resets its KL list every epoch, so it logs the last epoch's mean.
        loss_metrics["train/approx_kl"] = losses["approx_kl"][-1].mean()
        loss_metrics["train/loss"] = losses["loss"][-1, -1]

    def window_mean(x: Array) -> Array:
        return jnp.where(count > 0, (x * episodes.valid).sum() / jnp.maximum(count, 1), nan)

    return {
        "rollout/ep_rew_mean": window_mean(episodes.returns),
        "rollout/ep_len_mean": window_mean(episodes.lengths),
        # Best episode finished during this rollout (not an SB3 metric; sweeps rank by the
        # first time it reaches 500).
        "rollout/ep_rew_max": jnp.nan_to_num(
            jnp.max(jnp.where(done, episode_return, -jnp.inf)), neginf=jnp.nan
        ).astype(jnp.float32),
        **loss_metrics,
        "train/explained_variance": explained_variance(value_pred, returns),
        "train/learning_rate": jnp.asarray(learning_rate, jnp.float32),
    }


def custom_metrics(
    metrics: tuple[tuple[str, Callable[..., Any]], ...],
    rollout: Any,
    batch: Any,
    losses: dict[str, Array],
) -> dict[str, Array]:
    """A user's own metrics (``PPOConfig.metrics``) of one iteration, as float32 scalars.

    Args:
        metrics: ``(name, fn)`` pairs; each ``fn(rollout, batch, losses)`` returns a scalar.
        rollout: the iteration's :class:`~jaxcart.core.ppo.Transition`, fields
            ``[num_steps, num_envs, ...]`` (time-major).
        batch: the training :class:`~jaxcart.core.ppo.Batch`, fields ``[batch_size, ...]``.
        losses: the loss terms of every gradient step, ``[update_epochs, num_minibatches]``.

    Raises:
        ValueError: a function returned something other than one number.
    """
    out = {}
    for name, fn in metrics:
        value = jnp.asarray(fn(rollout, batch, losses))
        if value.size != 1:
            raise ValueError(f"metric {name!r} must return a scalar, got shape {value.shape}")
        out[name] = value.reshape(()).astype(jnp.float32)
    return out
