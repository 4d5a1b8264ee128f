"""Aggregates over several configurations, rliable's *tasks*: the stratified bootstrap.

A run measured on several tasks (here: CartPole configurations, e.g. different environment
parameters) has one score array per task, ``tasks = [scores_task_0 [n_0], scores_task_1
[n_1], ...]``. rliable (Agarwal et al. 2021, ``rliable/library.py`` ``StratifiedBootstrap``
and ``get_interval_estimates``) resamples the runs (seeds) *within each task*, independently
across tasks, and never resamples the tasks themselves (its default ``task_bootstrap=False``):
the interval is the uncertainty of repeating the experiment with new seeds on the same tasks.
Its aggregates reduce all ``runs x tasks`` scores at once: ``aggregate_iqm`` is
``scipy.stats.trim_mean(scores, 0.25, axis=None)``, the IQM of every score pooled, and
``aggregate_optimality_gap`` likewise pools; ``probability_of_improvement`` is the mean over
tasks of each task's ``P(X_m > Y_m)``. This module does the same, every resample at once:

- :func:`stratified_bootstrap_ci`: a statistic of the pooled scores (seeds resampled per task);
- :func:`stratified_difference_ci`: the difference of that statistic between two runs;
- :func:`stratified_probability_of_improvement` and its ``_ci``.

Scores must be on one scale across tasks (rliable normalises each task's scores first, e.g.
by its maximum return; CartPole configurations share the maximum of 500, so nothing needs
normalising). rliable's score matrix gives every task the same number of seeds; here tasks
may differ, and the pooled statistic then weighs each task by its seed count. With one task
every function here is its single-run counterpart in :mod:`jaxcart.analysis.stats`, on the
same resamples.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jaxcart.analysis import stats


def _tasks(tasks: Sequence[np.ndarray], name: str) -> list[np.ndarray]:
    """Each task's scores ``[n_m]``, checked (1-D, finite, non-empty); at least one task."""
    if len(tasks) == 0:
        raise ValueError(f"{name} holds no task: pass one score array per task")
    return [stats.check_seeds(t, f"{name}[{m}]") for m, t in enumerate(tasks)]


def _pooled_resamples(tasks: list[np.ndarray], reps: int, rng: np.random.Generator) -> np.ndarray:
    """``[reps, sum n_m]``: each task's seeds resampled within the task, tasks side by side."""
    return np.concatenate([t[stats.resample_indices(t.size, reps, rng)] for t in tasks], axis=-1)


def stratified_bootstrap_ci(
    tasks: Sequence[np.ndarray],
    statistic: stats.Statistic = stats.iqm,
    reps: int = stats.DEFAULT_REPS,
    confidence: float = stats.CONFIDENCE,
    seed: int = stats.DEFAULT_SEED,
) -> stats.Estimate:
    """``statistic`` of all tasks' scores pooled, with a stratified percentile bootstrap
    interval (rliable's ``get_interval_estimates`` with ``aggregate_iqm``).

    Definition: value = ``statistic(concatenate(tasks))``; each resample replaces task ``m``'s
    ``n_m`` scores by ``n_m`` draws with replacement from them (task 0's indices first).

    Args:
        tasks: per task, ``[n_m]`` scores of one run (finite, non-empty).
        statistic: reduces ``[reps, N]`` along -1, e.g. :func:`stats.iqm`.

    Returns:
        The pooled estimate and its interval.
    """
    tasks = _tasks(tasks, "tasks")
    boot = statistic(_pooled_resamples(tasks, reps, np.random.default_rng(seed)), axis=-1)
    low, high = stats.percentile_interval(boot, confidence)
    return stats.Estimate(float(statistic(np.concatenate(tasks), axis=-1)), float(low), float(high))


def stratified_difference_ci(
    tasks_x: Sequence[np.ndarray],
    tasks_y: Sequence[np.ndarray],
    statistic: stats.Statistic = stats.iqm,
    reps: int = stats.DEFAULT_REPS,
    confidence: float = stats.CONFIDENCE,
    seed: int = stats.DEFAULT_SEED,
) -> stats.Estimate:
    """``statistic(pooled X) - statistic(pooled Y)`` with a stratified bootstrap interval:
    every task's seeds resampled within that task and run, X's tasks first, then Y's.

    Args:
        tasks_x: per task, ``[n_m]`` scores of run X; tasks_y: per task, ``[k_m]`` of run Y.
    """
    tasks_x, tasks_y = _tasks(tasks_x, "tasks_x"), _tasks(tasks_y, "tasks_y")
    rng = np.random.default_rng(seed)
    boot_x = statistic(_pooled_resamples(tasks_x, reps, rng), axis=-1)
    boot_y = statistic(_pooled_resamples(tasks_y, reps, rng), axis=-1)
    low, high = stats.percentile_interval(boot_x - boot_y, confidence)
    value = statistic(np.concatenate(tasks_x), axis=-1) - statistic(
        np.concatenate(tasks_y), axis=-1
    )
    return stats.Estimate(float(value), float(low), float(high))


def _paired(tasks_x: Sequence[np.ndarray], tasks_y: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Per task, the ``[n_m, k_m]`` pair wins of X's seeds over Y's (the tasks in one order)."""
    tasks_x, tasks_y = _tasks(tasks_x, "tasks_x"), _tasks(tasks_y, "tasks_y")
    if len(tasks_x) != len(tasks_y):
        raise ValueError(
            f"tasks_x has {len(tasks_x)} tasks and tasks_y {len(tasks_y)}: P(X > Y) compares "
            "the two runs task by task"
        )
    return [stats.pair_wins(x, y) for x, y in zip(tasks_x, tasks_y)]


def stratified_probability_of_improvement(
    tasks_x: Sequence[np.ndarray], tasks_y: Sequence[np.ndarray]
) -> float:
    """rliable's probability of improvement over tasks: the mean over tasks ``m`` of
    ``P(X_m > Y_m) + 0.5 P(X_m = Y_m)`` (:func:`stats.probability_of_improvement` per task).

    Args:
        tasks_x: per task, ``[n_m]`` scores of run X; tasks_y: the same tasks in the same
            order, ``[k_m]`` scores of run Y.
    """
    return float(np.mean([wins.mean() for wins in _paired(tasks_x, tasks_y)]))


def stratified_probability_of_improvement_ci(
    tasks_x: Sequence[np.ndarray],
    tasks_y: Sequence[np.ndarray],
    reps: int = stats.DEFAULT_REPS,
    confidence: float = stats.CONFIDENCE,
    seed: int = stats.DEFAULT_SEED,
) -> stats.Estimate:
    """:func:`stratified_probability_of_improvement` with a bootstrap interval: every task's
    seeds of X and of Y resampled within the task, independently (rliable's
    ``StratifiedIndependentBootstrap``); X's draws for all tasks first, then Y's.
    """
    wins = _paired(tasks_x, tasks_y)
    rng = np.random.default_rng(seed)
    cx = [stats.resample_counts(w.shape[0], reps, rng) for w in wins]  # [reps, n_m] each
    cy = [stats.resample_counts(w.shape[1], reps, rng) for w in wins]  # [reps, k_m] each
    # A resample's pairs in task m: x_i drawn cx_i times, y_j drawn cy_j times -> cx_i cy_j.
    boot = np.mean([((a @ w) * b).sum(-1) / w.size for w, a, b in zip(wins, cx, cy)], axis=0)
    low, high = stats.percentile_interval(boot, confidence)
    value = float(np.mean([w.mean() for w in wins]))
    return stats.Estimate(value, float(low), float(high))
