"""Greedy (argmax) evaluation of trained runs, in Gymnasium's own env of the run's id (the
verdict, :mod:`jaxcart.core.solved`) and in jaxcart's JAX env (a cross-check)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np

from jaxcart.core import cartpole, physics
from jaxcart.core.config import PPOConfig, float_dtype
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.evaluation import greedy_returns
from jaxcart.core.ppo import make_network
from jaxcart.core.solved import EVAL_SEED, NUM_EVAL_EPISODES, is_solved
from jaxcart.engine.loop import seed_index_keys
from jaxcart.engine.signals import Stopped
from jaxcart.gym.stock import make_cartpole, reset_options
from jaxcart.rundir import reader
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.policy import RunParams, make_policy, run_params


@dataclass(frozen=True)
class _GymnasiumCartPole:
    """The constants of one ``gymnasium.make(env_id)`` CartPole (Gymnasium's ``CartPoleEnv``
    under its ``TimeLimit``), and its step for a whole batch of states at once."""

    gravity: float
    masscart: float
    masspole: float
    total_mass: float
    length: float
    polemass_length: float
    force_mag: float
    tau: float
    x_threshold: float
    theta_threshold_radians: float
    euler: bool
    sutton_barto_reward: bool
    max_episode_steps: int | None  # the TimeLimit's; None: no truncation

    @classmethod
    def of(cls, env) -> _GymnasiumCartPole:
        """The constants of ``env`` (a ``gymnasium.make`` result) as its step reads them."""
        from gymnasium.envs.classic_control.cartpole import CartPoleEnv

        cartpole = env.unwrapped
        if not isinstance(cartpole, CartPoleEnv):
            name = env.spec.id if env.spec is not None else repr(env)
            raise ValueError(
                f"{name} is not Gymnasium's CartPoleEnv "
                f"({type(cartpole).__name__}): the batched evaluation steps CartPoleEnv's physics"
            )
        return cls(
            gravity=cartpole.gravity,
            masscart=cartpole.masscart,
            masspole=cartpole.masspole,
            total_mass=cartpole.total_mass,
            length=cartpole.length,
            polemass_length=cartpole.polemass_length,
            force_mag=cartpole.force_mag,
            tau=cartpole.tau,
            x_threshold=cartpole.x_threshold,
            theta_threshold_radians=cartpole.theta_threshold_radians,
            euler=cartpole.kinematics_integrator == "euler",
            sutton_barto_reward=bool(getattr(cartpole, "_sutton_barto_reward", False)),
            max_episode_steps=env.spec.max_episode_steps if env.spec else None,
        )

    def per_policy(self, per_run: dict[str, np.ndarray]) -> _GymnasiumCartPole:
        """These constants with some fields one value per policy (arrays ``[P]``, shaped
        ``[P, 1]`` to broadcast over the episodes), and the masses Gymnasium derives from
        them recomputed as its constructor does."""
        if not per_run:
            return self
        values = {n: np.asarray(v, np.float64)[:, None] for n, v in per_run.items()}
        new = dataclasses.replace(self, **values)
        return dataclasses.replace(
            new,
            total_mass=new.masspole + new.masscart,
            polemass_length=new.masspole * new.length,
        )

    def step(self, state: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``CartPoleEnv.step`` for every state at once: float64 ``state [4, ...]`` (rows x,
        x_dot, theta, theta_dot) and actions ``[...]`` -> ``(next state [4, ...], terminated
        [...])``.

        Every line is ``CartPoleEnv.step``'s, in its order of operations, on arrays: NumPy's
        element-wise float64 arithmetic rounds each operation as on the single env's scalars,
        so each next state is bit-identical to the single env's.
        """
        x, x_dot, theta, theta_dot = state
        force = np.where(actions == 1, self.force_mag, -self.force_mag)
        costheta = np.cos(theta)
        sintheta = np.sin(theta)
        temp = (force + self.polemass_length * np.square(theta_dot) * sintheta) / self.total_mass
        thetaacc = (self.gravity * sintheta - costheta * temp) / (
            self.length * (4.0 / 3.0 - self.masspole * np.square(costheta) / self.total_mass)
        )
        xacc = temp - self.polemass_length * thetaacc * costheta / self.total_mass
        if self.euler:
            x = x + self.tau * x_dot
            x_dot = x_dot + self.tau * xacc
            theta = theta + self.tau * theta_dot
            theta_dot = theta_dot + self.tau * thetaacc
        else:  # semi-implicit Euler
            x_dot = x_dot + self.tau * xacc
            x = x + self.tau * x_dot
            theta_dot = theta_dot + self.tau * thetaacc
            theta = theta + self.tau * theta_dot
        terminated = (
            (x < -self.x_threshold)
            | (x > self.x_threshold)
            | (theta < -self.theta_threshold_radians)
            | (theta > self.theta_threshold_radians)
        )
        return np.stack([x, x_dot, theta, theta_dot]), terminated

    def reward(self, terminated: np.ndarray) -> np.ndarray:
        """``CartPoleEnv``'s reward of a step that ended ``terminated`` (the first time)."""
        if self.sutton_barto_reward:
            return np.where(terminated, -1.0, 0.0)
        return np.ones(terminated.shape)


