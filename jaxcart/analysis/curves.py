"""Per-seed scores from learning curves, for the statistics of :mod:`jaxcart.analysis.stats`.

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
"""

from __future__ import annotations

import numpy as np

from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.solved import return_bounds


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
