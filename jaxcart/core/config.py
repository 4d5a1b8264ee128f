"""PPO configuration: one frozen, validated dataclass with a docstring per field, and presets.

:class:`PPOConfig` is also a JAX pytree. Each field is declared once, traced or static:

- a field declared with :func:`traced` (a float hyperparameter such as ``learning_rate``) is a
  leaf. The compiled program receives it as an array: changing it never recompiles, and a sweep
  over it is one vmap axis (leaves ``[R]``, one value per run: :meth:`PPOConfig.per_run`);
- every other field (shapes, switches) is static: part of the pytree's structure, so the
  compiled program is specialised to it and JAX compiles anew when it changes.

The program reads the one config it is given; there is no second copy with other values.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import jax
import numpy as np

from jaxcart.core import envs
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.errors import ConfigError
from jaxcart.core.metrics import EVAL_METRICS, METRIC_NAMES
from jaxcart.core.pytree import float_dtype

BOUNDS = {
    "> 0": lambda v: v > 0,
    "in (0, 1]": lambda v: (v > 0) & (v <= 1),
    ">= 0": lambda v: v >= 0,
}
"""What a traced field may hold (:func:`validate` names the bound), and the test of it."""


def traced(default: float, bound: str = "> 0") -> Any:
    """Declares a float hyperparameter that travels through the compiled program as an array
    (a pytree leaf of :class:`PPOConfig`): a Python float, or one float32 value per run, each
    finite and within ``bound`` (a key of :data:`BOUNDS`)."""
    return field(default=default, metadata={"traced": True, "bound": bound})


def setting(default: Any, **meta: Any) -> Any:
    """Declares a static field once, with what :func:`validate`, :meth:`PPOConfig.to_dict` and
    the command line read of it besides its type (an ``int`` field is a positive integer, a
    ``bool`` one true or false): ``choices`` (the values a string takes), ``minimum`` and
    ``maximum`` (an integer's least and greatest values), ``bound`` (a number's, a key of
    :data:`BOUNDS`; None passes when it is the default), ``new`` (added after the first
    config.json: left out of it at its default, or while the field it names is off, so that
    older runs read as they did) and ``cli=False`` (Python API only)."""
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class PPOConfig:
    """Hyperparameters of PPO on CartPole-v1. Defaults are Stable-Baselines3's.

    A traced field holds a Python float for one setting, or an array ``[R]`` with one value
    per run (:meth:`per_run`; a sweep). Inside the compiled program traced fields are tracers
    and static fields are Python values.
    """

    num_envs: int = 1
    """Parallel environments per run (SB3: n_envs)."""
    num_steps: int = 2048
    """Steps collected per environment per iteration (SB3: n_steps)."""
    total_timesteps: int = 80_000
    """Environment steps per run, rounded up to whole iterations of num_envs x num_steps."""
    minibatch_size: int = 64
    """Transitions per gradient step (SB3: batch_size); must divide num_envs x num_steps."""
    update_epochs: int = 10
    """Passes over each rollout per iteration (SB3: n_epochs)."""
    learning_rate: float = traced(3e-4)
    """Adam step size (initial value when anneal_lr is on)."""
    anneal_lr: bool = False
    """Decay the learning rate linearly to 0 over the iterations (as PureJaxRL/CleanRL do;
    SB3's lin_X with anneal_progress sb3)."""
    anneal_clip: bool = setting(False, new=True)
    """Decay clip_coef linearly to 0 as anneal_lr does the learning rate (rl-zoo3's lin_X
    clip_range)."""
    anneal_progress: str = setting("start", choices=("start", "sb3"), new=True)
    """What an annealed rate measures in iteration i (from 0): start (i / num_iterations, as
    PureJaxRL/CleanRL do) or sb3 (SB3's progress_remaining, updated after the rollout: 1 -
    (i + 1) x num_envs x num_steps / total_timesteps, one iteration ahead)."""
    adam_eps: float = traced(1e-5)
    """Adam epsilon."""
    gamma: float = traced(0.99, "in (0, 1]")
    """Discount factor, in (0, 1]."""
    gae_lambda: float = traced(0.95, "in (0, 1]")
    """GAE lambda, in (0, 1]."""
    clip_coef: float = traced(0.2)
    """PPO ratio clip range epsilon (SB3: clip_range)."""
    clip_range_vf: float = traced(0.2)
    """Value clip range, used when value_clip is sb3 or purejaxrl (SB3: clip_range_vf)."""
    ent_coef: float = traced(0.0, ">= 0")
    """Entropy bonus coefficient."""
    vf_coef: float = traced(0.5, ">= 0")
    """Value loss coefficient."""
    max_grad_norm: float = traced(0.5)
    """Global gradient-norm clip."""
    norm_adv: bool = True
    """Normalise advantages per minibatch (mean 0, std 1)."""
    adv_std: str = setting("sample", choices=("sample", "population"))
    """The std that normalises advantages: sample (ddof 1, as SB3's torch) or population
    (ddof 0, as PureJaxRL's jnp.std)."""
    value_clip: str = setting("off", choices=("off", "sb3", "purejaxrl"))
    """Value-loss clipping: off (SB3's default, plain MSE), sb3 (the prediction clipped to
    within clip_range_vf of its value at collection, then MSE) or purejaxrl (half the mean of
    the larger of the clipped and unclipped squared errors)."""
    target_kl: float | None = setting(None, bound="> 0")
    """Stop an iteration's epochs at the first minibatch whose approx KL exceeds 1.5 x
    target_kl, before its gradient step (SB3's rule); none: never."""
    bootstrap_truncation: bool = True
    """Bootstrap from V(final_obs) at time-limit truncations; off treats them as terminations."""
    hidden_sizes: tuple[int, ...] = (64, 64)
    """Hidden layer widths of both the actor and the critic MLP, e.g. 64,64."""
    activation: str = setting("tanh", choices=("tanh", "relu"))
    """Hidden activation: tanh or relu."""
    linear_actor: bool = False
    """A linear policy, softmax(W obs + b): the actor has no hidden layers (the critic keeps
    hidden_sizes)."""
    weight_init: str = setting("orthogonal", choices=("orthogonal", "default"))
    """Weight initialisation: orthogonal (SB3: gains sqrt(2), 0.01 for the policy head, 1 for
    the value head, zero biases) or default (PyTorch's nn.Linear: weights and biases uniform in
    +-1/sqrt(fan_in))."""
    env: str = setting(DEFAULT_ENV, new=True)
    """The environment: CartPole-v1 (jaxcart's own), or Acrobot-v1 or MountainCar-v0 (gymnax's,
    pip install -e '.[gymnax]'); judged in Gymnasium's env of the same id."""
    network: Any = field(default=None, metadata={"cli": False})
    """The actor-critic, a flax module mapping observations [..., obs_dim] to (logits [...,
    num_actions], value [...]); None: the built-in SB3 MLP that hidden_sizes, activation,
    linear_actor and weight_init describe. Python API only: a run directory records its
    importable class and fields, and rebuilds it from them."""
    eval_every: int = setting(0, minimum=0, new=True)
    """Every N iterations, play periodic_eval_episodes greedy episodes in jaxcart's env inside
    the compiled program, from the same start states for every run (eval/mean_return and
    eval/min_return); 0: never."""
    periodic_eval_episodes: int = setting(10, maximum=1024, new="eval_every")
    """Greedy episodes of each evaluation during training (with eval_every)."""
    keep_best: bool = setting(False, new="eval_every")
    """Keep each run's policy with the best eval/mean_return so far (ties: the later one) as
    params_best.npz beside params.npz; needs eval_every."""
    metrics: Any = field(default=(), metadata={"cli": False})
    """Your own per-iteration metrics: a mapping name -> fn, each fn(rollout, batch, losses)
    returning a scalar, computed inside the compiled program after the update (kept as a
    tuple of (name, fn) pairs). They join metrics.csv, the loggers and plot. Python API only:
    a run directory records their names and importable functions."""

    def __post_init__(self) -> None:
        if isinstance(self.metrics, Mapping):  # a dict is not hashable: the pytree needs it so
            object.__setattr__(self, "metrics", tuple(self.metrics.items()))
        validate(self)

    @property
    def batch_size(self) -> int:
        """Transitions per iteration: num_envs x num_steps."""
        return self.num_envs * self.num_steps

    @property
    def num_minibatches(self) -> int:
        """Gradient steps per epoch."""
        return self.batch_size // self.minibatch_size

    @property
    def num_iterations(self) -> int:
        """Iterations per run: total_timesteps rounded up to whole rollouts."""
        return math.ceil(self.total_timesteps / self.batch_size)

    @property
    def env_steps_per_seed(self) -> int:
        """Environment steps actually taken per run (total_timesteps rounded up)."""
        return self.num_iterations * self.batch_size

    def per_run(self, num_runs: int) -> PPOConfig:
        """This config with every traced field as :func:`float_dtype` ``[num_runs]`` (float32;
        float64 under ``JAX_ENABLE_X64``): a scalar repeated for every run, an array of one
        value per run kept (the form the compiled program takes).

        Raises:
            ConfigError: a traced field holds an array of another length.
        """
        values, dtype = {}, float_dtype()
        for name in TRACED_FIELDS:
            value = np.asarray(getattr(self, name), dtype)
            if value.ndim == 0:
                value = np.full((num_runs,), value, dtype)
            elif value.shape != (num_runs,):
                raise ConfigError(
                    f"{name} holds {value.shape[0]} values, one per run; expected {num_runs}",
                    name,
                )
            values[name] = value
        return _replace_unchecked(self, values)

    @property
    def metric_names(self) -> tuple[str, ...]:
        """The names of :attr:`metrics`, in order (the extra columns of metrics.csv)."""
        return tuple(name for name, _ in self.metrics)

    @property
    def extra_metric_names(self) -> tuple[str, ...]:
        """The columns beyond the built-in ones: the periodic evaluation's (with eval_every),
        then :attr:`metric_names`."""
        evaluation = EVAL_METRICS if self.eval_every else ()
        return (*evaluation, *self.metric_names)

    @property
    def is_per_run(self) -> bool:
        """Whether any traced field holds one value per run (an array) instead of a float."""
        return any(np.ndim(getattr(self, name)) for name in TRACED_FIELDS)

    def to_dict(self) -> dict:
        """Plain dict of the fields (tuples become lists when dumped to JSON; a per-run
        field is refused: write each run's config, or the sweep, instead). A custom
        ``network`` is written as :func:`network_spec`; the built-in one (None) is left out.

        Raises:
            ConfigError: a network that cannot be recorded (see :func:`network_spec`).
        """
        if self.is_per_run:
            raise ValueError("a per-run config has no single dict; use to_dict() of each run's")
        data = {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if f.metadata.get("cli", True) and not self._left_out(f)
        }
        if self.network is not None:
            data["network"] = network_spec(self.network)
            for name in BUILTIN_NETWORK_FIELDS:  # they describe a network this run does not use
                del data[name]
        if self.metrics:
            data["metrics"] = {name: function_path(fn) for name, fn in self.metrics}
        return data

    def _left_out(self, f: dataclasses.Field) -> bool:
        """Whether :meth:`to_dict` leaves out a field added after the first config.json: at
        its default, or while the field its ``new`` names is off (so older runs read the same)."""
        new = f.metadata.get("new")
        if isinstance(new, str):
            return not getattr(self, new)
        return bool(new) and getattr(self, f.name) == f.default

    @classmethod
    def from_dict(cls, data: dict) -> PPOConfig:
        """Inverse of :meth:`to_dict`; rejects unknown keys with a :class:`ConfigError`.

        Nothing is imported: a recorded network stays data and recorded metrics keep their
        names but not their functions (:class:`RecordedCode`).
        Readers need neither; running the policy or training needs the code, which
        :func:`resolve_code` brings in only when the caller passes it or opts in."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(f"unknown config field(s): {', '.join(unknown)}")
        data = dict(data)
        if isinstance(data.get("hidden_sizes"), list):  # JSON's array; validate checks it
            data["hidden_sizes"] = tuple(data["hidden_sizes"])
        if data.get("network") is not None:
            data["network"] = RecordedCode.from_spec(data["network"])
        if "metrics" in data:
            recorded = data["metrics"]
            if not isinstance(recorded, dict) or not all(
                isinstance(v, str) for v in recorded.values()
            ):
                raise ConfigError(f"metrics must map names to 'module:function', got {recorded!r}")
            data["metrics"] = {name: RecordedCode(path) for name, path in recorded.items()}
        return cls(**data)


def network_spec(network: Any) -> dict:
    """How a run directory records a network: its class as ``"module:QualName"`` and the
    dataclass fields (a flax module is a dataclass) that differ from the class's defaults.

    A class defined in ``__main__`` (a script or a notebook) is recorded too: the same
    process rebuilds it, another one refuses in one line (:meth:`RecordedCode.build`).

    Raises:
        ConfigError: a field set to something other than its default is not a JSON value.
    """
    if isinstance(network, RecordedCode):  # as it was read
        return network.spec()
    cls = type(network)
    where = f"{cls.__module__}:{cls.__qualname__}"
    fields = {}
    for f in dataclasses.fields(network):
        if f.name in ("parent", "name") or not f.init:
            continue
        value = getattr(network, f.name)
        if f.default is not dataclasses.MISSING and _same(value, f.default):
            continue
        value = list(value) if isinstance(value, tuple) else value
        if not _is_json(value):
            raise ConfigError(
                f"network field {f.name}={value!r} of {where} is not a JSON value, so a run "
                "directory cannot record it; make it the class's default or a JSON value"
            )
        fields[f.name] = value
    return {"class": where, "fields": fields}


def _same(value: Any, default: Any) -> bool:
    try:
        return bool(value is default or value == default)
    except Exception:  # an array or another type without a truth value
        return False


class RebuildError(ConfigError):
    """A run's network class or metric function, recorded as ``module:name``, cannot be
    imported or built in this process: the run directory is sound, its code is out of reach."""


class UntrustedCodeError(RebuildError):
    """A run directory names code (a network class, metric functions) that the caller did
    not pass and did not opt in to import: nothing from the directory runs unless asked."""


@dataclass(frozen=True)
class RecordedCode:
    """A run's own code as its directory records it, not imported: a network class or a
    metric function as ``"module:QualName"`` (``path``), with a network's fields as canonical
    JSON (``fields_json``; None for a function). Readers (plots, comparisons) need no more;
    :func:`resolve_code` imports it (:meth:`build`) when the policy must run or train."""

    path: str
    fields_json: str | None = None

    @classmethod
    def from_spec(cls, spec: Any) -> RecordedCode:
        """A network from what :func:`network_spec` wrote, its shape checked; imports nothing.

        Raises:
            ConfigError: not ``{"class": "module:Name", "fields": {JSON}}``.
        """
        fields = spec.get("fields") or {} if isinstance(spec, dict) else None
        path = spec.get("class") if isinstance(spec, dict) else None
        module, _, name = path.partition(":") if isinstance(path, str) else ("", "", "")
        if (
            not module
            or not name
            or not isinstance(fields, dict)
            or not _is_json(fields)
            or set(spec) - {"class", "fields"}
        ):
            raise ConfigError(
                f"network must be a recorded network ({{'class': 'module:Name', 'fields': "
                f"{{...}}}}), got {spec!r:.200}"
            )
        return cls(path, json.dumps(fields, sort_keys=True))

    def spec(self) -> dict:
        """A network's ``{"class", "fields"}`` object, as it was read."""
        return {"class": self.path, "fields": json.loads(self.fields_json)}

    def build(self, code: Any = None) -> Any:
        """The code: ``code`` (a class the caller passed), else the object :attr:`path` names,
        imported. A function must be callable; a network's class must be a
        ``flax.linen.Module`` subclass, checked before it is called with the recorded fields
        (lists become tuples). One of a script, a notebook or a function's body
        (``__main__``, ``<locals>``, ``<lambda>``) is not imported.

        Raises:
            RebuildError: it cannot be imported or built, saying why.
        """
        import importlib

        network = self.fields_json is not None
        where = (
            f"cannot rebuild the run's {'network' if network else 'metric function'} {self.path}"
        )
        module, _, name = self.path.partition(":")
        if code is None and (module == "__main__" or "<locals>" in name or "<lambda>" in name):
            if network:
                raise RebuildError(
                    f"{where}: a class defined in a script or notebook can only be rebuilt "
                    "there; pass it (network=...) or define it in an importable module"
                )
            raise RebuildError(f"{where}: define it at the top level of an importable module")
        try:
            if code is None:  # exactly "module:Name": the module, then the names in it
                code = importlib.import_module(module)
                for part in name.split("."):
                    code = getattr(code, part)
        except Exception as exc:  # someone else's module, imported by name on request
            hint = (
                " (run from the folder the run was trained in, or add the module's folder to "
                "PYTHONPATH)"
                if isinstance(exc, ModuleNotFoundError)
                else ""
            )
            raise RebuildError(f"{where}: {type(exc).__name__}: {exc}{hint}") from None
        if not network:
            if not callable(code):
                raise RebuildError(f"{where}: not callable")
            return code
        import flax.linen as nn

        if not (isinstance(code, type) and issubclass(code, nn.Module)):
            raise RebuildError(f"{where}: {code!r:.80} is not a flax.linen.Module subclass")
        fields = json.loads(self.fields_json)
        try:
            return code(**{k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()})
        except Exception as exc:  # a constructor of someone else's code
            raise RebuildError(f"{where}: {type(exc).__name__}: {exc}") from None

    def __call__(self, *args: Any) -> Any:
        raise ConfigError(f"the run's metric function {self.path} was not imported")

    def __repr__(self) -> str:
        return f"RecordedCode({self.path})"


RecordedNetwork = RecordedMetric = RecordedCode
"""What a run directory records of a network class and of a metric function: one kind."""


def recorded_code(config: PPOConfig) -> list[str]:
    """What of ``config`` is code named by a run directory and not yet imported:
    ``module:Name`` of its network and of each metric function."""
    code = (config.network, *(fn for _, fn in config.metrics))
    return [c.path for c in code if isinstance(c, RecordedCode)]


def untrusted_code(paths: list[str], where: str = "") -> UntrustedCodeError:
    """The one-line refusal to run ``paths`` (``module:Name``) that a run directory names."""
    return UntrustedCodeError(
        f"{where}{': ' if where else ''}the run was trained with code of its own "
        f"({', '.join(paths)}), and a run directory runs no code unless you say so: pass "
        "the network class (network=MyNet in Python) or opt in to import it with "
        "--trust-code (trust_code=True)"
    )


def resolve_code(
    config: PPOConfig, network: type | None = None, trust_code: bool = False, where: str = ""
) -> PPOConfig:
    """``config`` ready to run: a recorded network built from ``network`` (the class, passed
    by the caller) or, with ``trust_code``, imported by its recorded name; recorded metric
    functions imported with ``trust_code`` (a resume). A config that names no code is
    returned as is.

    Raises:
        UntrustedCodeError: the run names code and the caller neither passed it nor opted
            in; the message names both ways in.
        RebuildError: the code cannot be imported or built (:meth:`RecordedCode.build`).
    """
    passed = getattr(config.network, "path", None) if network is not None else None
    needs_import = [path for path in recorded_code(config) if path != passed]
    if needs_import and not trust_code:
        raise untrusted_code(needs_import, where)
    built = {"network": build_code(config.network, network)}  # the network first, as ever
    built["metrics"] = tuple((name, build_code(fn)) for name, fn in config.metrics)
    return _replace_unchecked(config, built)


def build_code(code: Any, cls: type | None = None) -> Any:
    """``code`` built if it is recorded (:meth:`RecordedCode.build`), else as it is."""
    return code.build(cls) if isinstance(code, RecordedCode) else code


def function_path(fn: Any) -> str:
    """How a run directory records a metric function: ``"module:QualName"``."""
    if isinstance(fn, RecordedCode):
        return fn.path
    return f"{getattr(fn, '__module__', None)}:{getattr(fn, '__qualname__', type(fn).__name__)}"


def _is_json(value: Any) -> bool:
    if value is None or isinstance(value, (bool, int, float, str)):
        return True
    if isinstance(value, list):
        return all(_is_json(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and _is_json(v) for k, v in value.items())
    return False


BUILTIN_NETWORK_FIELDS = ("hidden_sizes", "activation", "linear_actor", "weight_init")
"""The fields that describe the built-in MLP: a run with its own ``network`` leaves them out
of config.json (a run directory written before may hold them; they are read as ever)."""


TRACED_FIELDS: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(PPOConfig) if f.metadata.get("traced")
)
"""The fields declared with :func:`traced`, in declaration order: the pytree's leaves."""
STATIC_FIELDS: tuple[str, ...] = tuple(
    f.name for f in dataclasses.fields(PPOConfig) if not f.metadata.get("traced")
)
"""Every other field, in declaration order: the pytree's structure."""


def _replace_unchecked(config: PPOConfig | None, values: dict[str, Any]) -> PPOConfig:
    """``dataclasses.replace`` without ``__init__``'s validation: for JAX's unflattening (the
    leaves may be tracers or placeholders; ``config`` None: every field is in ``values``) and
    for values already checked."""
    new = object.__new__(PPOConfig)
    for f in dataclasses.fields(PPOConfig):
        object.__setattr__(new, f.name, values.get(f.name, getattr(config, f.name, None)))
    return new


def _flatten(config: PPOConfig) -> tuple[list, tuple]:
    leaves = [(jax.tree_util.GetAttrKey(n), getattr(config, n)) for n in TRACED_FIELDS]
    return leaves, tuple(getattr(config, n) for n in STATIC_FIELDS)


def _unflatten(static: tuple, leaves: list) -> PPOConfig:
    values = {**dict(zip(STATIC_FIELDS, static)), **dict(zip(TRACED_FIELDS, leaves))}
    return _replace_unchecked(None, values)


jax.tree_util.register_pytree_with_keys(PPOConfig, _flatten, _unflatten)


MAX_WEIGHTS = 1 << 26
"""Weights per MLP (64 M): far above any CartPole network, a bound for untrusted configs."""
MAX_BATCH = 1 << 24
"""Transitions per iteration: the minibatch shuffle packs an index into 24 bits."""
MAX_ITERATIONS = 2**31 - 1
"""Iterations per run: the chunk loop counts them in int32 (a new run and a resumed
``config.json`` are held to it alike)."""


def _is_number(value: Any) -> bool:
    """Whether ``value`` is a real number, or a 1-d array of them, every one finite (a bool is
    none: NumPy's bool is no ``np.number``)."""
    return (
        isinstance(value, (int, float, np.ndarray, jax.Array, np.number))
        and np.ndim(value) <= 1
        and np.issubdtype(np.asarray(value).dtype, np.number)
        and bool(np.all(np.isfinite(value)))
    )


def _is_int(value: Any, least: int = 1, most: int | None = None) -> bool:
    """Whether ``value`` is an ``int`` (not a bool) in ``[least, most]`` (no upper bound: None)."""
    return (
        isinstance(value, int)
        and not isinstance(value, bool)
        and least <= value
        and (most is None or value <= most)
    )


def check_field(f: dataclasses.Field, value: Any, option: str | None = None) -> None:
    """Raises :class:`ConfigError` for a value that is not what the field's declaration says
    (:func:`setting`, :func:`traced`): an integer (``int``, or ``int | None`` left at None)
    within its ``minimum`` (default 1) and ``maximum``, positive integers (``tuple[int, ...]``,
    one or more), true or false, one of its
    ``choices``, a finite number within its ``bound``. ``option``: the error's
    :attr:`ConfigError.option` (a command line then names the field as its option)."""
    meta = f.metadata
    least, most, choices = meta.get("minimum", 1), meta.get("maximum"), meta.get("choices")
    if value is None and f.default is None:  # an optional setting left out
        return
    if f.type in ("int", "int | None") and not _is_int(value, least, most):
        what = "a positive integer" if least else "a non-negative integer"
        what = f"in [{least}, {most}]" if most else what
        raise ConfigError(f"{f.name} must be {what}, got {value!r}", option)
    if f.type == "tuple[int, ...]" and not (
        isinstance(value, (tuple, list)) and value and all(_is_int(h) for h in value)
    ):
        raise ConfigError(f"{f.name} must be one or more positive integers, got {value!r}", option)
    if f.type == "bool" and not isinstance(value, bool):
        raise ConfigError(f"{f.name} must be true or false, got {value!r}", option)
    if choices and value not in choices:
        either = ", ".join(map(repr, choices[:-1])) + f" or {choices[-1]!r}"
        raise ConfigError(f"{f.name} must be {either}, got {value!r}", option)
    bound, optional = meta.get("bound"), " (or none)" if f.default is None else ""
    if bound is not None and (not _is_number(value) or (np.ndim(value) and not meta.get("traced"))):
        raise ConfigError(f"{f.name} must be a finite number{optional}, got {value!r}", option)
    if bound is not None and not np.all(BOUNDS[bound](np.asarray(value))):
        raise ConfigError(f"{f.name} must be {bound}{optional}, got {value!r}", option)


def validate(config: PPOConfig) -> None:
    """Raises :class:`ConfigError` naming the first invalid field and what to do about it:
    each field as it is declared (:func:`check_field`), then what the fields make together."""
    c = config
    for f in dataclasses.fields(c):
        check_field(f, getattr(c, f.name))
    if c.batch_size % c.minibatch_size != 0:
        raise ConfigError(
            f"minibatch_size={c.minibatch_size} does not divide the rollout of "
            f"num_envs x num_steps = {c.num_envs} x {c.num_steps} = {c.batch_size}; "
            f"pick a divisor of {c.batch_size}"
        )
    sizes = (4, *c.hidden_sizes)
    weights = sum(a * b for a, b in zip(sizes, sizes[1:]))
    if weights > MAX_WEIGHTS:
        raise ConfigError(
            f"hidden_sizes={c.hidden_sizes!r} makes {weights:,} weights per MLP, more than "
            f"the {MAX_WEIGHTS:,} this trainer supports; use smaller layers"
        )
    if c.batch_size > MAX_BATCH:
        raise ConfigError(
            f"num_envs x num_steps = {c.batch_size:,} transitions per iteration is more than "
            f"the {MAX_BATCH:,} one minibatch shuffle supports; use fewer envs or steps"
        )
    if c.num_iterations > MAX_ITERATIONS:
        raise ConfigError(
            f"total_timesteps={c.total_timesteps:,} makes {c.num_iterations:,} iterations of "
            f"{c.batch_size:,} transitions, more than the {MAX_ITERATIONS:,} this trainer counts; "
            "use fewer total_timesteps"
        )
    flax_like = all(callable(getattr(c.network, name, None)) for name in ("init", "apply"))
    if not (c.network is None or isinstance(c.network, RecordedCode) or flax_like):
        raise ConfigError(f"network must be a flax module (with init and apply), got {c.network!r}")
    if not isinstance(c.env, str):
        raise ConfigError(f"env must be an env id, got {c.env!r}")
    try:
        envs.make(c.env)
    except envs.EnvError as exc:
        raise ConfigError(str(exc), "env") from None
    _validate_metrics(c.metrics)
    if c.keep_best and not c.eval_every:
        raise ConfigError(
            "keep_best needs eval_every: give the iterations between evaluations, or turn "
            "keep_best off (--no-keep-best)"
        )


MAX_CUSTOM_METRICS = 32
"""Custom metrics per run: a bound for an untrusted config.json (each is a column per
iteration and run in the stream, metrics.csv and every wave's file)."""
_METRIC_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_./-]{0,63}")
RESERVED_METRIC_NAMES = (
    *METRIC_NAMES,
    *EVAL_METRICS,
    "time/fps",
    "time/elapsed",
    "seed_index",
    "iteration",
    "env_steps",
)
"""Column names a custom metric cannot take: the built-in metrics and metrics.csv's index."""


