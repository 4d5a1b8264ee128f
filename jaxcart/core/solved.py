"""What "solved" means for CartPole-v1, in one place: every greedy evaluation episode in
Gymnasium's own ``CartPole-v1`` scores 500, over :data:`NUM_EVAL_EPISODES` episodes whose
resets are seeded from :data:`EVAL_SEED`."""

from __future__ import annotations

import numpy as np

NUM_EVAL_EPISODES = 20


EVAL_SEED = 1_000_000
"""Episode i of a Gymnasium evaluation is reset with seed ``EVAL_SEED + i`` (all runs alike)."""


SOLVED_RETURN = 500.0
"""CartPole-v1's maximum return: an episode that lasts until the 500-step time limit."""


SOLVED_DEFINITION = "all {episodes} greedy episodes score 500 in gymnasium.make('CartPole-v1')"


def is_solved(returns: np.ndarray) -> np.ndarray:
    """The one definition of solved: every evaluation episode scored 500.

    Args:
        returns: ``[..., episodes]``.

    Returns:
        ``[...]`` bool.
    """
    return (np.asarray(returns) >= SOLVED_RETURN).all(axis=-1)
