"""What "solved" means, in one place: for CartPole-v1, every greedy evaluation episode in
Gymnasium's own ``CartPole-v1`` scores 500; for the other envs, the mean greedy return in
Gymnasium's env of the same id reaches that env's ``reward_threshold`` (Acrobot-v1: -100,
MountainCar-v0: -110). Over :data:`NUM_EVAL_EPISODES` episodes whose resets are seeded from
:data:`EVAL_SEED`."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

DEFAULT_ENV = "CartPole-v1"

GYMNAX_ENVS: dict[str, float] = {
    "Acrobot-v1": -100.0,
    "MountainCar-v0": -110.0,
}
"""gymnax envs the trainer takes, each with Gymnasium's ``reward_threshold`` for its id (the
mean greedy return that counts as solved): the discrete-action, flat-observation envs of
gymnax that Gymnasium also registers, so that a policy is judged in Gymnasium's own env.
(Here, not in :mod:`jaxcart.core.envs`, so that reading them imports no JAX.)"""

NUM_EVAL_EPISODES = 20


EVAL_SEED = 1_000_000
"""Episode i of a Gymnasium evaluation is reset with seed ``EVAL_SEED + i`` (all runs alike)."""


SOLVED_RETURN = 500.0
"""CartPole-v1's maximum return: an episode that lasts until the 500-step time limit."""


EPISODE_LIMITS = {DEFAULT_ENV: 500, "Acrobot-v1": 500, "MountainCar-v0": 200}
"""Gymnasium's ``max_episode_steps`` of each env (gymnax's ``max_steps_in_episode`` agrees)."""


SOLVED_BY = {DEFAULT_ENV: ("every", SOLVED_RETURN)} | {
    k: ("mean", v) for k, v in GYMNAX_ENVS.items()
}
"""Each env's rule: every episode's return (CartPole-v1: 500) or the mean return (the others:
Gymnasium's ``reward_threshold``) reaches the threshold."""


REWARD_SIGN = {DEFAULT_ENV: 1.0, "Acrobot-v1": -1.0, "MountainCar-v0": -1.0}
"""CartPole pays +1 a step; Acrobot and MountainCar -1 a step until the goal (Acrobot 0 on the
step that reaches it)."""


def is_solved(returns: np.ndarray, env_id: str = DEFAULT_ENV) -> np.ndarray:
    """The one definition of solved (:data:`SOLVED_BY`): every evaluation episode scored 500
    (CartPole-v1), or the mean return reached the env's ``reward_threshold`` (the others).

    Args:
        returns: ``[..., episodes]``.

    Returns:
        ``[...]`` bool.
    """
    rule, threshold = SOLVED_BY[env_id]
    returns = np.asarray(returns)
    if rule == "every":
        return (returns >= threshold).all(axis=-1)
    return returns.mean(axis=-1) >= threshold


def solved_return(env_id: str = DEFAULT_ENV) -> float:
    """The return that solves ``env_id`` (:data:`SOLVED_BY`'s threshold: 500 on CartPole-v1,
    the ``reward_threshold`` on the others): what ``compare``'s optimality gap and its
    "reached" (a training episode that scored it) measure against."""
    return SOLVED_BY[env_id][1]


def reached_label(env_ids: Iterable[str]) -> str:
    """The solved return of ``env_ids`` as a column label: ``500``, ``-100``, or
    ``threshold`` for envs whose thresholds differ."""
    targets = {solved_return(env_id) for env_id in env_ids}
    return f"{targets.pop():g}" if len(targets) == 1 else "threshold"


def solved_definition(env_id: str = DEFAULT_ENV) -> str:
    """The sentence ``evaluation.json`` records, with ``{episodes}`` left to fill in."""
    rule, threshold = SOLVED_BY[env_id]
    if rule == "every":
        return f"all {{episodes}} greedy episodes score {threshold:g} in gymnasium.make('{env_id}')"
    return (
        f"the mean of {{episodes}} greedy episodes in gymnasium.make('{env_id}') is at least "
        f"its reward_threshold, {threshold:g}"
    )


def return_bounds(env_id: str = DEFAULT_ENV) -> tuple[float, float]:
    """The least and greatest episode return of the env (:data:`REWARD_SIGN` times the
    episode limit, and 0)."""
    return tuple(sorted((0.0, REWARD_SIGN[env_id] * EPISODE_LIMITS[env_id])))
