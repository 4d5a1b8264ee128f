"""The compiled chunk: R runs of :func:`~jaxcart.core.ppo.train_iteration`, vmapped over runs
and scanned over iterations, with the divergence guard around it.

A run is one independent agent (without a sweep the runs are the seeds; with one, every
combination x seed). Every array here has a leading run axis ``[R, ...]``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import env as cartpole
from jaxcart.core.config import PPOConfig
from jaxcart.core.metrics import EPISODE_WINDOW, METRIC_NAMES, EpisodeBuffer
from jaxcart.core.ppo import RunnerState, make_optimizer, train_iteration
from jaxcart.core.tricks import Hyperparams

Array = jax.Array


def initial_runners(
    params: dict, obs: np.ndarray, keys: np.ndarray, config: PPOConfig
) -> RunnerState:
    """Runners at iteration 0 from host-drawn parameters and reset observations (NumPy).

    Args:
        params: network parameters with a leading run axis, leaves ``[R, ...]``.
        obs: reset observations ``[R, num_envs, 4]`` (they are the env state: velocities and
            angles are the observation, and the step counters start at 0).
        keys: raw PRNG keys ``[R, 2]`` uint32.

    Returns:
        A :class:`RunnerState` with NumPy leaves ``[R, ...]``: Adam's moments and count at 0,
        no finished episodes, not diverged.
    """
    num_runs, num_envs = obs.shape[:2]
    one_run = jax.tree.map(lambda x: x[0], params)
    opt_shapes = jax.eval_shape(make_optimizer(Hyperparams.from_config(config)).init, one_run)
    zeros = lambda shape, dtype: np.zeros((num_runs, *shape), dtype)
    window = (EPISODE_WINDOW,)
    return RunnerState(
        params=params,
        opt_state=jax.tree.map(lambda s: zeros(s.shape, s.dtype), opt_shapes),
        env_state=cartpole.EnvState(
            obs[..., 0], obs[..., 1], obs[..., 2], obs[..., 3], zeros((num_envs,), np.int32)
        ),
        obs=obs,
        episode_return=zeros((num_envs,), obs.dtype),
        episode_length=zeros((num_envs,), np.int32),
        episodes=EpisodeBuffer(
            zeros(window, np.float32), zeros(window, np.float32), zeros(window, bool)
        ),
        key=keys,
        diverged_at=np.full((num_runs,), -1, np.int32),
    )


def guard_divergence(
    old: RunnerState, new: RunnerState, metrics: dict[str, Array], iteration: Array
) -> tuple[RunnerState, dict[str, Array]]:
    """Marks a run (no run axis here) whose update produced non-finite parameters or losses.

    Records ``diverged_at`` (1-based, as metrics.csv numbers iterations) the first time, and
    reports NaN metrics for every later iteration. It selects nothing: keeping the old state
    alive beside the new one, leaf by leaf, in every iteration made the compiled program about
    a third slower to compile (``benchmarks/RESULTS.md``, "Cold compile"). :func:`train_chunk`
    instead rolls a marked run back to its state at the start of the chunk (the last state a
    checkpoint can hold), so the run keeps finite parameters and later chunks leave it
    untouched.
    """
    finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(new.params)]))
    for name in ("train/loss", "train/value_loss", "train/policy_gradient_loss"):
        finite &= jnp.isfinite(metrics[name])
    frozen = old.diverged_at >= 0
    # recorded 1-based, as metrics.csv numbers iterations
    diverged_at = jnp.where(frozen | finite, old.diverged_at, (iteration + 1).astype(jnp.int32))
    metrics = {k: jnp.where(frozen, jnp.nan, v) for k, v in metrics.items()}
    return new.replace(diverged_at=diverged_at), metrics


def guarded_iteration(
    runner: RunnerState,
    hp: Hyperparams,
    iteration: Array,
    config: PPOConfig,
    env_params: cartpole.EnvParams,
) -> tuple[RunnerState, dict[str, Array]]:
    """:func:`~jaxcart.core.ppo.train_iteration` of one run, then :func:`guard_divergence`."""
    new, metrics = train_iteration(runner, hp, iteration, config, env_params)
    return guard_divergence(runner, new, metrics, iteration)


def roll_back_diverged(start: RunnerState, end: RunnerState) -> RunnerState:
    """``end``, except that every run marked diverged (``diverged_at >= 0``, leaves ``[R]``)
    gets its ``start`` state back, with its ``diverged_at`` kept."""
    diverged = end.diverged_at >= 0

    def pick(s: Array, e: Array) -> Array:
        return jnp.where(diverged.reshape(diverged.shape + (1,) * (e.ndim - 1)), s, e)

    return jax.tree.map(pick, start, end).replace(diverged_at=end.diverged_at)


def train_chunk(
    runners: RunnerState,
    hps: Hyperparams,
    start_iteration: Array,
    config: PPOConfig,
    env_params: cartpole.EnvParams,
    chunk_size: int,
    count: Array | None = None,
) -> tuple[RunnerState, dict[str, Array]]:
    """Scans up to ``chunk_size`` iterations of every run; jit this (config, env_params and
    chunk_size static).

    Args:
        runners: a :class:`RunnerState` with a leading run axis ``[R]``.
        hps: :class:`Hyperparams` with leaves ``[R]``.
        start_iteration: int32 scalar, the index of the chunk's first iteration. When
            ``chunk_size`` does not divide the run, iterations at or past
            ``config.num_iterations`` are skipped (state unchanged, metrics NaN) by a
            ``lax.cond``, so one compiled chunk serves any number of iterations; when it does,
            the guard is left out (a smaller program that compiles faster).
        count: int32 scalar or None. When given, only the chunk's first ``count`` iterations
            run (the rest are skipped like the overhang), so one compiled program runs chunks
            of any length up to ``chunk_size``: the host picks each chunk's length from the
            time the last one took. Skipping leaves the computed iterations bit-identical
            (the guard selects whole iterations; ``tests/test_trainer.py`` checks it).

    Returns:
        Runners after the chunk (a run that diverged during it rolled back to its state at the
        chunk's start, see :func:`guard_divergence`) and metrics with leaves
        ``[chunk_size, R]``.
    """
    runs_iteration = jax.vmap(guarded_iteration, in_axes=(0, 0, None, None, None))

    def run(runners: RunnerState, iteration: Array):
        return runs_iteration(runners, hps, iteration, config, env_params)

    num_runs = runners.key.shape[0]

    def skip(runners: RunnerState, iteration: Array):
        return runners, {name: jnp.full((num_runs,), jnp.nan, jnp.float32) for name in METRIC_NAMES}

    def body(runners: RunnerState, offset: Array):
        iteration = start_iteration + offset
        if count is None and config.num_iterations % chunk_size == 0:
            return run(runners, iteration)  # chunks tile the run: no guard needed
        active = iteration < config.num_iterations
        if count is not None:
            active &= offset < count
        return jax.lax.cond(active, run, skip, runners, iteration)

    end, metrics = jax.lax.scan(body, runners, jnp.arange(chunk_size, dtype=jnp.int32))
    return roll_back_diverged(runners, end), metrics


__all__ = [
    "guard_divergence",
    "guarded_iteration",
    "initial_runners",
    "roll_back_diverged",
    "train_chunk",
]
