"""CartPole's physics settings, in one module: the fields of
:class:`~jaxcart.core.cartpole.EnvParams` a user sets (``--env-param``, read by
:func:`jaxcart.run.spec.parse_env_params`), the randomisations of ``--randomize``
(:class:`Randomization`) and their per-run values (NumPy, on the host); the checks that keep
``EnvParams`` physical (for a new run's settings and for a ``config.json`` read back alike);
and the JAX side of physics drawn per episode (:class:`EpisodeState`, :func:`step_batch`).

A value given for every run is a Python number on ``EnvParams``: it is a constant of the
compiled program, exactly as the defaults are. Only a field that differs between runs travels
as an array ``[R]`` (:func:`~jaxcart.core.pytree.split_per_run`), so a run that sweeps and
randomises nothing compiles the very program it always did.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxcart.core import cartpole, pytree
from jaxcart.core.cartpole import EnvParams
from jaxcart.core.errors import ConfigError

FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(EnvParams))
"""Every field of :class:`EnvParams`, the names ``--env-param`` takes."""

CONTINUOUS: tuple[str, ...] = pytree.per_run_names(EnvParams())
"""The float fields that may differ between runs (``--sweep env.NAME``, ``--randomize``)."""

PREFIX = "env."
"""How a sweep or a randomisation names a physics field: ``env.length``."""


def check_physics(params: EnvParams, dtype: np.dtype | None = None) -> None:
    """Raises :class:`ConfigError` (one line) for params outside physical sense: masses,
    length, ``tau`` and thresholds must be positive, gravity and the force not negative,
    every number finite, the episode limit a positive integer and the reset bounds ordered.
    Numbers are checked in the float type the env runs in (``dtype``, default
    :func:`~jaxcart.core.pytree.float_dtype`: float32, float64 under x64), and so are the
    quantities the step derives from them alone (total mass, pole mass x length, the pole's
    angular acceleration when pushed from rest): a value that overflows there, or a positive
    one that rounds to 0, would make every run diverge at its first iteration.
    Fields may hold arrays (one value per run); every value is checked."""
    dtype = np.dtype(pytree.float_dtype() if dtype is None else dtype)  # starts no backend
    positive = ("masscart", "masspole", "length", "tau", "x_threshold", "theta_threshold_radians")
    ran: dict[str, np.ndarray] = {}  # each number as the env holds it
    for name in (*positive, "gravity", "force_mag", "reset_low", "reset_high"):
        value = np.asarray(getattr(params, name), np.float64)
        with np.errstate(over="ignore"):  # an overflow is what is checked
            ran[name] = value.astype(dtype)
        if not np.all(np.isfinite(ran[name])):
            raise ConfigError(
                f"env param {name} must be a finite number (in {dtype}, as the env runs), "
                f"got {_shown(value)}"
            )
        if name in positive and np.any(ran[name] <= 0):
            raise ConfigError(f"env param {name} must be > 0 (in {dtype}), got {_shown(value)}")
        if name in ("gravity", "force_mag") and np.any(value < 0):
            raise ConfigError(f"env param {name} must be >= 0, got {_shown(value)}")
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        total_mass = ran["masspole"] + ran["masscart"]
        derived = {
            "total mass": total_mass,
            "pole mass x length": ran["masspole"] * ran["length"],
            "pole's angular acceleration from rest": ran["force_mag"]
            / total_mass
            / (ran["length"] * (dtype.type(4 / 3) - ran["masspole"] / total_mass)),
        }
    for what, value in derived.items():
        if not np.all(np.isfinite(value)):
            raise ConfigError(
                f"env params give a {what} that overflows {dtype}, the float type the env "
                "runs in; choose values of a more moderate size"
            )
    steps = params.max_episode_steps
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps <= 0:
        raise ConfigError(f"env param max_episode_steps must be a positive integer, got {steps!r}")
    if not isinstance(params.sutton_barto_reward, (bool, np.bool_)):
        raise ConfigError(
            f"env param sutton_barto_reward must be true or false, got {params.sutton_barto_reward!r}"
        )
    if not params.reset_low < params.reset_high:
        raise ConfigError(
            f"env params reset_low={params.reset_low:g} must be below reset_high="
            f"{params.reset_high:g}"
        )


def _shown(value: np.ndarray) -> str:
    bad = value.reshape(-1)
    return f"{bad[0]:g}" if bad.size == 1 else f"values down to {np.nanmin(bad):g}"


def make_env_params(values: dict[str, Any], dtype: np.dtype | None = None) -> EnvParams:
    """:class:`EnvParams` with ``values`` over the defaults, checked (in ``dtype``, as
    :func:`check_physics`).

    Raises:
        ConfigError: an unknown field, a wrong type or a value outside sense.
    """
    unknown = sorted(set(values) - set(FIELDS))
    if unknown:
        raise ConfigError(
            f"CartPole has no env param {unknown[0]!r}; choose one of: {', '.join(FIELDS)}"
        )
    try:
        params = EnvParams(**values)
    except ValueError as exc:  # the integrator's own check
        raise ConfigError(f"env param {exc}") from None
    check_physics(params, dtype)
    return params


def overrides(params: EnvParams) -> dict[str, Any]:
    """The fields of ``params`` that differ from CartPole-v1's (what ``config.json`` records:
    nothing for the default physics, so older runs read the same)."""
    default = EnvParams()
    return {
        name: getattr(params, name)
        for name in FIELDS
        if getattr(params, name) != getattr(default, name)
    }


def check_continuous(name: str, option: str) -> None:
    """Raises :class:`ConfigError` unless ``name`` is a field that may differ between runs."""
    if name in FIELDS and name not in CONTINUOUS:
        raise ConfigError(
            f"{option} env.{name}: only continuous physics fields vary between runs "
            f"({', '.join(CONTINUOUS)}); set {name} for all runs with --env-param"
        )
    if name not in FIELDS:
        raise ConfigError(
            f"{option} env.{name}: CartPole has no env param {name!r}; choose one of: "
            f"{', '.join(CONTINUOUS)}"
        )


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

    @property
    def option(self) -> str:
        """As ``--randomize`` takes it (:func:`jaxcart.run.spec.parse_randomize`): ``env.NAME=LOW:HIGH:PER``."""
        return f"{PREFIX}{self.name}={self.low!r}:{self.high!r}:{self.per}"


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


def describe(values: dict[str, Any]) -> str:
    """``length=1 masspole=0.2``: a run's physics as a label (``""`` for the defaults)."""
    return " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in values.items())


