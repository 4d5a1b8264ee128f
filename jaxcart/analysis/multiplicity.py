"""What a set of comparisons can still say: saturation, and many intervals read at once.

- :func:`saturated`: every score of every run is the same (e.g. every seed at 500). Then every
  bootstrap interval is a point, every difference 0 and every probability of improvement 0.5:
  the runs cannot be told apart by these scores, and the comparison should say so instead of
  printing a table of identical intervals (compare a harder score, e.g. the area under the
  learning curve, :func:`jaxcart.analysis.curves.auc`).
- :func:`num_comparisons`, :func:`bonferroni_confidence`, :func:`familywise_miss_bound`: each
  95% interval covers its true value 95% of the time *on its own*; reading N of them at once,
  the chance that at least one misses is up to N x 5% (Bonferroni's bound, from
  ``P(A or B) <= P(A) + P(B)``). Either say so, or widen each interval to confidence
  ``1 - 5%/N`` so that all N hold together with probability at least 95%.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jaxcart.analysis import stats


def saturated(runs: Sequence[np.ndarray]) -> bool:
    """Whether all scores of all runs are equal (nothing left to discriminate).

    Args:
        runs: per run, ``[n_r]`` scores (finite, non-empty), e.g. each seed's mean return.
    """
    if len(runs) == 0:
        raise ValueError("runs holds no run")
    pooled = np.concatenate([stats.check_seeds(r, f"runs[{i}]") for i, r in enumerate(runs)])
    return bool((pooled == pooled[0]).all())


def num_comparisons(num_runs: int, all_pairs: bool = False) -> int:
    """How many comparisons a table of ``num_runs`` runs makes.

    Args:
        num_runs: runs compared, the baseline included.
        all_pairs: every pair of runs, ``num_runs (num_runs - 1) / 2``; otherwise each run
            against the baseline, ``num_runs - 1``.
    """
    if int(num_runs) != num_runs or num_runs < 1:
        raise ValueError(f"num_runs must be a positive whole number, got {num_runs}")
    return num_runs * (num_runs - 1) // 2 if all_pairs else num_runs - 1


def _check(comparisons: int, confidence: float) -> None:
    if int(comparisons) != comparisons or comparisons < 1:
        raise ValueError(f"comparisons must be a positive whole number, got {comparisons}")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")


def bonferroni_confidence(comparisons: int, confidence: float = stats.CONFIDENCE) -> float:
    """The confidence each of ``comparisons`` intervals needs for all of them to hold together
    with probability at least ``confidence``: ``1 - (1 - confidence) / comparisons``
    (0.9875 for 4 comparisons at 95%). Pass it as ``confidence=`` to the interval functions.
    """
    _check(comparisons, confidence)
    return 1 - (1 - confidence) / comparisons


def familywise_miss_bound(comparisons: int, confidence: float = stats.CONFIDENCE) -> float:
    """An upper bound on the chance that at least one of ``comparisons`` intervals, each at
    ``confidence`` on its own, misses its true value: ``min(1, comparisons (1 - confidence))``
    (Bonferroni; independent intervals would give ``1 - confidence ** comparisons``, a little
    less; intervals against one shared baseline are not independent, hence the bound).
    """
    _check(comparisons, confidence)
    return min(1.0, comparisons * (1 - confidence))
