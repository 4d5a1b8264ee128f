"""Greedy (argmax) evaluation of trained runs, in Gymnasium's own env of the run's id (the
verdict, :mod:`jaxcart.core.solved`) and in jaxcart's JAX env (a cross-check, by
:func:`jaxcart.core.evaluation.greedy_returns`, the one JAX greedy routine)."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import jax
import numpy as np

from jaxcart.core import physics
from jaxcart.core.config import PPOConfig, float_dtype
from jaxcart.core.evaluation import greedy_returns
from jaxcart.core.ppo import make_network
from jaxcart.core.solved import DEFAULT_ENV, EVAL_SEED, NUM_EVAL_EPISODES, is_solved
from jaxcart.engine.loop import seed_index_keys
from jaxcart.engine.signals import Stopped
from jaxcart.gym.stock import make_cartpole, reset_options
from jaxcart.rundir import reader
from jaxcart.rundir.policy import RunParams, make_policy, run_params

FAST_COMPILE = {"xla_backend_optimization_level": 1}
"""XLA's options for the cross-check program: LLVM's lighter optimization halves its compile
time (about 1 s to 0.5 s) and leaves its returns as they were (checked bit for bit)."""

Step = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``(actions [P, E], alive [P, E]) -> (rewards [P, E], done [P, E])``: one step of every
running episode of a policy x episode grid, its observations updated in place."""


def cartpole_step(c: Any, state: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``CartPoleEnv.step`` for every state at once, with the constants of ``c`` (a
    ``CartPoleEnv``, or its attributes with some one value per policy ``[P, 1]``): float64
    ``state [4, ...]`` (rows x, x_dot, theta, theta_dot) and actions ``[...]`` -> ``(next state
    [4, ...], terminated [...])``.

    Every line is ``CartPoleEnv.step``'s, in its order of operations, on arrays: NumPy's
    element-wise float64 arithmetic rounds each operation as on the single env's scalars,
    so each next state is bit-identical to the single env's.
    """
    x, x_dot, theta, theta_dot = state
    force = np.where(actions == 1, c.force_mag, -c.force_mag)
    costheta = np.cos(theta)
    sintheta = np.sin(theta)
    temp = (force + c.polemass_length * np.square(theta_dot) * sintheta) / c.total_mass
    thetaacc = (c.gravity * sintheta - costheta * temp) / (
        c.length * (4.0 / 3.0 - c.masspole * np.square(costheta) / c.total_mass)
    )
    xacc = temp - c.polemass_length * thetaacc * costheta / c.total_mass
    if c.kinematics_integrator == "euler":
        x = x + c.tau * x_dot
        x_dot = x_dot + c.tau * xacc
        theta = theta + c.tau * theta_dot
        theta_dot = theta_dot + c.tau * thetaacc
    else:  # semi-implicit Euler
        x_dot = x_dot + c.tau * xacc
        x = x + c.tau * x_dot
        theta_dot = theta_dot + c.tau * thetaacc
        theta = theta + c.tau * theta_dot
    terminated = (
        (x < -c.x_threshold)
        | (x > c.x_threshold)
        | (theta < -c.theta_threshold_radians)
        | (theta > c.theta_threshold_radians)
    )
    return np.stack([x, x_dot, theta, theta_dot]), terminated


def _cartpole_grid(
    env: Any, shape: tuple[int, int], seed: int, per_run: dict, options: dict | None
) -> tuple[np.ndarray, Step]:
    """Gymnasium's ``CartPoleEnv`` (``env``, a ``gymnasium.make`` result: its time limit
    included) for a grid of episodes in float64 NumPy arrays: episode ``e``'s start is
    ``env.reset(seed=seed + e, options=options)``'s, drawn by Gymnasium; the fields of
    ``per_run`` take one value per policy (``[P]``), and the masses Gymnasium derives from them
    are recomputed as its constructor does."""
    c = SimpleNamespace(**vars(env.unwrapped))
    for name, values in per_run.items():
        setattr(c, name, np.asarray(values, np.float64)[:, None])  # [P, 1]: over the episodes
    c.total_mass = c.masspole + c.masscart
    c.polemass_length = c.masspole * c.length
    limit = env.spec.max_episode_steps
    starts, first_obs = [], []
    for e in range(shape[1]):
        first_obs.append(env.reset(seed=seed + e, options=options)[0])
        starts.append(np.array(env.unwrapped.state, dtype=np.float64))
    state = np.broadcast_to(np.stack(starts, axis=1)[:, None, :], (4, *shape)).copy()
    obs = np.broadcast_to(np.stack(first_obs), (*shape, 4)).copy()  # rows contiguous
    steps = 0

    def step(actions: np.ndarray, alive: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        nonlocal steps
        stepped, terminated = cartpole_step(c, state, actions)
        steps += 1
        # Only the running episodes move on; the finished keep their state and observation.
        np.copyto(state, stepped, where=alive)
        np.copyto(obs, np.moveaxis(stepped, 0, -1), casting="same_kind", where=alive[..., None])
        if getattr(c, "_sutton_barto_reward", False):
            reward = np.where(terminated, -1.0, 0.0)
        else:
            reward = np.ones(shape)
        truncated = limit is not None and steps >= limit
        return reward, terminated | truncated  # TimeLimit: every running episode truncated

    return obs, step


def _env_grid(
    env_id: str, shape: tuple[int, int], seed: int, stack: contextlib.ExitStack
) -> tuple[np.ndarray, Step]:
    """One ``gymnasium.make(env_id)`` per policy and episode, each stepped by its own
    ``step`` (time limit included); episode ``e`` starts from ``reset(seed=seed + e)``."""
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

    return obs, step


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
    has terminated or reached the env's time limit. A Gymnasium ``CartPoleEnv`` steps as one
    batched float64 NumPy physics step (:func:`cartpole_step`), with ``env_params``' physics
    (:func:`jaxcart.gym.stock.make_cartpole`; a continuous field may hold one value per
    policy, ``[num_policies]``); each return is bit-identical to stepping one
    ``gymnasium.make(env_id)`` per episode (the same start states, float64 dynamics, float32
    observations and policy calls). Any other discrete-action env steps one
    ``gymnasium.make(env_id)`` per policy and episode, on its own physics.

    Args:
        policy: maps observations ``[num_policies, num_episodes, obs_dim]`` float32 to actions
            ``[num_policies, num_episodes]`` (a stacked :class:`NumpyPolicy`).
        env_id: a registered Gymnasium env with discrete actions (``CartPole-v1``,
            ``CartPole-v0``, ``Acrobot-v1``, ...).
        should_stop: polled before every step.

    Returns:
        Episode returns, ``[num_policies, num_episodes]`` float64.

    Raises:
        ValueError: an action outside the env's action space.
        Stopped: ``should_stop()`` turned true.
    """
    from gymnasium.envs.classic_control.cartpole import CartPoleEnv

    shape = (num_policies, num_episodes)
    static, per_run = _split(env_params)
    with contextlib.ExitStack() as stack:
        env = stack.enter_context(make_cartpole(static, env_id))
        num_actions = int(env.action_space.n)
        if isinstance(env.unwrapped, CartPoleEnv):
            obs, step = _cartpole_grid(env, shape, seed, per_run, reset_options(static))
        else:
            obs, step = _env_grid(env_id, shape, seed, stack)
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


