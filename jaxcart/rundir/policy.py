"""Trained policies as plain NumPy callables, for any Gymnasium loop (no JAX call per step).

Parameters come from ``params.npz`` of a finished run, or, for a run that did not finish
(stopped, killed, or stopped before its outputs were written), from its ``checkpoint.npz``:
:func:`run_params` says which in :attr:`RunParams.note`.
"""

from __future__ import annotations

import functools
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import envs, networks
from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import ConfigError, PPOConfig, resolve_code
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.reader import read_checkpoint_runs


class Policy:
    """A trained policy for one or a stack of seeds, callable on float32 observations:
    ``(obs_dim,) -> int``, ``(N, obs_dim) -> (N,)``, and when stacked ``(S, N, obs_dim) ->
    (S, N)``. Greedy (argmax) when ``deterministic``, else sampled from the policy's softmax
    with ``rng`` (a NumPy ``Generator``, or a seed for one).

    The built-in MLP (``network`` None: ``params`` holds its actor's layers,
    :func:`jaxcart.core.networks.actor_params`, with a leading seed axis ``[S, ...]`` on every
    array when ``stacked``) runs in plain NumPy, no JAX call per step. Any other flax
    ``network`` runs through JAX, one compiled call per step: the logits of
    ``network.apply(params, obs)``, vmapped over the seeds when ``stacked``."""

    num_seeds: int | None = None  # the leading seed axis of a stacked policy (else None)
    obs_dim: int | None = None  # the observation size (None: taken as given)
    env_id: str | None = None  # the env whose observations it takes (set by make_policy)
    note: str | None = None  # where the parameters came from, if not a finished run
    env_params: EnvParams | None = None
    """The physics the policy trained on (set by :func:`load_policy`; None: the env's own), for
    an env to run it in: ``jaxcart.gym.stock.make_cartpole(policy.env_params)``."""

    def __init__(
        self,
        params: dict,
        network: Any = None,
        activation: str = "tanh",
        stacked: bool = False,
        deterministic: bool = True,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        self.network, self.stacked, self.deterministic = network, stacked, deterministic
        self.rng = np.random.default_rng(rng)
        if network is not None:  # any flax network, through JAX
            self.params = jax.tree.map(jnp.asarray, params)
            logits = lambda p, x: network.apply(p, x)[0]
            self._logits = functools.partial(
                jax.jit(jax.vmap(logits) if stacked else logits), self.params
            )
            self.num_seeds = jax.tree.leaves(self.params)[0].shape[0] if stacked else None
            return

        def layer(p: dict) -> dict:  # the built-in MLP's actor, in NumPy
            kernel, bias = (np.asarray(p[name], np.float32) for name in ("kernel", "bias"))
            # stacked: bias [S, out] -> [S, 1, out] broadcasts over the N observations
            return {"kernel": kernel, "bias": bias[:, None, :] if stacked else bias}

        self.params = {name: layer(p) for name, p in params.items()}
        first = self.params[networks.layer_names(len(params) - 1)[0]]["kernel"]  # [S, obs_dim, h]
        self.num_seeds, self.obs_dim = first.shape[0] if stacked else None, first.shape[-2]
        self._logits = functools.partial(networks.mlp, self.params, activation=activation, xp=np)

    def logits(self, obs: np.ndarray) -> np.ndarray:
        """Policy logits for ``obs`` (any leading shape matching the stacking)."""
        x = np.asarray(obs, np.float32)
        if self.obs_dim is not None and x.shape[-1:] != (self.obs_dim,):
            raise ValueError(
                f"expected observations with {self.obs_dim} values in the last axis, got shape "
                f"{x.shape}"
            )
        if self.stacked and (x.ndim != 3 or x.shape[0] != self.num_seeds):
            raise ValueError(
                f"a policy of {self.num_seeds} stacked seeds takes observations "
                f"[{self.num_seeds}, N, {self.obs_dim or 'obs_dim'}], got shape {x.shape}"
            )
        return np.asarray(self._logits(x))

    def __call__(self, obs: np.ndarray) -> int | np.ndarray:
        actions = self.actions(obs, self.deterministic)
        return int(actions) if actions.ndim == 0 else actions

    def actions(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        """Actions (int64) for ``obs``: shape ``obs.shape[:-1]``; argmax when
        ``deterministic``, else sampled with :attr:`rng`."""
        logits = self.logits(obs)
        if not deterministic:  # Gumbel-max: argmax(logits + Gumbel noise) ~ softmax
            logits = logits + self.rng.gumbel(size=logits.shape)
        return np.asarray(np.argmax(logits, axis=-1), dtype=np.int64)

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """Stable-Baselines3's ``predict``, so the policy drops into code written for SB3
        (``evaluate_policy``, rl-zoo3's enjoy loop): ``(actions, state)``, where actions is an
        int64 array of shape ``observation.shape[:-1]`` (``()`` for one observation ``(4,)``,
        ``(N,)`` for a vectorized ``(N, 4)``) and ``state`` is returned as given (the policy
        has no recurrent state; ``episode_start`` is ignored for the same reason).
        ``deterministic`` is this call's choice, whatever the policy was loaded with.
        """
        return self.actions(observation, deterministic), state


def make_policy(
    params: dict,
    config: PPOConfig,
    stacked: bool = False,
    deterministic: bool = True,
    rng: np.random.Generator | int | None = None,
) -> Policy:
    """The :class:`Policy` of ``config``'s network with ``params``: the built-in MLP in NumPy,
    any other network through JAX; it takes observations of ``config.env``
    (:attr:`Policy.obs_dim` values, :attr:`Policy.env_id`)."""
    if config.network is None:
        params = networks.actor_params(jax.device_get(params))
    policy = Policy(params, config.network, config.activation, stacked, deterministic, rng)
    env = envs.make(config.env)
    policy.env_id, policy.obs_dim = env.id, env.obs_dim
    return policy


@dataclass(frozen=True)
class RunParams:
    """Every seed's parameters of one run directory (or one combination of a sweep)."""

    params: dict  # leaves [num_seeds, ...]
    config: PPOConfig
    num_seeds: int
    note: str | None = None
    """``from the checkpoint at iteration 12/40: the run did not finish`` when the parameters
    are not a finished run's; None for ``params.npz``."""
    env_params: EnvParams | None = None
    """The physics the run trained on (a randomised field: its nominal value), which its
    evaluation uses (:func:`jaxcart.rundir.reader.run_env_params`); None for an env without
    CartPole's physics (:func:`has_physics`), which plays on its own."""


def has_physics(env_id: str) -> bool:
    """Whether ``env_id``'s params are CartPole's :class:`EnvParams` (its
    :attr:`~jaxcart.core.envs.Env.default_params`): the physics ``--env-param`` and
    ``--sweep env.NAME`` set, and the env GIFs and the exports draw and declare.

    Raises:
        EnvError: an env this process cannot make (one line).
    """
    return isinstance(envs.make(env_id).default_params(), EnvParams)


def run_params(
    run_dir: str | os.PathLike,
    combination: int | None = None,
    policy: str = "final",
    network: type | None = None,
    trust_code: bool = False,
) -> RunParams:
    """Every seed's parameters of a run directory: ``params.npz`` when the run finished,
    else its checkpoint (:attr:`RunParams.note` says so). A sweep needs ``combination``
    (its ``combo-NNN/`` directory, or its runs in the sweep's checkpoint if unfinished).
    ``policy="best"`` takes each seed's best policy of the periodic evaluation instead
    (``params_best.npz``; a run trained with ``keep_best``). The directory is opened once
    and every file read through it. A run trained with its own network needs its class:
    ``network`` passed, or imported by its recorded name with ``trust_code``
    (:func:`~jaxcart.core.config.resolve_code`).

    Raises:
        RunDirError: not a run directory, nothing usable in it, or a bad ``combination``.
        ConfigError: the run's network is code not passed or trusted (one line naming both).
    """
    run_dir = Path(run_dir)
    with files.opened(run_dir) as directory:
        info = reader.read_run_config(directory)
        info["config"] = resolve_code(info["config"], network, trust_code, str(run_dir))
        combos = reader.recorded_combinations(info)
        sweep = reader.is_sweep(directory)
        if combos or sweep:
            if not reader.bounded_int(combination, 0, max(len(combos), 1) - 1):
                count, bounds = (f" of {len(combos)} combinations", f" in [0, {len(combos)})")
                raise RunDirError(
                    f"{run_dir} is a sweep{count if combos else ''}: choose a combination with "
                    f"combination=C (--combination C){bounds if combos else ''}, "
                    f"got {combination!r}"
                )
        elif combination is not None:
            raise RunDirError(f"{run_dir} is not a sweep; it has no combination {combination!r}")
        if not sweep:
            num_seeds, config = int(info.get("num_seeds", 1)), info["config"]
            physical = has_physics(config.env)
            try:  # the physics and config of the run, or of one combination of a sweep
                env = reader.run_env_params(info, combination) if physical else None
                if combination is not None:
                    config = reader.combo_config(config, combos[combination])
            except (ConfigError, TypeError, ValueError) as exc:
                what = "env_params" if combination is None else f"combination {combination}"
                raise RunDirError(f"{run_dir}: config.json {what} is unusable: {exc}") from None
            if not combos and files.present(directory / layout.PARAMS_FILE):
                params = reader.load_params(directory, policy, info)
                return RunParams(params, config, num_seeds, None, env)
            saved = read_checkpoint_runs(directory, info, policy)  # unfinished
            first = (combination or 0) * num_seeds
            params = jax.tree.map(lambda x: x[first : first + num_seeds], saved.params)
            return RunParams(params, config, num_seeds, saved.note, env)
    # a finished sweep: each combination is a run directory of its own (a link is refused)
    name = layout.combo_dir(".", int(combination)).name
    return run_params(files.subdir(run_dir, name), None, policy, network, trust_code)


def seed_params(
    trained: RunParams, seed_index: int | str, option: str = "seed_index", allow_all: bool = False
) -> dict:
    """One seed's parameters (no seed axis) of ``trained``.

    Raises:
        RunDirError: ``seed_index`` is not an integer in ``[0, num_seeds)`` (the message
            names it ``option``: ``--seed-index`` on a command line).
    """
    n = trained.num_seeds
    if not reader.bounded_int(seed_index, 0, n - 1):
        also = " or 'all'" if allow_all else ""
        raise RunDirError(
            f"{option} must be in [0, {n}){also} for this {n}-seed run, got {seed_index!r}"
        )
    return jax.tree.map(lambda x: np.asarray(x[seed_index]), trained.params)


def load_policy(
    run_dir: str | os.PathLike,
    seed_index: int | str = 0,
    combination: int | None = None,
    deterministic: bool = True,
    rng: np.random.Generator | int | None = None,
    policy: str = "final",
    network: type | None = None,
    trust_code: bool = False,
) -> Policy:
    """A policy of a trained run, usable in any Gymnasium loop.

    Args:
        run_dir: a run directory. One that did not finish gives the parameters of its last
            checkpoint, with a warning saying so (and ``policy.note``).
        seed_index: which seed, or ``"all"`` for every seed stacked (observations
            ``[S, N, obs_dim]`` -> actions ``[S, N]``).
        combination: a sweep's combination (required for a sweep directory).
        deterministic: argmax actions (as evaluated); False samples from the policy.
        rng: the NumPy ``Generator`` (or its seed) that samples when not ``deterministic``.
        policy: ``"final"`` (the parameters training ended with) or ``"best"`` (each seed's
            best by the periodic evaluation: a run trained with ``keep_best``).
        network: the ``flax.linen.Module`` subclass of a run trained with its own network,
            built with the fields the run recorded. Without it such a run is refused, unless
        trust_code: imports the network class the run names (its module's code runs); only a
            ``flax.linen.Module`` subclass is then built. Run directories from others: pass
            ``network`` instead.

    Returns:
        A callable mapping a float32 observation ``(obs_dim,)`` (CartPole's: 4) to an ``int``
        action, or ``(N, obs_dim)`` to ``(N,)`` actions (plain NumPy for the built-in MLP: no
        JAX call per step). Its parameters are the store's, checked against the run's network
        as they are read.

    Example::

        policy = jaxcart.load_policy("runs/my-run")
        obs, _ = env.reset()
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
    """
    trained = run_params(run_dir, combination, policy, network, trust_code)
    stacked = seed_index == "all"
    params = trained.params if stacked else seed_params(trained, seed_index, allow_all=True)
    policy = make_policy(params, trained.config, stacked, deterministic, rng)
    policy.env_params, policy.note = trained.env_params, trained.note
    if trained.note:
        warnings.warn(f"{run_dir}: parameters {trained.note}", UserWarning, stacklevel=2)
    return policy
