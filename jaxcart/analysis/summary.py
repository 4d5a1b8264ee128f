"""The statistics of a comparison of runs, from their per-seed scores: what
``python -m jaxcart.compare`` and a sweep's ranking print.

- :class:`Score`: which number stands for a seed (``eval``: its mean greedy return; ``auc``:
  the mean of its learning curve, :func:`jaxcart.analysis.curves.auc`; ``return-at:STEPS``:
  its training return at a budget, :func:`jaxcart.analysis.curves.return_at`).
- :data:`DEFINITIONS`: what each printed statistic is (:func:`jaxcart.results.scores.build_comparison`
  computes them: per run, the estimates of :data:`jaxcart.analysis.stats.ESTIMATORS` with
  percentile bootstrap intervals, the solve rate with its Wilson interval, and against its
  baseline the IQM difference and ``P(X > Y)``; arms over several configurations with the
  stratified bootstrap).

Every interval comes from ``np.random.default_rng(seed)``: the same scores give the same
numbers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from jaxcart.analysis import curves
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
