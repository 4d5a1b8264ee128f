"""Hyperparameter sweeps as one compiled program.

Every combination x seed is one run on the vmapped axis; the swept float hyperparameters
travel as arrays (:class:`~jaxcart.ppo.Hyperparams`), so the program compiles once whatever
the values. Run ``r`` is combination ``r // num_seeds`` with seed index ``r % num_seeds``;
all combinations share the seeds' random streams.
"""

from __future__ import annotations

import itertools
import math

import jax.numpy as jnp
import numpy as np

from jaxcart.config import TRACED_FIELDS, ConfigError, PPOConfig
from jaxcart.ppo import Hyperparams


def parse_sweep(specs: list[str]) -> dict[str, list[float]]:
    """``["learning_rate=1e-4,3e-4", "clip_coef=0.1,0.2"]`` -> ``{name: [values]}``.

    Raises:
        ConfigError: malformed spec, unknown or non-sweepable field, bad or repeated value.
    """
    sweep: dict[str, list[float]] = {}
    for spec in specs:
        name, sep, values = spec.partition("=")
        name = name.strip().replace("-", "_")
        if not sep or not name or not values.strip():
            raise ConfigError(
                f"malformed --sweep {spec!r}; expected NAME=V1,V2,... e.g. learning_rate=1e-4,3e-4"
            )
        if name not in TRACED_FIELDS:
            raise ConfigError(
                f"cannot sweep {name!r}: only float hyperparameters run in one program "
                f"({', '.join(TRACED_FIELDS)})"
            )
        if name in sweep:
            raise ConfigError(f"--sweep {name} given twice; put all its values in one option")
        try:
            parsed = [float(v) for v in values.split(",") if v.strip()]
        except ValueError:
            raise ConfigError(f"--sweep {name}: values must be numbers, got {values!r}") from None
        if not parsed or len(set(parsed)) != len(parsed):
            raise ConfigError(f"--sweep {name}: give distinct values, got {values!r}")
        sweep[name] = parsed
    return sweep


def combinations(sweep: dict[str, list[float]]) -> list[dict[str, float]]:
    """Every combination of the swept values, in ``itertools.product`` order."""
    names = list(sweep)
    return [dict(zip(names, values)) for values in itertools.product(*sweep.values())]


def validate_combinations(config: PPOConfig, combos: list[dict[str, float]]) -> list[PPOConfig]:
    """The config of each combination (validated: a bad value fails before compiling)."""
    out = []
    for combo in combos:
        try:
            out.append(PPOConfig(**{**config.to_dict(), **combo}))
        except ConfigError as exc:
            raise ConfigError(f"--sweep value out of range: {exc}") from None
    return out


def sweep_hyperparams(configs: list[PPOConfig], num_seeds: int) -> tuple[Hyperparams, np.ndarray]:
    """Hyperparameters of every run, leaves ``[C * S]``, and each run's seed index."""
    per_combo = [Hyperparams.from_config(c) for c in configs]
    hps = Hyperparams(
        **{
            name: jnp.repeat(jnp.stack([getattr(h, name) for h in per_combo]), num_seeds)
            for name in TRACED_FIELDS
        }
    )
    seed_indices = np.tile(np.arange(num_seeds), len(configs))
    return hps, seed_indices


def first_reach(returns: np.ndarray, env_steps: np.ndarray, target: float = 500.0) -> np.ndarray:
    """Env steps at which each run first reached ``target`` (pass ``rollout/ep_rew_max``: the
    iteration in which a training episode first scored 500).

    Args:
        returns: ``[iterations, R]``; env_steps: ``[iterations]``.

    Returns:
        ``[R]`` float, ``inf`` for runs that never reached it.
    """
    reached = np.nan_to_num(returns, nan=-np.inf) >= target
    first = np.where(reached.any(0), reached.argmax(0), -1)
    return np.where(first >= 0, env_steps[np.maximum(first, 0)], np.inf)


def rank(
    combos: list[dict[str, float]],
    solved: np.ndarray,
    final_return: np.ndarray,
    steps_to_500: np.ndarray,
    num_seeds: int,
    diverged_at: np.ndarray | None = None,
) -> list[dict]:
    """Per-combination summary sorted by solve rate, final return, then steps to 500.

    Args:
        solved, final_return, steps_to_500: per run, ``[C * S]``.
    """
    rows = []
    for c, combo in enumerate(combos):
        sl = slice(c * num_seeds, (c + 1) * num_seeds)
        steps = steps_to_500[sl]
        rows.append(
            {
                "combination": c,
                **combo,
                "solve_rate": float(np.mean(solved[sl])),
                "final_return": float(np.nanmean(final_return[sl]))
                if np.isfinite(final_return[sl]).any()
                else math.nan,
                "median_steps_to_500": float(np.median(steps)),
                "seeds_reaching_500": int(np.isfinite(steps).sum()),
                "seeds_diverged": 0 if diverged_at is None else int((diverged_at[sl] >= 0).sum()),
            }
        )
    return sorted(
        rows,
        key=lambda r: (
            -r["solve_rate"],
            -np.nan_to_num(r["final_return"], nan=-1.0),
            r["median_steps_to_500"],
        ),
    )