def _start_states(
    env, seed: int, num_episodes: int, options: dict | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Episode ``e``'s start from ``env.reset(seed=seed + e, options=options)``: ``(states
    [4, num_episodes] float64, observations [num_episodes, 4] float32)``, drawn by Gymnasium
    itself."""
    states, observations = [], []
    for e in range(num_episodes):
        obs, _ = env.reset(seed=seed + e, options=options)
        states.append(np.array(env.unwrapped.state, dtype=np.float64))
        observations.append(obs)
    return np.stack(states, axis=1), np.stack(observations)


def evaluate_gymnasium(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    seed: int = EVAL_SEED,
    env_id: str = "CartPole-v1",
    should_stop: Callable[[], bool] | None = None,
    env_params: cartpole.EnvParams | None = None,
) -> np.ndarray:
    """Runs ``num_episodes`` greedy episodes per policy in ``gymnasium.make(env_id)``, with
    ``env_params``' physics when given (:func:`jaxcart.gym.stock.make_cartpole`; a continuous
    field may hold one value per policy, ``[num_policies]``).

    Episode ``e`` of every policy starts where ``gymnasium.make(env_id).reset(seed=seed + e)``
    starts. All policies and episodes then advance in lockstep, with one batched policy call
    and one batched float64 NumPy physics step per time step (:class:`_GymnasiumCartPole`,
    Gymnasium's ``CartPoleEnv.step`` on arrays), until every episode has terminated or reached
    the env's time limit. Each return is bit-identical to stepping one ``gymnasium.make(env_id)``
    per episode: the same start states, float64 dynamics and float32 observations, and the
    same policy calls (finished episodes keep showing their last observation).

    Args:
        policy: maps observations ``[num_policies, num_episodes, 4]`` float32 to actions
            ``[num_policies, num_episodes]`` in ``{0, 1}`` (a stacked :class:`NumpyPolicy`).
        env_id: a registered Gymnasium ``CartPoleEnv`` (``CartPole-v1``, ``CartPole-v0``, ...).
        should_stop: polled before every step.

    Returns:
        Episode returns, ``[num_policies, num_episodes]`` float64.

    Raises:
        ValueError: ``env_id`` is not Gymnasium's ``CartPoleEnv``, or an action not 0 or 1.
        Stopped: ``should_stop()`` turned true.
    """
    static, per_run = physics.split_per_run(env_params or cartpole.EnvParams())
    env = make_cartpole(static, env_id)
    try:
        constants = _GymnasiumCartPole.of(env).per_policy(per_run)
        states, first_obs = _start_states(env, seed, num_episodes, reset_options(static))
    finally:
        env.close()
    shape = (num_policies, num_episodes)
    state = np.broadcast_to(states[:, None, :], (4, *shape)).copy()  # rows contiguous
    obs = np.broadcast_to(first_obs, (*shape, 4)).copy()
    returns = np.zeros(shape)
    alive = np.ones(shape, bool)
    steps = 0
    while alive.any():
        if should_stop is not None and should_stop():
            raise Stopped("evaluation interrupted")
        actions = np.asarray(policy(obs))
        invalid = alive & (actions != 0) & (actions != 1)
        if invalid.any():
            raise ValueError(f"actions must be 0 or 1, got {np.unique(actions[invalid])}")
        stepped, terminated = constants.step(state, actions)
        steps += 1
        # Only the running episodes move on; the finished keep their state and observation.
        np.add(returns, constants.reward(terminated), out=returns, where=alive)
        np.copyto(state, stepped, where=alive)
        np.copyto(obs, np.moveaxis(stepped, 0, -1), casting="same_kind", where=alive[..., None])
        alive &= ~terminated
        if constants.max_episode_steps is not None and steps >= constants.max_episode_steps:
            alive[:] = False  # TimeLimit: every episode still running is truncated here
    return returns


def evaluate_gymnasium_env(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    seed: int = EVAL_SEED,
    env_id: str = "Acrobot-v1",
    should_stop: Callable[[], bool] | None = None,
) -> np.ndarray:
    """:func:`evaluate_gymnasium` for any discrete-action Gymnasium env, stepping one
    ``gymnasium.make(env_id)`` per policy and episode (its own ``step``, time limit included).

    Episode ``e`` of every policy starts from ``reset(seed=seed + e)``; all episodes advance in
    lockstep with one batched policy call per time step (finished episodes keep showing their
    last observation).

    Args:
        policy: maps observations ``[num_policies, num_episodes, obs_dim]`` float32 to actions
            ``[num_policies, num_episodes]``.

    Returns:
        Episode returns, ``[num_policies, num_episodes]`` float64.

    Raises:
        ValueError: an action outside the env's action space.
        Stopped: ``should_stop()`` turned true.
    """
    import gymnasium as gym

    shape = (num_policies, num_episodes)
    games = [[gym.make(env_id) for _ in range(num_episodes)] for _ in range(num_policies)]
    try:
        obs = np.stack(
            [[np.asarray(g.reset(seed=seed + e)[0]) for e, g in enumerate(row)] for row in games]
        ).astype(np.float32)
        num_actions = int(games[0][0].action_space.n)
        returns = np.zeros(shape)
        alive = np.ones(shape, bool)
        while alive.any():
            if should_stop is not None and should_stop():
                raise Stopped("evaluation interrupted")
            actions = np.asarray(policy(obs))
            invalid = alive & ((actions < 0) | (actions >= num_actions))
            if invalid.any():
                raise ValueError(
                    f"actions must be in 0..{num_actions - 1}, got {np.unique(actions[invalid])}"
                )
            for p, e in zip(*np.nonzero(alive)):
                next_obs, reward, terminated, truncated, _ = games[p][e].step(int(actions[p, e]))
                obs[p, e] = next_obs
                returns[p, e] += float(reward)
                alive[p, e] = not (terminated or truncated)
    finally:
        for row in games:
            for g in row:
                g.close()
    return returns


def evaluate_in_gymnasium(
    policy: Callable[[np.ndarray], np.ndarray],
    num_policies: int,
    num_episodes: int = NUM_EVAL_EPISODES,
    env_id: str = DEFAULT_ENV,
    should_stop: Callable[[], bool] | None = None,
    env_params: cartpole.EnvParams | None = None,
) -> np.ndarray:
    """Greedy returns ``[num_policies, num_episodes]`` in ``gymnasium.make(env_id)``: CartPole
    by the batched :func:`evaluate_gymnasium` (with ``env_params``' physics), any other env by
    :func:`evaluate_gymnasium_env` (with its own)."""
    if env_id == DEFAULT_ENV:
        return evaluate_gymnasium(
            policy, num_policies, num_episodes, should_stop=should_stop, env_params=env_params
        )
    return evaluate_gymnasium_env(
        policy, num_policies, num_episodes, env_id=env_id, should_stop=should_stop
    )


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
    env_params: cartpole.EnvParams | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Greedy returns of every run of a training, ``([R, episodes], [R, episodes])``: in
    Gymnasium's CartPole-v1 (the same reset seeds for all) and in jaxcart's env (run r's
    episodes from ``fold_in(seed key of seed_indices[r], 1)``), both with ``env_params``'
    physics (default CartPole-v1's; a continuous field may hold one value per run, ``[R]``).

    Args:
        params: network parameters, leaves ``[R, ...]`` (NumPy).
    """
    num_runs = len(seed_indices)
    if config.env == DEFAULT_ENV:
        env_params = env_params or cartpole.EnvParams()
    else:  # another env plays on its own default params (env_params are CartPole's physics)
        env_params = None
    policy = make_policy(params, config, stacked=True)
    gym_returns = evaluate_in_gymnasium(
        policy, num_runs, episodes, config.env, should_stop=should_stop, env_params=env_params
    )
    indices = np.asarray(seed_indices)
    keys = jax.vmap(lambda k: jax.random.fold_in(k, 1))(seed_index_keys(seed, indices))
    network = make_network(config)
    static, per_run = physics.split_per_run(env_params)
    per_run = {n: np.asarray(v, float_dtype()) for n, v in per_run.items()}

    def one_run(p: dict, k: jax.Array, values: dict) -> jax.Array:
        run_env = physics.with_values(static, values)
        return greedy_returns(p, k, network, episodes, run_env, config.env)

    evaluate = jax.jit(jax.vmap(one_run))
    return gym_returns, np.asarray(evaluate(params, keys, per_run))


def evaluate_run_dir(
    run_dir: str | Path,
    episodes: int = NUM_EVAL_EPISODES,
    combination: int | None = None,
    network: type | None = None,
    trust_code: bool = False,
) -> tuple[np.ndarray, dict]:
    """Evaluates every seed of a run directory in Gymnasium's CartPole-v1: a finished run's
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
    return evaluate_params(run_dir, trained, episodes), {**info, "note": trained.note}


def evaluate_params(run_dir: str | Path, trained: RunParams, episodes: int) -> np.ndarray:
    try:
        policy = make_policy(trained.params, trained.config, stacked=True)
    except (KeyError, TypeError, ValueError) as exc:
        raise RunDirError(f"{run_dir} does not hold an actor: {exc}") from None
    return evaluate_in_gymnasium(
        policy, trained.num_seeds, episodes, trained.config.env, env_params=trained.env_params
    )