@pytree.dataclass
class EpisodeState:
    """The env state of envs whose physics are drawn anew at every reset: CartPole's state,
    each drawn field's value in the current episode, and the range it is drawn from (all
    ``[num_envs]``, so the draw needs nothing static and a checkpoint holds it all)."""

    env: Any
    values: dict[str, jax.Array]
    low: dict[str, jax.Array]
    high: dict[str, jax.Array]


def episode_state(
    env: Any,
    values: dict[str, np.ndarray],
    ranges: dict[str, tuple[float, float]],
    dtype: np.dtype,
) -> EpisodeState:
    """An :class:`EpisodeState` around ``env`` (NumPy fields ``[..., num_envs]``) whose first
    episodes have ``values`` (of the same shape) and draw later ones from ``ranges``, all in
    ``dtype`` (the observations')."""
    shape = np.shape(next(iter(values.values())))
    low = {n: np.full(shape, lo, dtype) for n, (lo, _) in ranges.items()}
    high = {n: np.full(shape, hi, dtype) for n, (_, hi) in ranges.items()}
    return EpisodeState(env, {n: np.asarray(values[n], dtype) for n in ranges}, low, high)


def step_batch(
    key: jax.Array, state: Any, action: jax.Array, params: EnvParams
) -> tuple[jax.Array, Any, jax.Array, jax.Array, jax.Array, dict]:
    """:func:`jaxcart.core.cartpole.step_batch`, itself for an :class:`EnvState`. For an
    :class:`EpisodeState`, each env steps with its episode's physics, and an env whose
    episode ends draws its next episode's values uniformly in their ranges, from ``key`` (the
    key its reset state is drawn from, folded with the field's number)."""
    if not isinstance(state, EpisodeState):
        return cartpole.step_batch(key, state, action, params)
    stepped = cartpole.step_batch(key, state.env, action, params.replace(**state.values))
    obs, env, reward, terminated, truncated, info = stepped
    done = terminated | truncated
    values = {}
    for name, value in state.values.items():
        unit = cartpole.hash_uniform(
            jax.random.fold_in(key, FIELDS.index(name) + 1), done.shape, value.dtype
        )
        drawn = state.low[name] + (state.high[name] - state.low[name]) * unit
        values[name] = jnp.where(done, drawn, value)
    return obs, state.replace(env=env, values=values), reward, terminated, truncated, info
