"""Greedy (argmax) evaluation in jaxcart's JAX env, and the periodic evaluation that can run
inside the compiled training program (``PPOConfig.eval_every``), keeping each run's best
policy (``PPOConfig.keep_best``, as SB3's ``EvalCallback`` keeps ``best_model``).

Pure JAX, one run (no run axis); the engine vmaps it over runs.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxcart.core import envs, networks, pytree
from jaxcart.core.config import PPOConfig
from jaxcart.core.envs import DEFAULT_ENV
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
    network: Any,
    num_episodes: int = NUM_EVAL_EPISODES,
    env_params: Any = None,
    env_id: str = DEFAULT_ENV,
) -> Array:
    """Greedy (argmax) returns of ``num_episodes`` episodes of ``env_id``'s
    :class:`~jaxcart.core.envs.Env`, ``[num_episodes]``; jit/vmap-able. The one JAX greedy
    evaluation: the final cross-check, the periodic evaluation and the benchmarks call it.

    Every episode steps in lockstep (the env's batched step) until all have terminated or
    reached the env's time limit; an episode that ends stops counting (the env resets it).

    Args:
        params: the network parameters (no run axis).
        key: episode ``e`` starts from ``env.reset(split(key, num_episodes)[e])``.
        network: the flax actor-critic ``params`` belong to (:func:`jaxcart.core.ppo.make_network`).
        env_params: the env's params (default: its own).
    """
    env = envs.make(env_id)
    env_params = env.default_params() if env_params is None else env_params
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(
        jax.random.split(key, num_episodes), env_params
    )
    step_key = jax.random.fold_in(key, 1)  # the batched step's resets, which do not count

    def one_step(carry: tuple) -> tuple:
        obs, state, alive, total, t = carry
        action = jnp.argmax(networks.apply(network, params, obs)[0], axis=-1)
        obs, state, reward, terminated, truncated, _ = env.step_batch(
            jax.random.fold_in(step_key, t), state, action, env_params
        )
        total = total + jnp.where(alive, reward, 0.0)
        return obs, state, alive & ~(terminated | truncated), total, t + 1

    alive = jnp.ones((num_episodes,), bool)
    init = (obs, state, alive, jnp.zeros((num_episodes,), obs.dtype), jnp.zeros((), jnp.int32))
    return jax.lax.while_loop(lambda carry: carry[2].any(), one_step, init)[3]


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
        metrics :data:`~jaxcart.core.metrics.EVAL_METRICS` (NaN when no evaluation ran).
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