def evaluate_runs(
    params: dict,
    config: PPOConfig,
    seed: int,
    seed_indices: np.ndarray,
    episodes: int,
    should_stop: Callable[[], bool] | None = None,
    env_params: Any = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy returns of every run of a training, ``([R, episodes], [R, episodes])``: in
    Gymnasium's env of ``config.env`` (the same reset seeds for all) and in jaxcart's env (run
    r's episodes from ``fold_in(seed key of seed_indices[r], 1)``), both with ``env_params``'
    physics (default CartPole-v1's; a continuous field may hold one value per run, ``[R]``;
    another env plays on its own). jaxcart's program compiles and runs in a thread while
    Gymnasium's episodes run.

    Args:
        params: network parameters, leaves ``[R, ...]`` (NumPy).
    """
    static, per_run = _split(env_params)
    per_run = {n: np.asarray(v, float_dtype()) for n, v in per_run.items()}
    network = make_network(config)

    def one_run(p: dict, k: jax.Array, values: dict) -> jax.Array:
        run_env = physics.with_values(static, values)
        key = jax.random.fold_in(k, 1)
        return greedy_returns(p, key, network, episodes, run_env, config.env)

    def in_jaxcart() -> np.ndarray:
        args = (params, seed_index_keys(seed, np.asarray(seed_indices)), per_run)
        program = jax.jit(jax.vmap(one_run)).lower(*args).compile(FAST_COMPILE)
        return np.asarray(program(*args))

    with ThreadPoolExecutor(1) as pool:
        jax_returns = pool.submit(in_jaxcart)
        trained = RunParams(params, config, len(seed_indices), env_params=env_params)
        return evaluate_params(trained, episodes, should_stop), jax_returns.result()


def evaluate_run_dir(
    run_dir: str | Path,
    episodes: int = NUM_EVAL_EPISODES,
    combination: int | None = None,
    network: type | None = None,
    trust_code: bool = False,
) -> tuple[np.ndarray, dict]:
    """Evaluates every seed of a run directory in Gymnasium's env of its id: a finished run's
    ``params.npz``, or the last checkpoint of one that did not finish.

    Args:
        combination: for a sweep directory, which combination.
        network, trust_code: for a run trained with its own network, as
            :func:`~jaxcart.rundir.policy.load_policy` takes them.

    Returns:
        ``(returns [num_seeds, episodes], info)`` with ``info`` the run's ``config.json``
        and ``info["note"]``: None, or where the parameters came from when the run did not
        finish (``from the checkpoint at iteration 12/40: the run did not finish``).

    Raises:
        RunDirError: not a usable run (or a sweep without ``combination``).
    """
    info = reader.read_run_config(run_dir)
    trained = run_params(run_dir, combination, network=network, trust_code=trust_code)
    return evaluate_params(trained, episodes), {**info, "note": trained.note}


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


def _split(env_params: Any) -> tuple[Any, dict[str, np.ndarray]]:
    """``(static, per_run)`` of CartPole's physics (:func:`~jaxcart.core.pytree.split_per_run`);
    ``(None, {})`` for None, the env's own."""
    return (None, {}) if env_params is None else physics.split_per_run(env_params)
