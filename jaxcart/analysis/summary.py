"""The statistics of a comparison of runs, from their per-seed scores: what
``python -m jaxcart.compare`` and a sweep's ranking print.

- :class:`Score`: which number stands for a seed (``eval``: its mean greedy return; ``auc``:
  the mean of its learning curve, :func:`jaxcart.analysis.curves.auc`; ``return-at:STEPS``:
  its training return at a budget, :func:`jaxcart.analysis.curves.return_at`).
- :func:`summarise`: per run, the estimates of :data:`jaxcart.analysis.stats.ESTIMATORS`
  with percentile bootstrap intervals, the solve rate with its Wilson interval, and against
  its reference run (the baseline) the IQM difference and ``P(X > Y)``, both with intervals;
  the all-pairs matrix of ``P(X > Y)``; whether the scores are saturated; how many
  comparisons were read at once.
- :func:`summarise_arms`: the same two arms (or more) measured on several configurations,
  aggregated with the stratified bootstrap of :mod:`jaxcart.analysis.tasks`.

Every interval comes from ``np.random.default_rng(seed)``: the same scores give the same
numbers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from jaxcart.analysis import curves, stats, tasks
from jaxcart.analysis import multiplicity as comparisons
from jaxcart.core.envs import DEFAULT_ENV

SCORES = {
    "eval": "each seed's mean greedy return in gymnasium.make('CartPole-v1') (evaluation.json)",
    "auc": "each seed's mean of rollout/ep_rew_mean over all iterations (area under its "
    "learning curve / env steps; no value, before the first episode ends or after a "
    "divergence, counts as the env's worst return)",
    "return-at": "each seed's rollout/ep_rew_mean at the first iteration at or past {steps:,} "
    "env steps (no value counts as the env's worst return)",
}
"""Each score's one-line definition (``return-at``'s is formatted with its steps)."""
ADJUSTMENTS = ("none", "bonferroni")
DEFINITIONS = {
    "score": "one number per seed, chosen by --score: eval, auc or return-at:STEPS",
    "iqm": "interquartile mean over seeds: the mean of the middle 50% of the seeds' scores",
    "mean": "mean over seeds",
    "median": "median over seeds (rliable's aggregate_median is the median over tasks of "
    "each task's mean: a different statistic)",
    "optimality_gap": "mean over seeds of max(500 - score, 0)",
    "solved": "fraction of seeds whose every greedy evaluation episode scored 500, with its "
    "95% Wilson interval",
    "difference_iqm": "IQM of the run minus IQM of its baseline; bootstrap interval with the "
    "seeds of each run resampled independently",
    "probability_of_improvement": "P(X > Y) + 0.5 P(X = Y) over all pairs of a seed of run X "
    "and a seed of the baseline Y (0.5: no difference)",
    "interval": "95% percentile bootstrap: 2.5th and 97.5th percentiles of the statistic over "
    "resampled seeds (fixed --seed: the same runs give the same numbers)",
    "saturated": "every seed of every run has the same score: no statistic of it can tell "
    "the runs apart",
    "arms": "one arm's runs on several configurations: IQM of all its scores pooled, seeds "
    "resampled within each configuration (rliable's stratified bootstrap); P(X > Y) is the "
    "mean over configurations",
}
"""One line per statistic: ``compare.json``'s ``definitions`` and ``compare --help``."""


