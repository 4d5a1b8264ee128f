"""Greedy (argmax) evaluation in jaxcart's JAX env, and the periodic evaluation that can run
inside the compiled training program (``PPOConfig.eval_every``), keeping each run's best
policy (``PPOConfig.keep_best``, as SB3's ``EvalCallback`` keeps ``best_model``).

Pure JAX, one run (no run axis); the engine vmaps it over runs.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxcart.core import cartpole, envs, networks, pytree
from jaxcart.core.config import PPOConfig
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.metrics import EVAL_METRICS
from jaxcart.core.networks import ActorCritic
from jaxcart.core.solved import NUM_EVAL_EPISODES

Array = jax.Array

EVAL_KEY_SEED = 2_000_000
"""The periodic evaluation's episodes start from resets drawn from ``PRNGKey(EVAL_KEY_SEED)``:
the same start states for every run and every evaluation, so they are compared on one test."""


@pytree.dataclass
class BestPolicy:
    """A run's best policy so far by the periodic evaluation's mean return (ties: the later)."""

    params: dict  # the network parameters of that iteration
    score: Array  # its eval/mean_return; -inf before the first evaluation
    iteration: Array  # int32, its 1-based iteration; 0 before the first evaluation


def greedy_returns(
    params: dict,
    key: Array,
    network: Any = None,
    num_episodes: int = NUM_EVAL_EPISODES,
    env_params: Any = None,
    env_id: str = DEFAULT_ENV,
) -> Array:
    """Greedy returns of ``num_episodes`` jaxcart episodes, ``[num_episodes]``; jit/vmap-able.

    Args:
        network: the flax actor-critic ``params`` belong to (default: the built-in MLP).
        key: draws the episodes' reset states.
        env_id: another env than CartPole-v1 plays on its :class:`~jaxcart.core.envs.Env`.
    """
    if env_id != DEFAULT_ENV:
        return _greedy_returns_env(params, key, network, num_episodes, env_params, env_id)
    env_params = env_params or cartpole.EnvParams()
    network = network if network is not None else ActorCritic()
    obs, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
        jax.random.split(key, num_episodes), env_params
    )

    def one_step(carry, _):
        obs, state, alive, total = carry
        action = jnp.argmax(networks.apply(network, params, obs)[0], axis=-1)
        obs, state, reward, terminated, truncated = jax.vmap(
            cartpole.step_env, in_axes=(0, 0, None)
        )(state, action, env_params)
        total = total + jnp.where(alive, reward, 0.0)
        alive = alive & ~(terminated | truncated)
        return (obs, state, alive, total), None

    init = (obs, state, jnp.ones((num_episodes,), bool), jnp.zeros((num_episodes,), obs.dtype))
    (_, _, _, total), _ = jax.lax.scan(one_step, init, None, length=env_params.max_episode_steps)
    return total


def _greedy_returns_env(
    params: dict, key: Array, network: Any, num_episodes: int, env_params: Any, env_id: str
) -> Array:
    """:func:`greedy_returns` on another env: its batched step until its time limit (the
    episodes that end earlier reset and stop counting)."""
    env = envs.make(env_id)
    env_params = env_params or env.default_params()
    network = network if network is not None else ActorCritic(num_actions=env.num_actions)
    reset_key, step_key = jax.random.split(key)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(
        jax.random.split(reset_key, num_episodes), env_params
    )

    def one_step(carry, key):
        obs, state, alive, total = carry
        action = jnp.argmax(networks.apply(network, params, obs)[0], axis=-1)
        obs, state, reward, terminated, truncated, _ = env.step_batch(
            key, state, action, env_params
        )
        total = total + jnp.where(alive, reward, 0.0)
        alive = alive & ~(terminated | truncated)
        return (obs, state, alive, total), None

    init = (obs, state, jnp.ones((num_episodes,), bool), jnp.zeros((num_episodes,), obs.dtype))
    keys = jax.random.split(step_key, env.max_episode_steps)
    (_, _, _, total), _ = jax.lax.scan(one_step, init, keys)
    return total


def periodic_evaluation(
    params: dict,
    best: BestPolicy | None,
    healthy: Array,
    config: PPOConfig,
    iteration: Array,
    network: Any,
    env_params: Any,
) -> tuple[BestPolicy | None, dict[str, Array]]:
    """Every ``config.eval_every`` iterations, ``config.periodic_eval_episodes`` greedy episodes
    of ``params`` from the fixed start states (:data:`EVAL_KEY_SEED`); between them nothing
    runs (a ``lax.cond`` on the iteration, which is the same for every run).

    Args:
        params: the run's parameters after this iteration's update.
        best: the run's best policy so far (``config.keep_best``), or None.
        healthy: bool scalar, the run has not diverged (a diverged run is not evaluated).
        iteration: int32 scalar, the 0-based index of this iteration.

    Returns:
        The best policy, updated when this evaluation scored at least its score, and the
        metrics :data:`EVAL_METRICS` (NaN when no evaluation ran).
    """
    due = (iteration + 1) % config.eval_every == 0
    dtype = jax.tree.leaves(params)[0].dtype

    def evaluate(params: dict) -> tuple[Array, Array]:
        key = jax.random.PRNGKey(EVAL_KEY_SEED)
        episodes = config.periodic_eval_episodes
        returns = greedy_returns(params, key, network, episodes, env_params, config.env)
        return returns.mean().astype(dtype), returns.min().astype(dtype)

    nan = jnp.full((), jnp.nan, dtype)
    mean, low = jax.lax.cond(due, evaluate, lambda _: (nan, nan), params)
    mean, low = jnp.where(healthy, mean, nan), jnp.where(healthy, low, nan)
    metrics = {"eval/mean_return": mean, "eval/min_return": low}
    if best is not None:
        better = due & healthy & (mean >= best.score)
        keep = lambda new, old: jnp.where(better, new, old)
        best = BestPolicy(
            params=jax.tree.map(keep, params, best.params),
            score=keep(mean.astype(jnp.float32), best.score),
            iteration=keep((iteration + 1).astype(jnp.int32), best.iteration),
        )
    return best, metrics


__all__ = [
    "EVAL_KEY_SEED",
    "EVAL_METRICS",
    "BestPolicy",
    "greedy_returns",
    "periodic_evaluation",
]
