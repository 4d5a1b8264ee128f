"""The compiled chunk: R runs of :func:`~jaxcart.core.ppo.train_iteration`, vmapped over runs
and scanned over iterations, with the divergence guard around it.

A run is one independent agent (without a sweep the runs are the seeds; with one, every
combination x seed). Every array here has a leading run axis ``[R, ...]``.

With more than :data:`UPDATE_GROUP` runs on a CPU device, the update (the epochs of minibatch
steps, most of an iteration's time) is computed in groups of runs, vmapped within a group and
one group after another (:func:`grouped_iteration`); the rollout stays vmapped over all runs.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import pytree
from jaxcart.core.config import PPOConfig, float_dtype
from jaxcart.core.evaluation import BestPolicy, periodic_evaluation
from jaxcart.core.metrics import EPISODE_WINDOW, METRIC_NAMES, EpisodeBuffer
from jaxcart.core.ppo import (
    RunnerState,
    finish_iteration,
    make_network,
    make_optimizer,
    prepare_update,
    scheduled,
    update_epochs,
)
from jaxcart.core.pytree import split_per_run

Array = jax.Array

UPDATE_GROUP = 8
"""Most runs whose update is vmapped together on a CPU device. Why: the update of 8 runs
(parameters, Adam moments, activations) fits in a core's L2 cache where that of 32 does not;
with 32 runs on a core the update in groups of 8 took 0.89-0.96x as long as vmapped over all 32
(``benchmarks/RESULTS.md``)."""


def initial_runners(
    params: dict, obs: np.ndarray, keys: np.ndarray, config: PPOConfig, env_state: Any
) -> RunnerState:
    """Runners at iteration 0 from host-drawn parameters and reset observations (NumPy).

    Args:
        params: network parameters with a leading run axis, leaves ``[R, ...]``.
        obs: reset observations ``[R, num_envs, obs_dim]``.
        keys: raw PRNG keys ``[R, 2]`` uint32.
        env_state: the env's state pytree, leaves ``[R, num_envs]``.

    Returns:
        A :class:`RunnerState` with NumPy leaves ``[R, ...]``: Adam's moments and count at 0,
        no finished episodes, not diverged.
    """
    num_runs, num_envs = obs.shape[:2]
    one_run = jax.tree.map(lambda x: x[0], params)
    opt_shapes = jax.eval_shape(make_optimizer(config).init, one_run)
    zeros = lambda shape, dtype: np.zeros((num_runs, *shape), dtype)
    window = (EPISODE_WINDOW,)
    return RunnerState(
        params=params,
        opt_state=jax.tree.map(lambda s: zeros(s.shape, s.dtype), opt_shapes),
        env_state=env_state,
        obs=obs,
        episode_return=zeros((num_envs,), obs.dtype),
        episode_length=zeros((num_envs,), np.int32),
        episodes=EpisodeBuffer(
            zeros(window, np.float32), zeros(window, np.float32), zeros(window, bool)
        ),
        key=keys,
        diverged_at=np.full((num_runs,), -1, np.int32),
        best=None
        if not config.keep_best
        else BestPolicy(  # none yet: score -inf
            params=jax.tree.map(np.copy, params),
            score=np.full((num_runs,), -np.inf, np.float32),
            iteration=np.zeros((num_runs,), np.int32),
        ),
    )


def guard_divergence(
    old: RunnerState, new: RunnerState, metrics: dict[str, Array], iteration: Array
) -> tuple[RunnerState, dict[str, Array]]:
    """Marks a run (no run axis here) whose update produced non-finite parameters or losses.

    Records ``diverged_at`` (1-based, as metrics.csv numbers iterations) the first time, and
    reports NaN metrics for every later iteration. It selects nothing: keeping the old state
    alive beside the new one, leaf by leaf, in every iteration made the compiled program about
    a third slower to compile. The trainer instead
    rolls a marked run back to its state at the start of the chunk (the last state a
    checkpoint can hold) with :func:`roll_back_diverged`, compiled apart and only once a run
    has diverged, so the run keeps finite parameters and later chunks leave it untouched.
    """
    # one reduction over every parameter and the three losses: a kernel or two, where a check
    # per leaf compiles to about 16 distinct kernels
    checked = [x.reshape(-1) for x in jax.tree.leaves(new.params)]
    checked += [metrics[n].reshape(1) for n in ("train/loss", "train/value_loss")]
    checked.append(metrics["train/policy_gradient_loss"].reshape(1))
    finite = jnp.all(jnp.isfinite(jnp.concatenate(checked)))
    frozen = old.diverged_at >= 0
    # recorded 1-based, as metrics.csv numbers iterations
    diverged_at = jnp.where(frozen | finite, old.diverged_at, (iteration + 1).astype(jnp.int32))
    metrics = {k: jnp.where(frozen, jnp.nan, v) for k, v in metrics.items()}
    return new.replace(diverged_at=diverged_at), metrics


def group_layout(num_runs: int, group: int) -> tuple[int, int]:
    """``(groups, width)``: the fewest groups of at most ``group`` runs, all of one width
    (``groups * width >= num_runs``; the last group is padded by at most ``groups - 1`` runs)."""
    groups = -(-num_runs // group)
    return groups, -(-num_runs // groups)


def in_groups(fn: Callable, num_runs: int, group: int) -> Callable:
    """``jax.vmap(fn)`` over a leading run axis ``[num_runs]``, computed as groups of runs
    (:func:`group_layout`) vmapped within a group, one group after another (``lax.map``).

    The run axis is padded by repeating the last run (the padding is computed and dropped).
    A run's numbers depend only on the group width, so only on ``num_runs``: not on its
    position or its neighbours (as with a plain vmap).
    """
    groups, width = group_layout(num_runs, group)

    def pad_and_split(x: Array) -> Array:
        extra = groups * width - num_runs
        if extra:
            x = jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)])
        return x.reshape((groups, width) + x.shape[1:])

    def grouped(*args):
        out = jax.lax.map(lambda g: jax.vmap(fn)(*g), jax.tree.map(pad_and_split, args))
        return jax.tree.map(lambda x: x.reshape((groups * width,) + x.shape[2:])[:num_runs], out)

    return grouped


def grouped_iteration(
    runners: RunnerState,
    config: PPOConfig,
    iteration: Array,
    env_params: Any,
    group: int | None = None,
) -> tuple[RunnerState, dict[str, Array]]:
    """:func:`~jaxcart.core.ppo.train_iteration` of every run ``[R]``, then
    :func:`guard_divergence`: vmapped over the runs, except the update with more than ``group``
    runs, computed in groups of at most ``group`` runs (:func:`in_groups`; None: never). The same
    arithmetic per run, but XLA then compiles the update for the group width, so the last bits
    differ from a plain vmap."""
    config = scheduled(config, iteration)
    before, rollout, batch, update_key, learning_rate = jax.vmap(
        prepare_update, in_axes=(0, 0, None, env_axes(env_params))
    )(runners, config, iteration, env_params)
    num_runs = len(runners.key)
    if group is None or num_runs <= group:
        update = jax.vmap(update_epochs)
    else:
        update = in_groups(update_epochs, num_runs, group)
    params, opt_state, losses = update(
        before.params, before.opt_state, batch, update_key, learning_rate, config
    )
    new, metrics = jax.vmap(finish_iteration)(
        before, rollout, batch, learning_rate, params, opt_state, losses, config
    )
    return jax.vmap(guard_divergence, in_axes=(0, 0, 0, None))(runners, new, metrics, iteration)


def env_axes(env_params: Any) -> Any:
    """The vmap axes of ``env_params`` over runs: None when every field is one value for all
    runs (the default, a constant of the program), else 0 for each field that holds an array
    ``[R]`` (a swept or randomised :func:`~jaxcart.core.pytree.per_run_field`) and None for
    the others. Fields not declared per run are constants whatever their shapes: gymnax's
    Acrobot's ``available_torque`` ``[3]`` is not a run axis."""
    if not split_per_run(env_params)[1]:
        return None
    return jax.tree.map(lambda v: 0 if jnp.ndim(v) else None, env_params)