@dataclass(frozen=True)
class Score:
    """Which number stands for one seed of a run.

    Attributes:
        name: ``"eval"``, ``"auc"`` or ``"return-at"``.
        steps: env steps per seed for ``"return-at"`` (None otherwise).
    """

    name: str = "eval"
    steps: int | None = None

    def __post_init__(self) -> None:
        if self.name not in SCORES:
            raise ValueError(f"unknown score {self.name!r}; choose eval, auc or return-at:STEPS")
        if (self.name == "return-at") != (self.steps is not None):
            raise ValueError("return-at needs its env steps (return-at:STEPS), and only it")

    @classmethod
    def parse(cls, text: str, parse_steps: Callable[[str], int] = int) -> Score:
        """``"eval"``, ``"auc"`` or ``"return-at:STEPS"`` (``parse_steps`` reads STEPS).

        Raises:
            ValueError: an unknown name, or return-at without its steps.
        """
        name, sep, steps = text.strip().partition(":")
        if name == "return-at":
            if not sep or not steps:
                raise ValueError("return-at needs its env steps, e.g. return-at:100000")
            return cls(name, parse_steps(steps))
        if sep:
            raise ValueError(f"score {name!r} takes no ':{steps}'")
        return cls(name)

    @property
    def label(self) -> str:
        """``eval``, ``auc`` or ``return-at:100000`` (as given to ``--score``)."""
        return self.name if self.steps is None else f"{self.name}:{self.steps}"

    @property
    def definition(self) -> str:
        return SCORES[self.name].format(steps=self.steps)

    def compute(
        self,
        evaluation: np.ndarray | None,
        returns: np.ndarray | None,
        env_steps: np.ndarray | None,
        env_id: str = DEFAULT_ENV,
    ) -> np.ndarray:
        """Each seed's score, ``[num_seeds]``.

        Args:
            evaluation: ``[num_seeds]`` mean greedy returns (needed by ``eval``).
            returns: ``[iterations, num_seeds]`` ``rollout/ep_rew_mean`` (``auc``, ``return-at``).
            env_steps: ``[iterations]`` env steps per seed (``return-at``).
            env_id: the env the run trained on (its worst return stands for no value).

        Raises:
            ValueError: the data this score needs is missing, or the run ends before STEPS.
        """
        if self.name == "eval":
            if evaluation is None:
                raise ValueError("no greedy evaluation (evaluation.json)")
            return np.asarray(evaluation, float)
        if returns is None or not np.isfinite(returns).any():
            raise ValueError("no rollout/ep_rew_mean recorded")
        if self.name == "auc":
            return curves.auc(returns, env_id)
        return curves.return_at(returns, env_steps, self.steps, env_id)


EVAL = Score()
"""The default score: each seed's mean greedy return."""


@dataclass(frozen=True)
class RunStats:
    """One run's statistics.

    Attributes:
        estimates: :data:`stats.ESTIMATORS` name -> estimate with its bootstrap interval.
        solved: fraction of seeds solved with its Wilson interval (None: not known).
        difference: IQM of this run minus its reference's (None for a reference itself).
        improvement: ``P(this run > reference)`` (None for a reference itself).
    """

    estimates: dict[str, stats.Estimate]
    solved: stats.Estimate | None
    difference: stats.Estimate | None
    improvement: stats.Estimate | None


@dataclass(frozen=True)
class Summary:
    """Every run's statistics and what holds for all of them.

    Attributes:
        runs: one per run, in order.
        references: per run, the index of the run it is compared with (itself: a baseline).
        matrix: ``[R, R]`` ``P(row > column)`` point values, None with two runs or fewer.
        saturated: every seed of every run has the same score.
        comparisons: differences read against a reference (each with a ``P(X > Y)``).
        confidence: of each difference and ``P(X > Y)`` interval (Bonferroni-widened with
            ``adjust="bonferroni"``).
        adjust: ``"none"`` or ``"bonferroni"``.
    """

    runs: list[RunStats]
    references: list[int]
    matrix: np.ndarray | None
    saturated: bool
    comparisons: int
    confidence: float
    adjust: str

    def reading_note(self) -> str:
        """One line: how many comparisons, and what that means for reading the intervals."""
        n = self.comparisons
        if n == 0:
            return "no comparison made (one run, or only baselines)"
        if self.adjust == "bonferroni":
            return (
                f"{n} comparison(s) against a baseline; each difference and P(X > Y) "
                f"interval is widened to {self.confidence:.2%} (Bonferroni) so that all {n} "
                f"hold together with probability at least {stats.CONFIDENCE:.0%}"
            )
        miss = comparisons.familywise_miss_bound(n)
        return (
            f"{n} comparison(s) against a baseline; each interval is "
            f"{stats.CONFIDENCE:.0%} on its own, so up to {miss:.0%} chance that at least one "
            "misses its true value (--adjust bonferroni widens them to hold together)"
        )


def _check_adjust(adjust: str) -> None:
    if adjust not in ADJUSTMENTS:
        raise ValueError(f"adjust must be one of {ADJUSTMENTS}, got {adjust!r}")


