"""The environments the trainer runs: jaxcart's CartPole-v1, gymnax's discrete-action envs
that Gymnasium also has (Acrobot-v1, MountainCar-v0), and any env a user registers
(:func:`register`), behind one functional protocol.

An :class:`Env` is the protocol gymnax and jaxcart share, as functions of a state and a params
pytree passed beside the config: ``reset(key, params) -> (obs, state)`` and a batched
``step_batch(key, state, action, params)`` that keeps ``terminated`` and ``truncated`` apart
and resets finished episodes on the same step, plus the sizes the trainer takes from it
(``obs_dim``, ``num_actions``). Nothing outside an env's own module asks which env it is: what
differs (CartPole's first states drawn on the host, its physics that may differ between runs:
:func:`~jaxcart.core.pytree.per_run_field`) is a member of the protocol or of the params.

gymnax's own ``step`` resets inside and merges the episode end into its bookkeeping; the
trainer bootstraps a time-limit truncation from V(final_obs), so the adapter here calls
gymnax's ``step_env`` (the transition alone: its ``done`` is the natural termination in gymnax
1.x), reads the truncation from the state's step counter against the params' time limit
(``state.time >= params.max_steps_in_episode``, gymnax's ``is_truncated``) and resets itself.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import cartpole, physics, pytree
from jaxcart.core.solved import DEFAULT_ENV, EPISODE_LIMITS, GYMNAX_ENVS

Array = jax.Array

GYMNAX_EXTRA = "pip install -e '.[gymnax]'"

ACTION_COUNTS = {DEFAULT_ENV: 2, "Acrobot-v1": 3, "MountainCar-v0": 3}
"""Each env's discrete actions, for readers of finished runs that need no gymnax import (the
plots); :func:`make`'s :attr:`Env.num_actions` agree (tested)."""


class EnvError(ValueError):
    """An env id the trainer cannot run; the message is one line that says why."""


@dataclass(frozen=True)
class Env:
    """One environment as the trainer sees it.

    Attributes:
        id: the env id (Gymnasium's, which gymnax's mirrors).
        obs_dim: observation size; observations are ``[obs_dim]`` floats.
        num_actions: discrete actions ``0 .. num_actions - 1``.
        default_params: the env's params pytree with its default (Gymnasium's) values.
        reset: ``(key, params) -> (obs [obs_dim], state)`` for one env.
        step_batch: ``(key, state [N], action [N], params) -> (obs [N, obs_dim], state [N],
            reward [N], terminated [N], truncated [N], {"final_obs": [N, obs_dim]})``, finished
            episodes reset on the same step (``final_obs``: the observation before the reset).
        reward_threshold: Gymnasium's ``reward_threshold`` for this id, or None for CartPole,
            which is judged by its own stricter rule (:mod:`jaxcart.core.solved`).
        gymnasium_grid: ``(id, params, (P, E), seed, stack) -> (obs [P, E, obs_dim], step,
            num_actions)``: Gymnasium's env of this id with ``params``' physics for a grid of
            greedy episodes stepped at once on the host, bit for bit as one env per episode
            (CartPole's: :func:`jaxcart.core.cartpole.gymnasium_grid`); None: one
            ``gymnasium.make(id)`` per episode (:func:`jaxcart.run.greedy.evaluate_gymnasium`).
        max_episode_steps: the time limit (CartPole's default; its params may set another).
        host_reset: ``(rng, params, num_envs, dtype) -> (obs [num_envs, obs_dim], state
            [num_envs])`` in NumPy from a run's ``numpy.random.Generator``: the first episodes
            drawn on the host, no program to compile (CartPole's); None: ``reset`` with keys
            the generator draws.
        draw_frame: ``(state, params) -> frame [H, W, 3] uint8`` of the state of Gymnasium's
            env of this id, drawn without pygame (CartPole's, with Pillow: GIFs where pygame
            is missing); None: frames come from Gymnasium's renderer alone.
    """

    id: str
    obs_dim: int
    num_actions: int
    default_params: Callable[[], Any]
    reset: Callable[[Array, Any], tuple[Array, Any]]
    step_batch: Callable[..., tuple]
    reward_threshold: float | None = None
    gymnasium_grid: Callable[..., tuple] | None = None
    max_episode_steps: int = 500
    host_reset: Callable[[np.random.Generator, Any, int, np.dtype], tuple] | None = None
    draw_frame: Callable[[Any, Any], np.ndarray] | None = None


CARTPOLE = Env(
    id=DEFAULT_ENV,
    obs_dim=4,
    num_actions=2,
    default_params=cartpole.EnvParams,
    gymnasium_grid=cartpole.gymnasium_grid,
    reset=cartpole.reset,
    # steps an EpisodeState too: physics drawn anew at every reset (--randomize ...:episode)
    step_batch=physics.step_batch,
    host_reset=cartpole.host_reset,
    draw_frame=cartpole.draw_frame,
)

_ENVS: dict[str, Env] = {DEFAULT_ENV: CARTPOLE}
"""jaxcart's own env and those registered in this process (gymnax's are made on demand)."""