def evaluate_runs(
    runners: RunnerState,
    metrics: dict[str, Array],
    config: PPOConfig,
    iteration: Array,
    env_params: Any,
) -> tuple[RunnerState, dict[str, Array]]:
    """:func:`~jaxcart.core.evaluation.periodic_evaluation` of every run ``[R]`` after an
    iteration: its metrics join the iteration's, its best policy the runners."""
    network = make_network(config)

    def one_run(runner: RunnerState, run_config: PPOConfig, run_env: Any):
        healthy = runner.diverged_at < 0
        return periodic_evaluation(
            runner.params, runner.best, healthy, run_config, iteration, network, run_env
        )

    axes = (0, 0, env_axes(env_params))  # each run on its own physics, when they differ
    best, evaluated = jax.vmap(one_run, in_axes=axes)(runners, config, env_params)
    return runners.replace(best=best), {**metrics, **evaluated}


def roll_back_diverged(start: RunnerState, end: RunnerState) -> RunnerState:
    """``end``, except that every run marked diverged (``diverged_at >= 0``, leaves ``[R]``)
    gets its ``start`` state back, with its ``diverged_at`` kept.

    Not part of :func:`train_chunk`: inside it, these selects (one per leaf of the state) and
    the start state kept alive across the chunk's loop made the default run's program 13
    kernels larger (220 against 207) for an event most runs never see. The trainer calls it
    only once a run has diverged."""
    rolled_back = pytree.where(end.diverged_at >= 0, start, end)
    return rolled_back.replace(diverged_at=end.diverged_at)


