"""Statistics for many seeds: the estimators of Agarwal et al. (2021), "Deep Reinforcement
Learning at the Edge of the Statistical Precipice" (the ``rliable`` library), in NumPy.

A run's *scores* are one number per seed (``[num_seeds]``; :mod:`jaxcart.compare` uses each
seed's mean greedy Gymnasium return). Over them:

- point estimates: :func:`iqm` (the interquartile mean, 25% trimmed mean), :func:`mean`,
  :func:`median` (the median over seeds), :func:`optimality_gap` (how far below CartPole-v1's
  maximum of 500, on average);
- :func:`bootstrap_ci`: a percentile bootstrap confidence interval of any of them, and
  :func:`difference_ci` of the difference between two runs;
- :func:`probability_of_improvement` of run X over run Y, ``P(X > Y) + 0.5 P(X = Y)`` over
  all seed pairs, and :func:`probability_of_improvement_ci`: the effect size to print (see
  there why not Cohen's d);
- :func:`wilson_interval`: a success rate (seeds solved out of n) with its Wilson interval;
- :func:`performance_profile` (fraction of seeds scoring above tau, or at least tau) and
  :func:`performance_profile_band`;
- :func:`curve_band`: a statistic across seeds of a learning curve ``[iterations, seeds]``
  with a bootstrap band per iteration (whole curves are resampled, as rliable does).

**Tasks.** A run measured on several tasks (here: CartPole configurations, e.g. different
environment parameters) has one score array per task, ``[scores_task_0 [n_0], scores_task_1
[n_1], ...]`` (:data:`Scores`), and :func:`bootstrap_ci`, :func:`difference_ci`,
:func:`probability_of_improvement` and its ``_ci`` take it in place of ``[n]``. rliable
(``rliable/library.py`` ``StratifiedBootstrap`` and ``get_interval_estimates``) resamples the
runs (seeds) *within each task*, independently across tasks, and never resamples the tasks
themselves (its default ``task_bootstrap=False``): the interval is the uncertainty of
repeating the experiment with new seeds on the same tasks. Its aggregates reduce all ``runs x
tasks`` scores at once: ``aggregate_iqm`` is ``scipy.stats.trim_mean(scores, 0.25,
axis=None)``, the IQM of every score pooled, and ``aggregate_optimality_gap`` likewise pools;
``probability_of_improvement`` is the mean over tasks of each task's ``P(X_m > Y_m)``. Here
too, every resample at once. Scores must be on one scale across tasks (rliable normalises each
task's scores first, e.g. by its maximum return; CartPole configurations share the maximum of
500, so nothing needs normalising). rliable's score matrix gives every task the same number of
seeds; here tasks may differ, and the pooled statistic then weighs each task by its seed
count. One task is the ordinary bootstrap over seeds, on the same resamples.

Beside this module: :mod:`jaxcart.analysis.summary` turns learning curves into per-seed scores
(area under the curve, return at a budget).

**NaN.** Scores are refused when they hold NaN (or infinity) or are empty: every function
over scores raises ``ValueError`` naming the argument and counting the NaN, because a NaN
score has no meaning (it would be trimmed, sorted last or compared as a loss, and give a
finite wrong answer). Learning curves are different: ``rollout/ep_rew_mean`` is NaN until a
seed's first episode ends (and after a seed diverges), so :func:`nan_iqm`, :func:`curve_band`
and :func:`first_at_least` keep their NaN semantics, each stated in its docstring.

Definitions follow rliable 1.2.0 (``rliable/metrics.py`` and ``library.py``): IQM is
``scipy.stats.trim_mean(x, 0.25)``; the optimality gap ``gamma - mean(min(x, gamma))`` equals
``mean(max(gamma - x, 0))``; the probability of improvement is the Mann-Whitney U statistic
over ``n * m``; profiles count scores strictly above tau; intervals are the 2.5th and 97.5th
percentiles of the bootstrap distribution (NumPy's linear interpolation). With one task
(CartPole) rliable's stratified bootstrap is the ordinary bootstrap over seeds. One name
differs: :func:`median` is the median over seeds, where rliable's ``aggregate_median`` is the
median over tasks of each task's mean score (on one task: the mean, e.g. 467.8 against 500).

**Why not rliable itself.** ``rliable`` 1.2.0 resolves beside jaxcart's pins without a
conflict, but brings eight packages (``arch``, ``statsmodels``, ``pandas``, ``seaborn``,
``patsy``, ...) for about a hundred lines of arithmetic, and its bootstrap (``arch``'s
``IIDBootstrap``) calls the statistic once per resample in a Python loop (rliable's default is
50,000 resamples per interval), where a comparison needs hundreds of intervals (every run,
estimator, tau and curve point). Here every bootstrap is a few array operations over all
resamples at once (10 runs x 64 seeds take well under a second), and jaxcart's dependencies
stay as they are. ``tests/test_stats.py`` checks each definition on fixed
samples against values worked out by hand, by brute force or by SciPy.

**Many comparisons.** What a set of comparisons can still say: saturation, and many intervals
read at once.

- :func:`saturated`: every score of every run is the same (e.g. every seed at 500). Then every
  bootstrap interval is a point, every difference 0 and every probability of improvement 0.5:
  the runs cannot be told apart by these scores, and the comparison should say so instead of
  printing a table of identical intervals (compare a harder score, e.g. the area under the
  learning curve, :func:`jaxcart.analysis.summary.auc`).
- :func:`bonferroni_confidence`, :func:`familywise_miss_bound`: each
  95% interval covers its true value 95% of the time *on its own*; reading N of them at once,
  the chance that at least one misses is up to N x 5% (Bonferroni's bound, from
  ``P(A or B) <= P(A) + P(B)``). Either say so, or widen each interval to confidence
  ``1 - 5%/N`` so that all N hold together with probability at least 95%.

Everything is deterministic: resamples come from ``np.random.default_rng(seed)``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from jaxcart.core.solved import SOLVED_RETURN

DEFAULT_REPS = 2000
"""Bootstrap resamples: enough for stable 2.5%/97.5% percentiles (rliable's profile default)."""
CONFIDENCE = 0.95
DEFAULT_SEED = 0
_CHUNK_ELEMENTS = 1 << 22  # resampled curve values held at once (32 MiB of float64)

Statistic = Callable[..., np.ndarray]
"""``statistic(values, axis=-1)``: reduces the last axis, e.g. ``np.mean`` or :func:`iqm`."""
Scores = np.ndarray | Sequence[np.ndarray]
"""One run's scores: ``[n]`` (one per seed), or per task ``[n_m]`` each (:func:`check_tasks`).
Every interval below takes either: on several tasks, seeds are resampled within each task and
the tasks never (rliable's stratified bootstrap, see the module docstring); on one task that is
the ordinary bootstrap over seeds."""


@dataclass(frozen=True)
class Estimate:
    """A point estimate and its confidence interval."""

    value: float
    ci_low: float
    ci_high: float

    def to_dict(self) -> dict[str, float]:
        return {"value": self.value, "ci_low": self.ci_low, "ci_high": self.ci_high}

    def format(self, digits: int = 1) -> str:
        """``412.3 [380.0, 450.5]``."""
        return f"{self.value:.{digits}f} [{self.ci_low:.{digits}f}, {self.ci_high:.{digits}f}]"


def check_scores(values: np.ndarray, name: str = "scores") -> np.ndarray:
    """``values`` as a float array, refused if it is empty or holds NaN or infinity.

    Args:
        values: ``[...]`` scores (any shape, at least one entry).
        name: the argument's name, for the error message.

    Raises:
        ValueError: naming ``name`` and counting its NaN and infinite entries.
    """
    values = np.asarray(values, float)
    if values.size == 0:
        raise ValueError(f"{name} is empty (shape {values.shape}): no score to summarise")
    finite = np.isfinite(values)
    if not finite.all():
        nan = int(np.isnan(values).sum())
        raise ValueError(
            f"{name} holds {nan} NaN and {int((~finite).sum()) - nan} infinite values among "
            f"{values.size}: scores must be finite (a NaN score would be sorted, trimmed or "
            "compared as a number)"
        )
    return values


def check_seeds(values: np.ndarray, name: str = "scores") -> np.ndarray:
    """One run's scores: :func:`check_scores`, and 1-D.

    Args:
        values: ``[n]`` per-seed scores; name: the argument's name, for the error message.
    """
    values = np.asarray(values, float)
    if values.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array of per-seed scores, got shape {values.shape}")
    return check_scores(values, name)


def check_tasks(scores: Scores, name: str = "scores") -> list[np.ndarray]:
    """One run's scores per task (rliable's *tasks*, :mod:`jaxcart.analysis.stats`'s module
    docstring), each :func:`check_seeds`-checked: an array, or a sequence of numbers, is one
    task (``name``); a sequence of arrays is one per task (``name[0]``, ``name[1]``, ...).

    Args:
        scores: ``[n]``, or per task ``[n_m]``.
    """
    if isinstance(scores, np.ndarray) or len(scores) == 0 or np.ndim(scores[0]) == 0:
        return [check_seeds(scores, name)]
    return [check_seeds(t, f"{name}[{m}]") for m, t in enumerate(scores)]


def iqm(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% (``int(0.25 n)`` cut from each end),
    ``scipy.stats.trim_mean(scores, 0.25, axis)`` as rliable computes it, in NumPy alone
    (importing ``scipy.stats`` takes about two seconds).

    Args:
        scores: ``[..., n]`` (reduced along ``axis``), finite (:func:`check_scores`).
    """
    ordered = np.sort(np.moveaxis(check_scores(scores), axis, -1), axis=-1)
    n = ordered.shape[-1]
    cut = int(0.25 * n)
    return ordered[..., cut : n - cut].mean(-1)


def mean(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """The mean over seeds, ``[..., n] -> [...]`` along ``axis`` (finite scores only)."""
    return np.mean(check_scores(scores), axis=axis)


def median(scores: np.ndarray, axis: int = -1) -> np.ndarray:
    """The median over seeds, ``[..., n] -> [...]`` along ``axis`` (finite scores only).

    Not rliable's ``aggregate_median``, the median over tasks of each task's mean score.
    """
    return np.median(check_scores(scores), axis=axis)


def optimality_gap(scores: np.ndarray, axis: int = -1, target: float = SOLVED_RETURN) -> np.ndarray:
    """Mean shortfall from ``target`` (default CartPole-v1's maximum return, 500):
    ``mean(max(target - x, 0))`` along ``axis``."""
    return np.mean(np.maximum(target - check_scores(scores), 0.0), axis=axis)


ESTIMATORS: dict[str, Statistic] = {
    "mean": mean,
    "median": median,
    "iqm": iqm,
    "optimality_gap": optimality_gap,
}
"""The aggregate estimates of a run, by name (each reduces ``axis``; ``"median"`` is the median
over seeds)."""


RANGE_BELOW = {"iqm": 5, "median": 6, "mean": 4, "optimality_gap": 4}
"""Seeds below which the percentile bootstrap interval of each estimator (at
:data:`CONFIDENCE`) is the range of the seeds, the lowest and highest score, rather than a
confidence interval: the resamples whose statistic equals the lowest seed's score are more
than the 2.5% tail (IQM of 4 seeds: 3 of 4 draws of the lowest, 5.1%; median of 5: 3 of 5,
5.8%; mean of 3: all three, 3.7%). ``tests/test_stats.py`` checks each bound."""


def interval_label(num_seeds: int | Sequence[int], statistic: str = "iqm") -> str:
    """What an interval of ``statistic`` over ``num_seeds`` seeds shows, for a table header:
    ``"95% CI"``, or ``"range of 2 seeds"`` below :data:`RANGE_BELOW` (never "CI" for what
    is only the seeds' range).

    Args:
        num_seeds: one run's seeds, or the seed counts of the runs that share the column
            (``"95% CI; range below 5 seeds"`` when some have too few and the counts differ).
        statistic: a name of :data:`ESTIMATORS`.
    """
    counts = {int(n) for n in np.atleast_1d(num_seeds)}
    below = RANGE_BELOW[statistic]
    ci = f"{CONFIDENCE:.0%} CI"
    if min(counts) >= below:
        return ci
    if len(counts) == 1:
        return f"range of {min(counts)} seed{'s' if min(counts) != 1 else ''}"
    return f"{ci}; range below {below} seeds"


def resample_indices(num: int, reps: int, rng: np.random.Generator) -> np.ndarray:
    """Indices of ``reps`` bootstrap resamples of ``num`` samples, ``[reps, num]``."""
    return rng.integers(0, num, size=(reps, num))


def resample_counts(num: int, reps: int, rng: np.random.Generator) -> np.ndarray:
    """How often each sample is drawn in each resample, ``[reps, num]`` (rows sum to num)."""
    idx = resample_indices(num, reps, rng)
    flat = (idx + num * np.arange(reps)[:, None]).ravel()
    return np.bincount(flat, minlength=reps * num).reshape(reps, num)


def percentile_interval(
    boot: np.ndarray, confidence: float = CONFIDENCE
) -> tuple[np.ndarray, np.ndarray]:
    """The percentile interval of bootstrap replicates ``[reps, ...]`` -> two ``[...]``
    (NaN replicates, e.g. resamples with no finite value, are left out)."""
    tail = 100 * (1 - confidence) / 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # "All-NaN slice": NaN is the answer
        low, high = np.nanpercentile(boot, [tail, 100 - tail], axis=0)
    return low, high


def _resampled(tasks: list[np.ndarray], reps: int, rng: np.random.Generator) -> np.ndarray:
    """``[reps, sum n_m]``: each task's seeds resampled within the task, tasks side by side."""
    return np.concatenate([t[resample_indices(t.size, reps, rng)] for t in tasks], axis=-1)


def bootstrap_ci(
    scores: Scores,
    statistic: Statistic,
    reps: int = DEFAULT_REPS,
    confidence: float = CONFIDENCE,
    seed: int = DEFAULT_SEED,
) -> Estimate:
    """``statistic(scores)`` and its percentile bootstrap confidence interval; on several
    tasks, ``statistic`` of all their scores pooled (rliable's ``get_interval_estimates``
    with ``aggregate_iqm``: ``scipy.stats.trim_mean(scores, 0.25, axis=None)``).

    Args:
        scores: ``[n]``, one per seed, or per task ``[n_m]`` (each task's seeds resampled
            within it, task 0's indices first); ``statistic(values, axis=-1)`` reduces
            ``[reps, n]``.

    Returns:
        The estimate; with one seed the interval is that one value (degenerate).
    """
    tasks = check_tasks(scores, "scores")
    resampled = _resampled(tasks, reps, np.random.default_rng(seed))
    low, high = percentile_interval(statistic(resampled, axis=-1), confidence)
    return Estimate(float(statistic(np.concatenate(tasks), axis=-1)), float(low), float(high))


def difference_ci(
    x: Scores,
    y: Scores,
    statistic: Statistic = iqm,
    reps: int = DEFAULT_REPS,
    confidence: float = CONFIDENCE,
    seed: int = DEFAULT_SEED,
) -> Estimate:
    """``statistic(x) - statistic(y)`` with a percentile bootstrap interval.

    Each resample draws X's seeds with replacement from X and, independently, Y's from Y
    (X's indices first, then Y's, from one generator; on several tasks within each task), as
    :func:`probability_of_improvement_ci` does; all resamples are reduced at once
    (``statistic`` reduces ``[reps, n]`` along -1). An interval that excludes 0 says the
    difference is larger than seed-to-seed noise.

    Args:
        x: ``[n]`` scores of run X; y: ``[m]`` scores of run Y (finite, non-empty); or each
            per task (:data:`Scores`), the statistic of each run's tasks pooled.

    Returns:
        The difference (positive: X higher) and its interval.
    """
    x, y = check_tasks(x, "x"), check_tasks(y, "y")
    rng = np.random.default_rng(seed)
    boot_x = statistic(_resampled(x, reps, rng), axis=-1)
    boot = boot_x - statistic(_resampled(y, reps, rng), axis=-1)  # [reps]
    low, high = percentile_interval(boot, confidence)
    value = statistic(np.concatenate(x), axis=-1) - statistic(np.concatenate(y), axis=-1)
    return Estimate(float(value), float(low), float(high))


def wilson_interval(successes: int, n: int, confidence: float = CONFIDENCE) -> Estimate:
    """A success rate ``successes / n`` (e.g. seeds solved) and its Wilson score interval.

    With ``p = successes / n`` and ``z`` the normal quantile at ``1 - (1 - confidence) / 2``
    (1.960 at 95%): ``(p + z²/2n ∓ z sqrt(p(1-p)/n + z²/4n²)) / (1 + z²/n)`` (Wilson 1927;
    SciPy's ``binomtest(k, n).proportion_ci(method="wilson")``). Unlike the normal
    approximation it stays inside [0, 1] and does not collapse at 0 or n successes: 64 of 64
    gives [0.9434, 1], a failure rate of up to 5.7% that 64 seeds cannot rule out.

    Args:
        successes: ``0 <= successes <= n``; n: trials, ``>= 1``.
        confidence: in (0, 1).
    """
    _check("n", n, confidence, " of trials")
    if int(successes) != successes or not 0 <= successes <= n:
        raise ValueError(f"successes must be a whole number in [0, n={n}], got {successes}")
    z = NormalDist().inv_cdf(1 - (1 - confidence) / 2)
    p, z2 = successes / n, z * z
    center = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / (1 + z2 / n)
    return Estimate(p, max(0.0, center - half), min(1.0, center + half))


def _task_wins(x: Scores, y: Scores) -> list[np.ndarray]:
    """Per task, the ``[n_m, k_m]`` pair wins of X's seeds over Y's (the tasks in one order):
    1 where ``x_i > y_j``, 0.5 where equal, 0 where less."""
    x, y = check_tasks(x, "x"), check_tasks(y, "y")
    if len(x) != len(y):
        raise ValueError(
            f"x has {len(x)} tasks and y {len(y)}: P(X > Y) compares the two runs task by task"
        )
    return [(a[:, None] > b) + 0.5 * (a[:, None] == b) for a, b in zip(x, y)]


def probability_of_improvement(x: Scores, y: Scores) -> float:
    """``P(X > Y) + 0.5 P(X = Y)`` for a random seed of X and a random seed of Y: the share of
    the ``n * m`` seed pairs that X wins, ties counting half (Mann-Whitney ``U / (n m)``); on
    several tasks, the mean over tasks of each task's (rliable's ``probability_of_improvement``).

    This is the effect size the comparison should print (0.5: no difference), beside
    :func:`difference_ci` for the size in returns. A standardised mean difference (Cohen's d)
    is not offered: its scale, the pooled SD, collapses on bounded, tied scores (every seed at
    500 against every seed at 499 divides by 0, where this gives 1), and one seed at 20 or at
    499 among 63 at 500, against 64 at 500, gives the same d = -0.18, so it adds nothing here.

    Args:
        x: ``[n]`` scores of run X; y: ``[m]`` scores of run Y (finite, non-empty); or each
            per task, the same tasks in the same order.
    """
    return float(np.mean([wins.mean() for wins in _task_wins(x, y)]))


def probability_of_improvement_ci(
    x: Scores,
    y: Scores,
    reps: int = DEFAULT_REPS,
    confidence: float = CONFIDENCE,
    seed: int = DEFAULT_SEED,
) -> Estimate:
    """:func:`probability_of_improvement` with a bootstrap interval; X's and Y's seeds are
    resampled independently, within each task (rliable's ``StratifiedIndependentBootstrap``),
    X's draws for all tasks first, then Y's.

    Args:
        x: ``[n]``; y: ``[m]``; or each per task.
    """
    wins = _task_wins(x, y)
    rng = np.random.default_rng(seed)
    cx = [resample_counts(w.shape[0], reps, rng) for w in wins]  # [reps, n_m] each
    cy = [resample_counts(w.shape[1], reps, rng) for w in wins]  # [reps, k_m] each
    # A resample's pairs in task m: x_i drawn cx_i times, y_j drawn cy_j times -> cx_i cy_j.
    boot = np.mean([((a @ w) * b).sum(-1) / w.size for w, a, b in zip(wins, cx, cy)], axis=0)
    low, high = percentile_interval(boot, confidence)
    return Estimate(float(np.mean([w.mean() for w in wins])), float(low), float(high))


def _above(scores: np.ndarray, taus: np.ndarray, at_least: bool) -> np.ndarray:
    """``[..., n, T]``: whether each score is above (or at least) each tau."""
    scores, taus = check_scores(scores)[..., :, None], np.asarray(taus, float)
    return scores >= taus if at_least else scores > taus


def performance_profile(scores: np.ndarray, taus: np.ndarray, at_least: bool = False) -> np.ndarray:
    """Fraction of seeds scoring strictly above each tau (rliable's score distribution), or at
    least tau with ``at_least=True``.

    rliable's strict ``>`` is 0 at tau = 500 on CartPole whatever the run, hiding the fraction
    of seeds at the maximum; the comparison should plot ``at_least=True`` (the curve then ends
    at the share of seeds scoring 500, and starts at 1 for tau = 0).

    Args:
        scores: ``[..., n]`` (finite, non-empty); taus: ``[T]``.

    Returns:
        ``[..., T]``.
    """
    return _above(scores, taus, at_least).mean(axis=-2)


def performance_profile_band(
    scores: np.ndarray,
    taus: np.ndarray,
    reps: int = DEFAULT_REPS,
    confidence: float = CONFIDENCE,
    seed: int = DEFAULT_SEED,
    at_least: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The profile of ``scores`` ``[n]`` at ``taus`` ``[T]`` and its bootstrap band
    (``at_least`` as in :func:`performance_profile`).

    Returns:
        ``(profile, low, high)``, each ``[T]``.
    """
    above = _above(check_seeds(scores, "scores"), taus, at_least).astype(float)
    n = above.shape[0]
    counts = resample_counts(n, reps, np.random.default_rng(seed))  # [reps, n]
    low, high = percentile_interval(counts @ above / n, confidence)  # [reps, T] -> [T]
    return above.mean(axis=0), low, high


def nan_iqm(values: np.ndarray, axis: int = -1) -> np.ndarray:
    """:func:`iqm` of the finite entries along ``axis`` (NaN where there are none)."""
    values = np.moveaxis(np.asarray(values, float), axis, -1)
    finite = np.isfinite(values)
    if values.shape[-1] and finite.all():  # the common case, twice as fast
        return iqm(values)
    ordered = np.sort(values, axis=-1)  # NaN sorts last
    n = finite.sum(-1, keepdims=True)
    cut = np.floor(0.25 * n)  # scipy's int(0.25 * n)
    pos = np.arange(values.shape[-1])
    keep = (pos >= cut) & (pos < n - cut)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(keep, ordered, 0.0).sum(-1) / keep.sum(-1)


def _nan_mean(values: np.ndarray, axis: int = -1) -> np.ndarray:
    finite = np.isfinite(values)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(finite, values, 0.0).sum(axis) / finite.sum(axis)


CURVE_STATISTICS: dict[str, Statistic] = {"mean": _nan_mean, "iqm": nan_iqm}


def curve_band(
    values: np.ndarray,
    statistic: str = "mean",
    reps: int = DEFAULT_REPS,
    confidence: float = CONFIDENCE,
    seed: int = DEFAULT_SEED,
    bounds: tuple[float, float] = (-math.inf, math.inf),
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A statistic across seeds of a learning curve, per iteration, with a bootstrap band.

    Each resample draws whole seeds (one set of seed indices for every iteration, as rliable
    resamples runs); NaN entries (no value yet) are left out of each statistic.

    Args:
        values: ``[iterations, num_seeds]``, NaN where a seed has no value.
        statistic: ``"mean"`` or ``"iqm"``.
        bounds: the metric's range; the band is clipped to it.

    Returns:
        ``(point, low, high)``, each ``[iterations]``: ``point`` NaN where no seed has a value,
        ``low``/``high`` NaN where fewer than two seeds do.
    """
    values = np.asarray(values, float)
    if values.ndim != 2:
        raise ValueError(f"values must be [iterations, num_seeds], got shape {values.shape}")
    reduce = CURVE_STATISTICS[statistic]
    point = reduce(values, axis=-1)
    rng = np.random.default_rng(seed)
    if statistic == "mean":
        # A resample's mean is a weighted sum: two matrix products over all resamples at once.
        counts = resample_counts(values.shape[1], reps, rng).T  # [S, reps]
        finite = np.isfinite(values)
        with np.errstate(invalid="ignore", divide="ignore"):
            boot = (np.where(finite, values, 0.0) @ counts) / (finite @ counts)  # [T, reps]
        low, high = percentile_interval(boot.T, confidence)
    else:
        idx = resample_indices(values.shape[1], reps, rng)  # [reps, S]
        rows = max(1, _CHUNK_ELEMENTS // idx.size)
        parts = [
            percentile_interval(reduce(values[i : i + rows][:, idx], axis=-1).T, confidence)
            for i in range(0, len(values), rows)
        ]
        low = np.concatenate([p[0] for p in parts])
        high = np.concatenate([p[1] for p in parts])
    few = np.isfinite(values).sum(-1) < 2
    low, high = np.where(few, np.nan, low), np.where(few, np.nan, high)
    return point, np.clip(low, *bounds), np.clip(high, *bounds)


def first_at_least(values: np.ndarray, x: np.ndarray, target: float) -> np.ndarray:
    """Where each seed's curve first reaches ``target``.

    Args:
        values: ``[iterations, num_seeds]`` (NaN never reaches); x: ``[iterations]``, e.g.
            env steps or seconds.

    Returns:
        ``[num_seeds]``: ``x`` at the first iteration with ``values >= target``, ``inf`` for
        seeds that never do.
    """
    reached = np.nan_to_num(np.asarray(values, float), nan=-np.inf) >= target
    first = reached.argmax(0)
    return np.where(reached.any(0), np.asarray(x, float)[first], np.inf)


def fraction_reached(first: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Fraction of seeds that had reached the target by each ``x``.

    Args:
        first: ``[num_seeds]`` from :func:`first_at_least`; x: ``[P]``.

    Returns:
        ``[P]``.
    """
    return (np.asarray(first, float)[:, None] <= np.asarray(x, float)).mean(0)


def saturated(runs: Sequence[np.ndarray]) -> bool:
    """Whether all scores of all runs are equal (nothing left to discriminate).

    Args:
        runs: per run, ``[n_r]`` scores (finite, non-empty), e.g. each seed's mean return.
    """
    if len(runs) == 0:
        raise ValueError("runs holds no run")
    pooled = np.concatenate([check_seeds(r, f"runs[{i}]") for i, r in enumerate(runs)])
    return bool((pooled == pooled[0]).all())


def _check(name: str, count: int, confidence: float, unit: str = "") -> None:
    """Raises ``ValueError`` unless ``count`` (named ``name``) is a positive whole number (of
    ``unit``) and ``confidence`` is in (0, 1)."""
    if int(count) != count or count < 1:
        raise ValueError(f"{name} must be a positive whole number{unit}, got {count}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")


def bonferroni_confidence(comparisons: int, confidence: float = CONFIDENCE) -> float:
    """The confidence each of ``comparisons`` intervals needs for all of them to hold together
    with probability at least ``confidence``: ``1 - (1 - confidence) / comparisons``
    (0.9875 for 4 comparisons at 95%). Pass it as ``confidence=`` to the interval functions.
    """
    _check("comparisons", comparisons, confidence)
    return 1 - (1 - confidence) / comparisons


def familywise_miss_bound(comparisons: int, confidence: float = CONFIDENCE) -> float:
    """An upper bound on the chance that at least one of ``comparisons`` intervals, each at
    ``confidence`` on its own, misses its true value: ``min(1, comparisons (1 - confidence))``
    (Bonferroni; independent intervals would give ``1 - confidence ** comparisons``, a little
    less; intervals against one shared baseline are not independent, hence the bound).
    """
    _check("comparisons", comparisons, confidence)
    return min(1.0, comparisons * (1 - confidence))