def register(env: Env) -> Env:
    """Makes ``env`` one the trainer takes by its id in this process (``PPOConfig(env=env.id)``,
    :func:`~jaxcart.engine.loop.train`, :func:`~jaxcart.core.evaluation.greedy_returns`), as
    ``jaxcart.register_env``; returns it. A run directory judges its runs in Gymnasium's env of
    the same id, so ``run_new`` takes the built-in ids only.

    Raises:
        EnvError: the id is one of jaxcart's own envs.
    """
    if env.id in ACTION_COUNTS:
        raise EnvError(f"env {env.id} is one of jaxcart's own; register yours under another id")
    _ENVS[env.id] = env
    make.cache_clear()
    return env


def env_ids() -> list[str]:
    """Every env id the trainer takes."""
    return [*_ENVS, *GYMNAX_ENVS]


@functools.cache
def make(env_id: str) -> Env:
    """The :class:`Env` of ``env_id`` (cached: the same object every call, so it can key
    compiled programs).

    Raises:
        EnvError: an unknown id, an env this trainer cannot run (continuous actions, no
            Gymnasium counterpart), or gymnax not installed; the message is one line.
    """
    if env_id in _ENVS:
        return _ENVS[env_id]
    try:
        import gymnax
        from gymnax.environments import spaces
    except ImportError:
        if env_id in GYMNAX_ENVS:
            raise EnvError(
                f"env {env_id} runs on gymnax's implementation, not installed: {GYMNAX_EXTRA}"
            ) from None
        raise EnvError(f"unknown env {env_id!r}; choose one of: {', '.join(env_ids())}") from None
    if env_id not in gymnax.registered_envs:
        raise EnvError(f"unknown env {env_id!r}; choose one of: {', '.join(env_ids())}")
    env, params = gymnax.make(env_id)
    trains = f"(it trains {', '.join(env_ids())})"
    if not isinstance(env.action_space(params), spaces.Discrete):
        raise EnvError(
            f"env {env_id} has continuous actions; jaxcart's PPO samples discrete actions {trains}"
        )
    if env_id not in GYMNAX_ENVS:
        raise EnvError(
            f"env {env_id} is not one jaxcart trains: runs are judged in Gymnasium's env of the "
            f"same id, which Gymnasium lacks for it {trains}"
        )

    def step(key: Array, state: Any, action: Array, params: Any) -> tuple:
        # gymnax 1.x's done is the natural termination; truncation is its time limit's
        obs, state, reward, terminated, _ = env.step_env(key, state, action, params)
        return obs, state, reward, terminated, state.time >= params.max_steps_in_episode

    return from_step(
        env_id,
        obs_dim=int(math.prod(env.observation_space(params).shape)),
        num_actions=int(env.action_space(params).n),
        reset=env.reset_env,
        step=step,
        default_params=lambda: env.default_params,
        max_episode_steps=EPISODE_LIMITS[env_id],
        reward_threshold=GYMNAX_ENVS[env_id],
    )


def from_step(
    id: str,
    *,
    obs_dim: int,
    num_actions: int,
    reset: Callable[[Array, Any], tuple[Array, Any]],
    step: Callable[[Array, Any, Array, Any], tuple],
    max_episode_steps: int,
    reward_threshold: float,
    default_params: Callable[[], Any] = lambda: None,
) -> Env:
    """An :class:`Env` from the functions of one env, gymnax's style: ``reset(key, params) ->
    (obs, state)`` and ``step(key, state, action, params) -> (obs, state, reward, terminated,
    truncated)`` (no reset inside; ``truncated``: the time limit). Its ``step_batch`` vmaps
    ``step`` over ``N`` envs and resets the finished ones on the same step (their last
    observation in ``final_obs``); observations are flattened to ``[obs_dim]`` floats of the
    training dtype."""

    def flat_reset(key: Array, params: Any) -> tuple[Array, Any]:
        obs, state = reset(key, params)
        return _flat_obs(obs, 0), state

    return Env(
        id=id,
        obs_dim=obs_dim,
        num_actions=num_actions,
        default_params=default_params,
        reset=flat_reset,
        step_batch=functools.partial(_step_batch, reset, step),
        max_episode_steps=max_episode_steps,
        reward_threshold=reward_threshold,
    )


def _flat_obs(obs: Array, batch_dims: int) -> Array:
    """Observations as floats of the training dtype, flattened to ``[..., obs_dim]``."""
    obs = jnp.asarray(obs, pytree.float_dtype())
    return obs.reshape(obs.shape[:batch_dims] + (-1,))


def _step_batch(
    reset: Callable, step: Callable, key: Array, state: Any, action: Array, params: Any
) -> tuple[Array, Any, Array, Array, Array, dict[str, Array]]:
    """One env's ``step`` for ``N`` envs, with same-step resets (:func:`from_step`)."""
    num_envs = action.shape[0]
    step_key, reset_key = jax.random.split(key)
    step_keys = jax.random.split(step_key, num_envs)
    final_obs, next_state, reward, terminated, truncated = jax.vmap(step, in_axes=(0, 0, 0, None))(
        step_keys, state, action, params
    )
    terminated, truncated = jnp.asarray(terminated, bool), jnp.asarray(truncated, bool)
    done = terminated | truncated
    reset_obs, reset_state = jax.vmap(reset, in_axes=(0, None))(
        jax.random.split(reset_key, num_envs), params
    )
    final_obs = _flat_obs(final_obs, 1)
    fresh = (_flat_obs(reset_obs, 1), reset_state)
    obs, state_out = pytree.where(done, fresh, (final_obs, next_state))
    reward = jnp.asarray(reward, final_obs.dtype)
    return obs, state_out, reward, terminated, truncated, {"final_obs": final_obs}
