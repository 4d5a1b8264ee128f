"""Greedy (argmax) evaluation of trained runs, in Gymnasium's own CartPole-v1 (the verdict,
:mod:`jaxcart.core.solved`) and in jaxcart's JAX env (a cross-check)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import env as cartpole
from jaxcart.core.config import PPOConfig
from jaxcart.core.networks import ActorCritic
from jaxcart.core.solved import EVAL_SEED, NUM_EVAL_EPISODES, is_solved
from jaxcart.engine.signals import Stopped
from jaxcart.engine.trainer import seed_keys
from jaxcart.rundir import reader
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.policy import RunParams, numpy_policy, run_params


def evaluate_gymnasium(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    seed: int = EVAL_SEED,
    env_id: str = "CartPole-v1",
    should_stop: Callable[[], bool] | None = None,
) -> np.ndarray:
    """Runs ``num_episodes`` greedy episodes per policy in ``gymnasium.make(env_id)``.

    Args:
        policy: maps observations ``[num_policies, num_episodes, 4]`` to actions of shape
            ``[num_policies, num_episodes]`` (a stacked :class:`NumpyPolicy`), so all policies
            and episodes advance in lockstep with one batched forward pass per step.

    Returns:
        Episode returns, ``[num_policies, num_episodes]`` float64.
    """
    import gymnasium as gym

    envs = [[gym.make(env_id) for _ in range(num_episodes)] for _ in range(num_policies)]
    obs = np.zeros((num_policies, num_episodes, 4), np.float32)
    for p, row in enumerate(envs):
        for e, env_ in enumerate(row):
            obs[p, e], _ = env_.reset(seed=seed + e)
    returns = np.zeros((num_policies, num_episodes))
    alive = np.ones((num_policies, num_episodes), bool)
    while alive.any():
        if should_stop is not None and should_stop():
            raise Stopped("evaluation interrupted")
        actions = np.asarray(policy(obs))
        for p, e in zip(*np.nonzero(alive)):
            o, r, terminated, truncated, _ = envs[p][e].step(int(actions[p, e]))
            obs[p, e] = o
            returns[p, e] += r
            if terminated or truncated:
                alive[p, e] = False
    for row in envs:
        for env_ in row:
            env_.close()
    return returns


def greedy_returns(
    params: dict,
    key: jax.Array,
    activation: str = "tanh",
    hidden_sizes: tuple[int, ...] = (64, 64),
    num_episodes: int = NUM_EVAL_EPISODES,
    env_params: cartpole.EnvParams | None = None,
) -> jax.Array:
    """Greedy returns of ``num_episodes`` jaxcart episodes, ``[num_episodes]``; jit/vmap-able."""
    env_params = env_params or cartpole.EnvParams()
    network = ActorCritic(hidden_sizes=tuple(hidden_sizes), activation=activation)
    obs, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
        jax.random.split(key, num_episodes), env_params
    )

    def one_step(carry, _):
        obs, state, alive, total = carry
        action = jnp.argmax(network.logits(params, obs), axis=-1)
        obs, state, reward, terminated, truncated = jax.vmap(
            cartpole.step_env, in_axes=(0, 0, None)
        )(state, action, env_params)
        total = total + jnp.where(alive, reward, 0.0)
        alive = alive & ~(terminated | truncated)
        return (obs, state, alive, total), None

    init = (obs, state, jnp.ones((num_episodes,), bool), jnp.zeros((num_episodes,), obs.dtype))
    (_, _, _, total), _ = jax.lax.scan(one_step, init, None, length=env_params.max_episode_steps)
    return total


def summarize(returns: np.ndarray) -> dict[str, np.ndarray]:
    """Per-policy mean, min and solved flag from returns ``[P, episodes]``."""
    returns = np.asarray(returns)
    return {
        "mean": returns.mean(axis=-1),
        "min": returns.min(axis=-1),
        "solved": is_solved(returns),
    }


def evaluate_runs(
    params: dict,
    config: PPOConfig,
    seed: int,
    seed_indices: np.ndarray,
    episodes: int,
    should_stop: Callable[[], bool] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy returns of every run of a training, ``([R, episodes], [R, episodes])``: in
    Gymnasium's CartPole-v1 (the same reset seeds for all) and in jaxcart's env (run r's
    episodes from ``fold_in(seed key of seed_indices[r], 1)``).

    Args:
        params: network parameters, leaves ``[R, ...]`` (NumPy).
    """
    num_runs = len(seed_indices)
    policy = numpy_policy(params, config.activation, stacked=True)
    gym_returns = evaluate_gymnasium(policy, num_runs, episodes, should_stop=should_stop)
    indices = np.asarray(seed_indices)
    keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(
        seed_keys(seed, int(indices.max()) + 1)[indices]
    )
    evaluate = jax.jit(
        jax.vmap(
            lambda p, k: greedy_returns(p, k, config.activation, config.hidden_sizes, episodes)
        )
    )
    return gym_returns, np.asarray(evaluate(params, keys))


def evaluate_run_dir(
    run_dir: str | Path, episodes: int = NUM_EVAL_EPISODES, combination: int | None = None
) -> tuple[np.ndarray, dict]:
    """Evaluates every seed of a run directory in Gymnasium's CartPole-v1: a finished run's
    ``params.npz``, or the last checkpoint of one that did not finish.

    Args:
        combination: for a sweep directory, which combination.

    Returns:
        ``(returns [num_seeds, episodes], info)`` with ``info`` the run's ``config.json``
        and ``info["note"]``: None, or where the parameters came from when the run did not
        finish (``from the checkpoint at iteration 12/40: the run did not finish``).

    Raises:
        RunDirError: not a usable run (or a sweep without ``combination``).
    """
    info = reader.read_run_config(run_dir)
    trained = run_params(run_dir, combination)
    return evaluate_params(run_dir, trained, episodes), {**info, "note": trained.note}


def evaluate_params(run_dir: str | Path, trained: RunParams, episodes: int) -> np.ndarray:
    try:
        policy = numpy_policy(trained.params, trained.config.activation, stacked=True)
    except (KeyError, TypeError, ValueError) as exc:
        raise RunDirError(f"{run_dir} does not hold an actor: {exc}") from None
    return evaluate_gymnasium(policy, trained.num_seeds, episodes)
