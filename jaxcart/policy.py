"""Trained policies as plain NumPy callables, for any Gymnasium loop (no JAX call per step)."""

from __future__ import annotations

import os

import jax
import numpy as np

from jaxcart import networks, rundir
from jaxcart.files import RunDirError


class NumpyPolicy:
    """Greedy actor in plain NumPy, for one or a stack of seeds.

    ``actor`` holds the actor's layers (:func:`jaxcart.networks.actor_params`), with a leading
    seed axis ``[S, ...]`` on every array when ``stacked``. Calling it on float32 observations
    returns argmax actions: ``(4,) -> int``, ``(N, 4) -> (N,)``, and when stacked
    ``(S, N, 4) -> (S, N)``.
    """

    def __init__(self, actor: dict, activation: str, stacked: bool = False) -> None:
        def layer(p: dict) -> dict:
            kernel, bias = np.asarray(p["kernel"], np.float32), np.asarray(p["bias"], np.float32)
            # stacked: bias [S, out] -> [S, 1, out] broadcasts over the N observations
            return {"kernel": kernel, "bias": bias[:, None, :] if stacked else bias}

        self.actor = {name: layer(p) for name, p in actor.items()}
        self.activation = activation
        self.stacked = stacked

    def logits(self, obs: np.ndarray) -> np.ndarray:
        """Policy logits for ``obs`` (any leading shape matching the stacking)."""
        x = np.asarray(obs, np.float32)
        if x.shape[-1] != 4:
            raise ValueError(
                f"expected observations with 4 values in the last axis, got shape {x.shape}"
            )
        return networks.mlp(self.actor, x, self.activation, xp=np)

    def __call__(self, obs: np.ndarray) -> int | np.ndarray:
        actions = np.argmax(self.logits(obs), axis=-1)
        return int(actions) if actions.ndim == 0 else actions


def numpy_policy(params: dict, activation: str, stacked: bool = False) -> NumpyPolicy:
    """A :class:`NumpyPolicy` from network parameters (a leading seed axis when ``stacked``)."""
    return NumpyPolicy(networks.actor_params(jax.device_get(params)), activation, stacked)


def load_policy(run_dir: str | os.PathLike, seed_index: int = 0) -> NumpyPolicy:
    """A greedy policy of one trained seed, usable in any Gymnasium loop.

    Returns:
        A callable mapping a float32 observation ``(4,)`` to an ``int`` action, or ``(N, 4)``
        to ``(N,)`` actions (plain NumPy; no JAX call per step).

    Example::

        policy = jaxcart.load_policy("runs/my-run")
        obs, _ = env.reset()
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
    """
    info = rundir.read_run_config(run_dir)
    params = rundir.load_params(run_dir)
    num_seeds = int(info.get("num_seeds", 1))
    if (
        isinstance(seed_index, bool)
        or not isinstance(seed_index, (int, np.integer))
        or not 0 <= seed_index < num_seeds
    ):
        raise RunDirError(f"seed_index must be an integer in [0, {num_seeds}), got {seed_index!r}")
    one = jax.tree.map(lambda x: x[seed_index], params)
    try:
        return numpy_policy(one, info["config"].activation)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise RunDirError(f"{run_dir} does not hold an actor network: {exc}") from None