def train_chunk(
    runners: RunnerState,
    config: PPOConfig,
    start_iteration: Array,
    env_params: Any,
    chunk_size: int,
    update_group: int | None = None,
    count: Array | None = None,
) -> tuple[RunnerState, dict[str, Array]]:
    """Scans up to ``chunk_size`` iterations of every run; jit this (env_params and chunk_size
    static; the config's static fields are part of its pytree structure).

    ``env_params``' fields are numbers (constants of the program), except those that differ
    between runs: arrays ``[R]``, vmapped with the runs (:func:`env_axes`).

    Args:
        runners: a :class:`RunnerState` with a leading run axis ``[R]``.
        config: every run's config, its traced fields ``[R]`` (:meth:`PPOConfig.per_run`).
        start_iteration: int32 scalar, the index of the chunk's first iteration. When
            ``chunk_size`` does not divide the run, iterations at or past
            ``config.num_iterations`` are skipped (state unchanged, metrics NaN) by a
            ``lax.cond``, so one compiled chunk serves any number of iterations; when it does,
            the guard is left out (a smaller program that compiles faster).
        update_group: with more runs than this, the update runs in groups of at most this
            many (:func:`grouped_iteration`); None vmaps everything over all runs.
        count: int32 scalar or None. When given, only the chunk's first ``count`` iterations
            run (the rest are skipped like the overhang), so one compiled program runs chunks
            of any length up to ``chunk_size``: the host picks each chunk's length from the
            time the last one took. Skipping leaves the computed iterations bit-identical
            (the guard selects whole iterations; ``tests/test_trainer.py`` checks it).

    Returns:
        Runners after the chunk and metrics with leaves ``[chunk_size, R]``. A run marked
        diverged during the chunk (:func:`guard_divergence`) holds non-finite state until the
        caller rolls it back to the chunk's start (:func:`roll_back_diverged`): so do not
        donate ``runners`` to this program.
    """
    num_runs = runners.key.shape[0]

    # Every metric leaves an iteration in the training's float type (float32; float64 under
    # x64), so the skipped iteration's NaNs are known without tracing the iteration again.
    dtype = float_dtype()
    names = (*METRIC_NAMES, *config.extra_metric_names)

    def run(runners: RunnerState, iteration: Array):
        runners, metrics = grouped_iteration(runners, config, iteration, env_params, update_group)
        if config.eval_every:  # nothing is added to the program without it
            runners, metrics = evaluate_runs(runners, metrics, config, iteration, env_params)
        return runners, {name: value.astype(dtype) for name, value in metrics.items()}

    def skip(runners: RunnerState, iteration: Array):
        return runners, {name: jnp.full((num_runs,), jnp.nan, dtype) for name in names}

    def body(runners: RunnerState, offset: Array):
        iteration = start_iteration + offset
        if count is None and config.num_iterations % chunk_size == 0:
            return run(runners, iteration)  # chunks tile the run: no guard needed
        active = iteration < config.num_iterations
        if count is not None:
            active &= offset < count
        return jax.lax.cond(active, run, skip, runners, iteration)

    return jax.lax.scan(body, runners, jnp.arange(chunk_size, dtype=jnp.int32))
