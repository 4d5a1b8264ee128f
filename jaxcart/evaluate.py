"""Greedy (argmax) evaluation, in jaxcart's JAX env and in Gymnasium's own CartPole-v1.

"Solved" means every one of the evaluation episodes (20 by default) scores 500.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart import env as cartpole

NUM_EVAL_EPISODES = 20
EVAL_SEED = 1_000_000
"""Episode i of a Gymnasium evaluation is reset with seed ``EVAL_SEED + i`` (all runs alike)."""


class NumpyPolicy:
    """Greedy actor in plain NumPy, for one or a stack of seeds.

    ``kernels[i]``/``biases[i]`` are the actor's layers; with a leading seed axis ``[S, ...]``
    when ``stacked``. Calling it on float32 observations returns argmax actions:
    ``(4,) -> int``, ``(N, 4) -> (N,)``, and when stacked ``(S, N, 4) -> (S, N)``.
    """

    def __init__(
        self,
        kernels: list[np.ndarray],
        biases: list[np.ndarray],
        activation: str,
        stacked: bool = False,
    ):
        self.kernels = [np.asarray(k, np.float32) for k in kernels]
        self.biases = [np.asarray(b, np.float32) for b in biases]
        self.activation = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}[activation]
        self.stacked = stacked

    def logits(self, obs: np.ndarray) -> np.ndarray:
        """Policy logits for ``obs`` (any leading shape matching the stacking)."""
        x = np.asarray(obs, np.float32)
        if x.shape[-1] != 4:
            raise ValueError(
                f"expected observations with 4 values in the last axis, got shape {x.shape}"
            )
        last = len(self.kernels) - 1
        for i, (k, b) in enumerate(zip(self.kernels, self.biases)):
            if self.stacked:
                x = np.matmul(x, k) + b[:, None, :]
            else:
                x = x @ k + b
            if i < last:
                x = self.activation(x)
        return x

    def __call__(self, obs: np.ndarray):
        actions = np.argmax(self.logits(obs), axis=-1)
        return int(actions) if actions.ndim == 0 else actions


def actor_layers(params: dict) -> tuple[list, list]:
    """The actor's kernels and biases in order, from ``{"params": {"actor": ...}}``."""
    actor = params["params"]["actor"]
    names = sorted(
        (n for n in actor if n.startswith("hidden_")), key=lambda n: int(n.split("_")[1])
    )
    names.append("out")
    return [actor[n]["kernel"] for n in names], [actor[n]["bias"] for n in names]


def numpy_policy(params: dict, activation: str, stacked: bool = False) -> NumpyPolicy:
    """A :class:`NumpyPolicy` from flax params (with a leading seed axis when ``stacked``)."""
    kernels, biases = actor_layers(jax.device_get(params))
    return NumpyPolicy(kernels, biases, activation, stacked)


def evaluate_gymnasium(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    seed: int = EVAL_SEED,
    env_id: str = "CartPole-v1",
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
    from jaxcart.networks import ActorCritic

    env_params = env_params or cartpole.EnvParams()
    network = ActorCritic(hidden_sizes=tuple(hidden_sizes), activation=activation)
    obs, state = jax.vmap(cartpole.reset, in_axes=(0, None))(
        jax.random.split(key, num_episodes), env_params
    )

    def one_step(carry, _):
        obs, state, alive, total = carry
        action = jnp.argmax(network.apply(params, obs, method=ActorCritic.logits), axis=-1)
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
        "solved": (returns >= 500).all(axis=-1),
    }
