"""Greedy (argmax) evaluation of trained runs, in Gymnasium's own env of the run's id (the
verdict, :mod:`jaxcart.core.solved`) and in jaxcart's JAX env (a cross-check, by
:func:`jaxcart.core.evaluation.greedy_returns`, the one JAX greedy routine)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import jax
import numpy as np

from jaxcart.core import envs, pytree
from jaxcart.core.config import PPOConfig, float_dtype
from jaxcart.core.evaluation import greedy_returns
from jaxcart.core.ppo import make_network
from jaxcart.core.solved import DEFAULT_ENV, EVAL_SEED, NUM_EVAL_EPISODES, is_solved
from jaxcart.engine.loop import seed_index_keys
from jaxcart.engine.signals import Stopped, in_background
from jaxcart.rundir.policy import RunParams, make_policy

FAST_COMPILE = {"xla_backend_optimization_level": 1}
"""XLA's options for the cross-check program: LLVM's lighter optimization halves its compile
time (about 1 s to 0.5 s) and leaves its returns as they were (checked bit for bit)."""

Step = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``(actions [P, E], alive [P, E]) -> (rewards [P, E], done [P, E])``: one step of every
running episode of a policy x episode grid, its observations updated in place (the step of
an :attr:`~jaxcart.core.envs.Env.gymnasium_grid`)."""


