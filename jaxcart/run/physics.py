"""CartPole's physics as a user sets it: ``NAME=VALUE`` settings of
:class:`~jaxcart.core.cartpole.EnvParams` (``--env-param``), the randomisations
(``--randomize``) and their per-run values (NumPy, on the host), and a run's physics as a label.

What keeps params physical, and the JAX side of per-run and per-episode physics, are in core
(:mod:`jaxcart.core.physics`, :mod:`jaxcart.core.pytree`): a ``config.json`` read back is
checked as a new run's settings are. This module also names those, so the run's spec needs
one physics module.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from jaxcart.core.cartpole import EnvParams
from jaxcart.core.errors import ConfigError
from jaxcart.core.physics import (
    CONTINUOUS,
    FIELDS,
    PREFIX,
    check_continuous,
    check_physics,
    make_env_params,
    overrides,
    with_values,
)

_KINDS = {f.name: f.type for f in dataclasses.fields(EnvParams)}


def parse_value(name: str, text: str) -> Any:
    """``text`` as field ``name``'s type (float, int, bool or the integrator's string).

    Raises:
        ConfigError: not a field of CartPole's params, or not a value of its type.
    """
    if name not in FIELDS:
        raise ConfigError(f"CartPole has no env param {name!r}; choose one of: {', '.join(FIELDS)}")
    kind, text = str(_KINDS[name]), text.strip()
    try:
        if kind == "bool":
            if text.lower() not in ("true", "false", "on", "off", "1", "0"):
                raise ValueError
            return text.lower() in ("true", "on", "1")
        if kind == "int":
            value = float(text)
            if not value.is_integer():
                raise ValueError
            return int(value)
        if kind == "str":
            return text
        return float(text)
    except ValueError:
        raise ConfigError(f"env param {name}: {text!r} is not a {kind}") from None


def parse_env_params(specs: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """``["length=1.0", "masspole=0.2"]`` -> ``{"length": 1.0, "masspole": 0.2}``.

    Raises:
        ConfigError: malformed, unknown, repeated or of the wrong type.
    """
    values: dict[str, Any] = {}
    for spec in specs:
        name, sep, text = spec.partition("=")
        name = name.strip().replace("-", "_")
        if name.startswith(PREFIX):
            name = name[len(PREFIX) :]
        if not sep or not name or not text.strip():
            raise ConfigError(
                f"malformed --env-param {spec!r}; expected NAME=VALUE, e.g. length=1.0"
            )
        if name in values:
            raise ConfigError(f"--env-param {name} given twice; keep one")
        values[name] = parse_value(name, text)
    return values


@dataclass(frozen=True)
class Randomization:
    """A physics field drawn uniformly in ``[low, high]``: once per run (``per="run"``), from
    the run's base seed and seed index, or at every reset (``per="episode"``)."""

    name: str
    low: float
    high: float
    per: str = "run"

    def to_dict(self) -> dict:
        return {"low": self.low, "high": self.high, "per": self.per}


def parse_randomize(specs: list[str] | tuple[str, ...]) -> tuple[Randomization, ...]:
    """``["env.length=0.5:1.5", "env.masspole=0.05:0.2:episode"]`` -> randomisations.

    Raises:
        ConfigError: malformed, not a continuous physics field, ``low > high``, repeated.
    """
    out: dict[str, Randomization] = {}
    for spec in specs:
        name, sep, text = spec.partition("=")
        name = name.strip().replace("-", "_")
        parts = text.split(":")
        if not sep or not name.startswith(PREFIX) or len(parts) not in (2, 3):
            raise ConfigError(
                f"malformed --randomize {spec!r}; expected env.NAME=LOW:HIGH[:episode], "
                "e.g. env.length=0.5:1.5"
            )
        name = name[len(PREFIX) :]
        check_continuous(name, "--randomize")
        per = parts[2].strip() if len(parts) == 3 else "run"
        if per not in ("run", "episode"):
            raise ConfigError(f"--randomize {spec!r}: the third part must be run or episode")
        try:
            low, high = float(parts[0]), float(parts[1])
        except ValueError:
            raise ConfigError(f"--randomize {spec!r}: LOW and HIGH must be numbers") from None
        if not low <= high:
            raise ConfigError(f"--randomize env.{name}: low {low:g} is above high {high:g}")
        if name in out:
            raise ConfigError(f"--randomize env.{name} given twice; keep one")
        out[name] = Randomization(name, low, high, per)
    return tuple(out.values())


def randomized_values(
    randomize: tuple[Randomization, ...], seed: int, seed_indices: np.ndarray
) -> dict[str, np.ndarray]:
    """Each per-run randomisation's value for every run, float64 ``[R]``: uniform in
    ``[low, high]`` from ``default_rng([seed, seed_index, field number])``, so a seed index
    draws the same physics whatever runs beside it (a replay of one seed draws its own)."""
    values = {}
    for r in randomize:
        if r.per != "run":
            continue
        tag = FIELDS.index(r.name)
        values[r.name] = np.array(
            [
                np.random.default_rng([seed, int(i), tag]).uniform(r.low, r.high)
                for i in np.asarray(seed_indices)
            ],
            np.float64,
        )
    return values


def episode_ranges(randomize: tuple[Randomization, ...]) -> dict[str, tuple[float, float]]:
    """The per-episode randomisations as ``{name: (low, high)}`` (``{}`` when none)."""
    return {r.name: (r.low, r.high) for r in randomize if r.per == "episode"}


def describe(values: dict[str, Any]) -> str:
    """``length=1 masspole=0.2``: a run's physics as a label (``""`` for the defaults)."""
    return " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items())


__all__ = [
    "CONTINUOUS",
    "FIELDS",
    "PREFIX",
    "Randomization",
    "check_continuous",
    "check_physics",
    "describe",
    "episode_ranges",
    "make_env_params",
    "overrides",
    "parse_env_params",
    "parse_randomize",
    "parse_value",
    "randomized_values",
    "with_values",
]
