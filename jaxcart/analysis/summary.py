"""The statistics of a comparison of runs, from their per-seed scores: what
``python -m jaxcart.compare`` and a sweep's ranking print.

- :class:`Score`: which number stands for a seed (``eval``: its mean greedy return; ``auc``:
  the mean of its learning curve, :func:`auc`; ``return-at:STEPS``: its training return at a
  budget, :func:`return_at`), the one definition that ``compare``, a sweep's ranking and
  ``tune`` (its pruner too) score by.
- :data:`DEFINITIONS`: what each printed statistic is
  (:func:`jaxcart.results.scores.build_comparison` computes them: per run, the estimates of
  :data:`jaxcart.analysis.stats.ESTIMATORS` with percentile bootstrap intervals, the solve
  rate with its Wilson interval, and against its baseline the IQM difference and
  ``P(X > Y)``; arms over several configurations with the stratified bootstrap).

**Curves.** Per-seed scores from learning curves, for the statistics of
:mod:`jaxcart.analysis.stats`.

A learning curve is ``rollout/ep_rew_mean`` as ``[iterations, num_seeds]`` (a run's
``metrics.csv`` column, one row per seed and iteration). It is NaN where a seed has no value:
before the seed's first episode ends (no return to average yet) and, after a seed diverges,
for every later iteration (the trainer stops updating it). Neither is a return the seed
earned, so the scores here **count a NaN iteration as the env's worst return**
(:func:`jaxcart.core.solved.return_bounds`: 0 on CartPole-v1, -500 on Acrobot-v1, -200 on
MountainCar-v0): a slow or broken seed is scored down, never dropped or scored up, whatever
the env's range of returns (0 is CartPole's worst return but Acrobot's best), and every score
is finite and ready for the bootstrap (which refuses NaN). Infinite values are refused.

- :func:`auc`: the area under each seed's learning curve, as its mean return over the run;
- :func:`return_at`: each seed's return at a given number of env steps.

Every interval comes from ``np.random.default_rng(seed)``: the same scores give the same
numbers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from jaxcart.analysis.stats import first_at_least
from jaxcart.core.config import ConfigError
from jaxcart.core.solved import DEFAULT_ENV, return_bounds, solved_return

RETURN_METRIC = "rollout/ep_rew_mean"
"""The learning curve the scores here read (a ``metrics.csv`` column)."""
REACHED_METRIC = "rollout/ep_rew_max"
"""What says a seed's training reached its env's solved return (:func:`first_reached`)."""
SCORES = {
    "eval": "each seed's mean greedy return in {where} (evaluation.json)",
    "auc": "each seed's mean of rollout/ep_rew_mean over all iterations (area under its "
    "learning curve / env steps; no value, before the first episode ends or after a "
    "divergence, counts as the env's worst return)",
    "return-at": "each seed's rollout/ep_rew_mean at the first iteration at or past {steps:,} "
    "env steps (no value counts as the env's worst return)",
}
"""Each score's one-line definition (formatted with ``return-at``'s steps and the env:
:meth:`Score.definition`)."""
ADJUSTMENTS = ("none", "bonferroni")
DEFINITIONS = {
    "score": "one number per seed, chosen by --score: eval, auc or return-at:STEPS",
    "iqm": "interquartile mean over seeds: the mean of the middle 50% of the seeds' scores",
    "mean": "mean over seeds",
    "median": "median over seeds (rliable's aggregate_median is the median over tasks of "
    "each task's mean: a different statistic)",
    "optimality_gap": "mean over seeds of max(T - score, 0), T the env's solved return "
    "(CartPole-v1: 500, Acrobot-v1: -100)",
    "solved": "fraction of seeds solved by their env's rule (CartPole-v1: every greedy "
    "evaluation episode scored 500; the others: the mean reached the env's reward_threshold), "
    "with its 95% Wilson interval",
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


def _curves(curves: np.ndarray, env_id: str) -> np.ndarray:
    """``[iterations, num_seeds]`` with NaN as the env's worst return; refused if empty, not
    2-D or infinite."""
    curves = np.asarray(curves, float)
    if curves.ndim != 2 or curves.size == 0:
        raise ValueError(
            f"curves must be a non-empty [iterations, num_seeds] array, got shape {curves.shape}"
        )
    infinite = int(np.isinf(curves).sum())
    if infinite:
        raise ValueError(f"curves holds {infinite} infinite values: returns are finite or NaN")
    return np.nan_to_num(curves, nan=return_bounds(env_id)[0])


def auc(curves: np.ndarray, env_id: str = DEFAULT_ENV) -> np.ndarray:
    """Each seed's normalised area under its learning curve: the mean of ``ep_rew_mean`` over
    all of the run's iterations, NaN counting as the env's worst return (see the module
    docstring). The one definition that ``compare``, ``tune`` and its pruner use.

    Every iteration collects the same number of env steps, so this is the area under the
    return-against-env-steps curve divided by the run's env steps, in units of return (0 to
    500 on CartPole-v1; subtract the worst return and divide by the range for the fraction of
    the largest possible area). It rewards learning early and staying there, where the final
    return cannot tell a fast seed from a slow one. From ``metrics.csv``: for each
    ``seed_index``, the mean of the ``rollout/ep_rew_mean`` column over its rows, with
    ``nan`` read as the worst return.

    Args:
        curves: ``[iterations, num_seeds]``.
        env_id: the env the curves come from (its worst return fills the NaN iterations).

    Returns:
        ``[num_seeds]``.
    """
    return _curves(curves, env_id).mean(axis=0)


def return_at(
    curves: np.ndarray, env_steps: np.ndarray, steps: float, env_id: str = DEFAULT_ENV
) -> np.ndarray:
    """Each seed's ``ep_rew_mean`` at the first iteration that has collected at least ``steps``
    env steps (per seed), NaN counting as the env's worst return (see the module docstring).

    Args:
        curves: ``[iterations, num_seeds]``.
        env_steps: ``[iterations]``, increasing: env steps per seed at the end of each
            iteration (``metrics.csv``'s ``env_steps``).
        steps: the budget to read the return at.
        env_id: the env the curves come from.

    Returns:
        ``[num_seeds]``.

    Raises:
        ValueError: if the run ends before ``steps`` env steps.
    """
    values = _curves(curves, env_id)
    env_steps = np.asarray(env_steps, float)
    if env_steps.shape != values.shape[:1]:
        raise ValueError(
            f"env_steps has shape {env_steps.shape}, curves has {values.shape[0]} iterations"
        )
    if not steps <= env_steps[-1]:
        raise ValueError(
            f"the run never reaches {steps:g} env steps: it ends at {env_steps[-1]:g} per seed"
        )
    return values[int(np.searchsorted(env_steps, steps, side="left"))]


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
            raise ValueError(
                "return-at needs its env steps, e.g. return-at:100000 (and only it takes them)"
            )

    @classmethod
    def parse(cls, text: str, parse_steps: Callable[[str], int] = int) -> Score:
        """``"eval"``, ``"auc"`` or ``"return-at:STEPS"`` (``parse_steps`` reads STEPS).

        Raises:
            ValueError: an unknown name, or return-at without its steps.
        """
        name, sep, steps = text.strip().partition(":")
        if sep and name != "return-at":
            raise ValueError(f"score {name!r} takes no ':{steps}'")
        return cls(name, parse_steps(steps) if steps else None)

    @property
    def label(self) -> str:
        """``eval``, ``auc`` or ``return-at:100000`` (as given to ``--score``)."""
        return self.name if self.steps is None else f"{self.name}:{self.steps}"

    def definition(self, env_ids: Sequence[str] = (DEFAULT_ENV,)) -> str:
        """The score's one-line definition for runs of ``env_ids``: ``eval`` names the env
        (``gymnasium.make('Acrobot-v1')``, or "each run's env" when they differ)."""
        envs = sorted(set(env_ids))
        where = f"gymnasium.make('{envs[0]}')" if len(envs) == 1 else "each run's env"
        return SCORES[self.name].format(steps=self.steps, where=where)

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
            return auc(returns, env_id)
        return return_at(returns, env_steps, self.steps, env_id)

    def of_run(self, run: Any, means: np.ndarray | None = None) -> np.ndarray:
        """Each seed's score of a run read back (a :class:`~jaxcart.rundir.reader.RunCurves`:
        its curve, env steps and env), as ``compare``, a sweep's ranking and ``tune`` score
        it; ``means``: its seeds' mean greedy returns (default: its final policies', from its
        ``evaluation.json`` when it has one).

        Raises:
            ConfigError: ``PATH: cannot score by --score LABEL: why`` (a score the run cannot
                give: no evaluation, no curve, ``return-at`` past its end).
        """
        if means is None and run.evaluation is not None:
            means = np.array([float(s["gymnasium_mean"]) for s in run.evaluation["seeds"]])
        try:
            return self.compute(means, run.metrics.get(RETURN_METRIC), run.env_steps, run.env)
        except ValueError as exc:
            raise ConfigError(f"{run.path}: cannot score by --score {self.label}: {exc}") from None


def first_reached(run: Any, x: np.ndarray | None) -> np.ndarray | None:
    """``x`` (env steps or seconds, ``[iterations]``) where a training episode of each seed
    of ``run`` (a :class:`~jaxcart.rundir.reader.RunCurves`) first scored its env's solved
    return (:func:`~jaxcart.core.solved.solved_return`: 500 on CartPole-v1), ``[num_seeds]``
    (``inf``: never); None without the data (Stable-Baselines3 logs no episode maximum)."""
    best = run.metrics.get(REACHED_METRIC)
    if x is None or best is None or not np.isfinite(best).any():
        return None
    return first_at_least(best, x, solved_return(run.env))


EVAL = Score()
"""The default score: each seed's mean greedy return."""