def _env_grid(
    env_id: str, params: Any, shape: tuple[int, int], seed: int, stack: contextlib.ExitStack
) -> tuple[np.ndarray, Step, int]:
    """One ``gymnasium.make(env_id)`` per policy and episode, each stepped by its own
    ``step`` (time limit included) on its own physics (``params`` unused); episode ``e``
    starts from ``reset(seed=seed + e)``: the grid of an env without its own
    :attr:`~jaxcart.core.envs.Env.gymnasium_grid`."""
    import gymnasium as gym

    games = [
        [stack.enter_context(gym.make(env_id)) for _ in range(shape[1])] for _ in range(shape[0])
    ]
    obs = np.stack(
        [[np.asarray(g.reset(seed=seed + e)[0]) for e, g in enumerate(row)] for row in games]
    ).astype(np.float32)

    def step(actions: np.ndarray, alive: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        reward, done = np.zeros(shape), np.zeros(shape, bool)
        for p, e in zip(*np.nonzero(alive)):
            obs[p, e], reward[p, e], terminated, truncated, _ = games[p][e].step(int(actions[p, e]))
            done[p, e] = terminated or truncated
        return reward, done

    return obs, step, int(games[0][0].action_space.n)


def evaluate_gymnasium(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    seed: int = EVAL_SEED,
    env_id: str = DEFAULT_ENV,
    should_stop: Callable[[], bool] | None = None,
    env_params: Any = None,
) -> np.ndarray:
    """Runs ``num_episodes`` greedy episodes per policy in ``gymnasium.make(env_id)``: the one
    Gymnasium evaluation loop (the final verdict, ``python -m jaxcart.evaluate``, benchmarks).

    Episode ``e`` of every policy starts where ``gymnasium.make(env_id).reset(seed=seed + e)``
    starts. All policies and episodes then advance in lockstep, with one batched policy call
    per time step (finished episodes keep showing their last observation), until every episode
    has terminated or reached the env's time limit. An env whose protocol has a
    :attr:`~jaxcart.core.envs.Env.gymnasium_grid` steps the whole grid at once with
    ``env_params``' physics (CartPole's: :func:`jaxcart.core.cartpole.gymnasium_grid`, a
    continuous field may hold one value per policy, ``[num_policies]``), each return
    bit-identical to stepping one ``gymnasium.make(env_id)`` per episode; any other
    discrete-action env steps one ``gymnasium.make(env_id)`` per policy and episode, on its
    own physics.

    Args:
        policy: maps observations ``[num_policies, num_episodes, obs_dim]`` float32 to actions
            ``[num_policies, num_episodes]`` (a stacked :class:`~jaxcart.rundir.policy.Policy`).
        env_id: a registered Gymnasium env with discrete actions (``CartPole-v1``,
            ``CartPole-v0``, ``Acrobot-v1``, ...).
        should_stop: polled before every step.

    Returns:
        Episode returns, ``[num_policies, num_episodes]`` float64.

    Raises:
        ValueError: an action outside the env's action space.
        Stopped: ``should_stop()`` turned true.
    """
    grid = _env_grid
    with contextlib.suppress(envs.EnvError):  # an id of Gymnasium's alone: its own envs
        grid = envs.make(env_id).gymnasium_grid or _env_grid
    shape = (num_policies, num_episodes)
    with contextlib.ExitStack() as stack:
        obs, step, num_actions = grid(env_id, env_params, shape, seed, stack)
        returns, alive = np.zeros(shape), np.ones(shape, bool)
        while alive.any():
            if should_stop is not None and should_stop():
                raise Stopped("evaluation interrupted")
            actions = np.asarray(policy(obs))
            invalid = alive & ~np.isin(actions, np.arange(num_actions))
            if invalid.any():
                raise ValueError(
                    f"actions must be in 0..{num_actions - 1}, got {np.unique(actions[invalid])}"
                )
            reward, done = step(actions, alive)
            np.add(returns, reward, out=returns, where=alive)
            alive &= ~done
    return returns


def summarize(returns: np.ndarray, env_id: str = DEFAULT_ENV) -> dict[str, np.ndarray]:
    """Per-policy mean, min and solved flag (as ``env_id`` defines it) from returns
    ``[P, episodes]``."""
    returns = np.asarray(returns)
    return {
        "mean": returns.mean(axis=-1),
        "min": returns.min(axis=-1),
        "solved": is_solved(returns, env_id),
    }


class CrossCheck:
    """The final evaluation of a training's runs (:meth:`evaluate`): greedy returns in the
    env's Gymnasium counterpart (the verdict) and in jaxcart's env (the cross-check), the
    latter from a program that compiles in a thread as soon as the parameters' shapes are
    known (:meth:`compile_for`). Training starts it when its own program has compiled, so
    that the final evaluation finds it ready. The kept-best policies get the Gymnasium verdict
    alone (:meth:`verdict`): nothing records a JAX replay of them.

    Args:
        config: the runs' config (its env and network).
        seed, seed_indices: run r's episodes start from ``fold_in(seed key of
            seed_indices[r], 1)`` in jaxcart's env; Gymnasium's use the same reset seeds
            for all.
        episodes: episodes per run.
        env_params: the physics (default the env's own; a continuous field may hold one
            value per run, ``[R]``; an env without a Gymnasium grid of its own plays
            Gymnasium's episodes on its own physics).
    """

    def __init__(
        self,
        config: PPOConfig,
        seed: int,
        seed_indices: np.ndarray,
        episodes: int,
        env_params: Any = None,
    ) -> None:
        static, per_run = (None, {}) if env_params is None else pytree.split_per_run(env_params)
        network = make_network(config)

        def one_run(p: dict, k: jax.Array, values: dict) -> jax.Array:
            run_env = pytree.with_values(static, values)
            key = jax.random.fold_in(k, 1)
            return greedy_returns(p, key, network, episodes, run_env, config.env)

        self.config, self.episodes, self.env_params = config, episodes, env_params
        self._one_run = one_run
        self._keys = seed_index_keys(seed, np.asarray(seed_indices))
        self._per_run = {n: np.asarray(v, float_dtype()) for n, v in per_run.items()}
        self._program: Future | None = None
        self._shapes: Any = None

    def compile_for(self, params: Any) -> Future:
        """Starts compiling the program for parameters shaped as ``params`` (arrays or
        ``jax.ShapeDtypeStruct`` leaves ``[R, ...]``), unless it was started for that shape;
        returns the future of the compiled program."""
        shapes = jax.tree.map(lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype), params)
        if self._program is None or shapes != self._shapes:
            self._shapes, self._program = shapes, Future()
            args = (shapes, self._keys, self._per_run)
            program = jax.jit(jax.vmap(self._one_run))
            in_background(lambda: program.lower(*args).compile(FAST_COMPILE), self._program)
        return self._program

    def returns(self, params: dict) -> Future:
        """A future of jaxcart's greedy returns ``[R, episodes]`` of ``params`` (NumPy,
        leaves ``[R, ...]``), computed in a thread once the program is compiled."""
        self.compile_for(params)
        program, done = self._program, Future()
        in_background(lambda: np.asarray(program.result()(params, self._keys, self._per_run)), done)
        return done

    def evaluate(
        self, params: dict, should_stop: Callable[[], bool] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Greedy returns of ``params`` (NumPy, leaves ``[R, ...]``) in Gymnasium's env and
        in jaxcart's, ``([R, episodes], [R, episodes])``: jaxcart's program runs in a thread
        while Gymnasium's episodes run (:meth:`verdict`).

        Raises:
            Stopped: ``should_stop()`` turned true during Gymnasium's episodes.
        """
        jax_returns = self.returns(params)
        return self.verdict(params, should_stop), jax_returns.result()

    def verdict(self, params: dict, should_stop: Callable[[], bool] | None = None) -> np.ndarray:
        """Greedy returns ``[R, episodes]`` of ``params`` in Gymnasium's env alone
        (:func:`evaluate_params`): the kept-best policies' verdict, of which no JAX replay is
        recorded.

        Raises:
            Stopped: ``should_stop()`` turned true during Gymnasium's episodes.
        """
        trained = RunParams(params, self.config, len(self._keys), env_params=self.env_params)
        return evaluate_params(trained, self.episodes, should_stop)


def evaluate_params(
    trained: RunParams, episodes: int, should_stop: Callable[[], bool] | None = None
) -> np.ndarray:
    """Greedy returns ``[num_seeds, episodes]`` of every seed of ``trained`` in Gymnasium's env
    of its id (:func:`evaluate_gymnasium`), on its physics: the final evaluation of a training
    and ``python -m jaxcart.evaluate`` alike. A run directory's parameters are the store's,
    checked against the run's network as they were read (:func:`run_params`)."""
    policy = make_policy(trained.params, trained.config, stacked=True)
    config, env_params = trained.config, trained.env_params
    return evaluate_gymnasium(
        policy, trained.num_seeds, episodes, EVAL_SEED, config.env, should_stop, env_params
    )