def _validate_metrics(metrics: Any) -> None:
    if not isinstance(metrics, tuple) or not all(
        isinstance(m, tuple) and len(m) == 2 for m in metrics
    ):
        raise ConfigError(f"metrics must be a mapping of name -> function, got {metrics!r}")
    if len(metrics) > MAX_CUSTOM_METRICS:
        raise ConfigError(f"metrics holds {len(metrics)} metrics, at most {MAX_CUSTOM_METRICS}")
    names = [name for name, _ in metrics]
    for name, fn in metrics:
        if not isinstance(name, str) or not _METRIC_NAME.fullmatch(name):
            raise ConfigError(
                f"metric name {name!r} must be 1-64 letters, digits or _ . / - "
                "(it becomes a metrics.csv column), e.g. custom/pole_angle"
            )
        if name in RESERVED_METRIC_NAMES:
            raise ConfigError(f"metric name {name!r} is a built-in column; choose another")
        if names.count(name) > 1:
            raise ConfigError(f"metric name {name!r} is given twice")
        if not callable(fn):
            raise ConfigError(f"metric {name!r} must be a function, got {fn!r}")


PRESETS: dict[str, dict] = {
    # Stable-Baselines3's PPO defaults on CartPole-v1: PPO("MlpPolicy", "CartPole-v1").learn(80_000)
    "sb3": {},
    # PureJaxRL's CartPole PPO settings.
    "purejaxrl": dict(
        num_envs=4,
        num_steps=128,
        # PureJaxRL's NUM_UPDATES = 5e5 // 128 // 4 = 976 iterations, rounded down, where
        # jaxcart rounds total_timesteps up (as SB3 does): 977 at 500_000
        total_timesteps=976 * 512,
        minibatch_size=128,
        update_epochs=4,
        learning_rate=2.5e-4,
        anneal_lr=True,
        ent_coef=0.01,
        # PureJaxRL's loss: its value clipping (by clip_eps, with the 1/2 factor), jnp.std's
        # population std, and truncation treated as termination
        value_clip="purejaxrl",
        adv_std="population",
        bootstrap_truncation=False,
    ),
    # Least wall time to a policy that solves every seed on a 2-core CPU, under XLA's native
    # ISA and pinned to AVX2 (what another CPU does to the floats): the entropy bonus keeps
    # a seed from settling early on a poor policy, and the best of 14 evaluations on 64 start
    # states each (the last one the final policy) is kept; a 32-32 network halves the
    # update's arithmetic. 512/512 on four held-out base seeds, both settings
    # (benchmarks/experiments/fast_preset.md has the search).
    "fast": dict(
        hidden_sizes=(32, 32),
        num_envs=4,
        num_steps=128,
        total_timesteps=100_000,
        minibatch_size=128,
        update_epochs=4,
        learning_rate=5e-3,
        anneal_lr=True,
        ent_coef=0.01,
        eval_every=14,
        periodic_eval_episodes=64,
        keep_best=True,
    ),
    # Acrobot-v1 on gymnax's implementation (pip install -e '.[gymnax]'), chosen with sweeps
    # and compare to beat rejax's own Acrobot config on wall time: a 32-32 network halves the
    # update's cost, and entropy 0.05 keeps every seed exploring until it reaches the goal
    # (benchmarks/experiments/acrobot_preset.md has the search and its held-out checks).
    "acrobot": dict(
        env="Acrobot-v1",
        num_envs=16,
        num_steps=64,
        total_timesteps=153_600,
        minibatch_size=256,
        update_epochs=4,
        hidden_sizes=(32, 32),
        learning_rate=2.5e-3,
        anneal_lr=True,
        ent_coef=0.05,
    ),
}


def preset(name: str, **overrides) -> PPOConfig:
    """The named preset's config, with ``overrides`` applied."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; choose one of: {', '.join(PRESETS)}")
    return PPOConfig(**{**PRESETS[name], **overrides})


@functools.cache
def config_fields() -> list[dataclasses.Field]:
    """The fields of :class:`PPOConfig` the command line sets (all but ``network`` and
    ``metrics``), in
    declaration order."""
    return [f for f in dataclasses.fields(PPOConfig) if f.metadata.get("cli", True)]