def summarise(
    scores: Sequence[np.ndarray],
    solved: Sequence[int | None],
    references: Sequence[int],
    reps: int = stats.DEFAULT_REPS,
    seed: int = stats.DEFAULT_SEED,
    adjust: str = "none",
    extra_comparisons: int = 0,
    matrix: bool = True,
) -> Summary:
    """Statistics of runs from their per-seed scores.

    Args:
        scores: per run, ``[n_r]`` finite scores.
        solved: per run, how many of its seeds are solved (None: unknown).
        references: per run, the index of the run it is compared with (its own index for a
            baseline).
        reps, seed: bootstrap resamples and their random seed.
        adjust: ``"bonferroni"`` widens every difference and ``P(X > Y)`` interval to
            :func:`comparisons.bonferroni_confidence` of the number of comparisons.
        extra_comparisons: comparisons made beside these runs' (e.g. of arms), counted in.
        matrix: the all-pairs matrix (with more than two runs).
    """
    _check_adjust(adjust)
    scores = [stats.check_seeds(s, f"scores[{i}]") for i, s in enumerate(scores)]
    count = sum(r != i for i, r in enumerate(references)) + extra_comparisons
    confidence = stats.CONFIDENCE
    if adjust == "bonferroni" and count:
        confidence = comparisons.bonferroni_confidence(count)
    runs = []
    for i, (x, k, ref) in enumerate(zip(scores, solved, references)):
        difference = improvement = None
        if ref != i:
            y = scores[ref]
            difference = stats.difference_ci(x, y, stats.iqm, reps, confidence, seed)
            improvement = stats.probability_of_improvement_ci(x, y, reps, confidence, seed)
        runs.append(
            RunStats(
                stats.bootstrap_cis(x, stats.ESTIMATORS, reps, seed=seed),
                None if k is None else stats.wilson_interval(int(k), x.size),
                difference,
                improvement,
            )
        )
    pairs = None
    if matrix and len(scores) > 2:
        pairs = np.array([[stats.probability_of_improvement(x, y) for y in scores] for x in scores])
    return Summary(
        runs,
        list(references),
        pairs,
        comparisons.saturated(scores),
        count,
        confidence,
        adjust,
    )


@dataclass(frozen=True)
class ArmStats:
    """One arm over every configuration (task): stratified estimates.

    Attributes:
        iqm: IQM of all its tasks' scores pooled, stratified bootstrap interval.
        difference: its pooled IQM minus the baseline arm's (None for the baseline).
        improvement: mean over tasks of ``P(X_m > Y_m)`` against the baseline arm (None for
            the baseline).
    """

    iqm: stats.Estimate
    difference: stats.Estimate | None
    improvement: stats.Estimate | None

    def to_dict(self) -> dict:
        return {
            "iqm": self.iqm.to_dict(),
            "difference_iqm": self.difference and self.difference.to_dict(),
            "probability_of_improvement": self.improvement and self.improvement.to_dict(),
        }


def summarise_arms(
    arms: Sequence[Sequence[np.ndarray]],
    baseline: int = 0,
    reps: int = stats.DEFAULT_REPS,
    seed: int = stats.DEFAULT_SEED,
    confidence: float = stats.CONFIDENCE,
) -> list[ArmStats]:
    """Arms measured on the same configurations, rliable-style (seeds resampled within each
    configuration, configurations never resampled: :mod:`jaxcart.analysis.tasks`).

    Args:
        arms: per arm, per task (the same tasks in the same order), ``[n]`` scores.
        baseline: the arm the others are compared with.
        confidence: of the difference and ``P(X > Y)`` intervals.
    """
    base = arms[baseline]
    out = []
    for a, arm in enumerate(arms):
        difference = improvement = None
        if a != baseline:
            difference = tasks.stratified_difference_ci(
                arm, base, stats.iqm, reps, confidence, seed
            )
            improvement = tasks.stratified_probability_of_improvement_ci(
                arm, base, reps, confidence, seed
            )
        iqm = tasks.stratified_bootstrap_ci(arm, stats.iqm, reps, seed=seed)
        out.append(ArmStats(iqm, difference, improvement))
    return out
