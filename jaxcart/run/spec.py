"""What a run is, as values: what it trains (:class:`RunSpec`), how it is carried out
(:class:`RunOptions`), the events it reports (:class:`Hooks`), the run being carried out
(:class:`Run`) and what a call did (:class:`Outcome`, :class:`Evaluation`).

Nothing here trains or touches files: :mod:`jaxcart.run.lifecycle` does, through
:mod:`jaxcart.run.lifecycle` and the run's :class:`~jaxcart.rundir.directory.RunDir`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jaxcart.analysis.summary import Score
from jaxcart.core import envs, physics, pytree
from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import TRACED_FIELDS, ConfigError, PPOConfig, check_field, setting
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.solved import is_solved
from jaxcart.engine.loop import Progress, TrainResult
from jaxcart.run import sweep as sweeps
from jaxcart.run.loggers import check_available
from jaxcart.run.waves import WavePlan
from jaxcart.rundir.directory import RunDir
from jaxcart.rundir.reader import (
    SHAPE_FIELDS,
    check_num_runs,
    combo_config,
    env_values,
    sweep_combinations,
)


# -- the one reading of NAME=VALUE options (--sweep, --env-param, --randomize, --space) ------
def assignments(
    specs: Sequence[str], option: str, form: str, twice: str = "keep one", prefix: str = ""
) -> Iterator[tuple[str, str]]:
    """Each ``NAME=VALUE`` of a repeatable ``option`` as ``(NAME, VALUE)``, NAME as it is read:
    stripped, its dashes read as underscores (``clip-coef`` is ``clip_coef``), less an
    optional ``prefix`` (``env.`` of ``--env-param``): what every option that assigns parses
    its values with.

    Raises:
        ConfigError: a spec without ``=``, NAME or VALUE (``malformed OPTION 'SPEC';
            expected FORM``), or a NAME given twice (``OPTION NAME given twice; TWICE``).
    """
    seen = set()
    for spec in specs:
        name, sep, text = spec.partition("=")
        name = name.strip().replace("-", "_").removeprefix(prefix)
        if not sep or not name or not text.strip():
            raise ConfigError(f"malformed {option} {spec!r}; expected {form}")
        if name in seen:
            raise ConfigError(f"{option} {name} given twice; {twice}")
        seen.add(name)
        yield name, text


def distinct_values(option: str, name: str, text: str, parse: Callable[[str], Any]) -> list:
    """The comma-separated values of ``NAME=V1,V2,...``, each read by ``parse``.

    Raises:
        ConfigError: no value, or a value given twice; ``parse``'s errors pass through.
    """
    values = [parse(v) for v in text.split(",") if v.strip()]
    if not values or len(set(values)) != len(values):
        raise ConfigError(f"{option} {name}: give distinct values, got {text!r}")
    return values


MAX_GROUPS = 64
"""Shape groups per structural sweep: each compiles a program of its own."""


def parse_sweep(specs: Sequence[str]) -> tuple[dict[str, list[float]], dict[str, list]]:
    """``--sweep``'s one reading: ``["learning_rate=1e-4,3e-4", "num_envs=4,8"]`` -> its float
    axes ``{name: [values]}``, every combination in one program (a continuous physics field
    sweeps as ``env.length=0.5,1.0``, kept with its prefix), and its shape axes
    ``{name: [values]}`` (:data:`~jaxcart.rundir.reader.SHAPE_FIELDS`: an integer each, or
    hidden_sizes' ``64x64``), one program per combination of their values.

    Raises:
        ConfigError: malformed spec, unknown or non-sweepable field, bad or repeated value,
            or too many shape groups.
    """
    sweep: dict[str, list[float]] = {}
    shapes: dict[str, list] = {}
    form = "NAME=V1,V2,... e.g. learning_rate=1e-4,3e-4"
    for name, text in assignments(specs, "--sweep", form, "put all its values in one option"):
        if name in SHAPE_FIELDS:
            kind = "tuple[int, ...]" if name == "hidden_sizes" else "int"
            parse = functools.partial(parse_value, kind, option=f"--sweep {name}")
            shapes[name] = distinct_values("--sweep", name, text, parse)
            continue
        if name.startswith(physics.PREFIX):
            physics.check_continuous(name[len(physics.PREFIX) :], "--sweep")
        elif name not in TRACED_FIELDS:
            raise ConfigError(
                f"cannot sweep {name!r}: only float hyperparameters run in one program "
                f"({', '.join(TRACED_FIELDS)}); num_envs, num_steps, minibatch_size, "
                "update_epochs and hidden_sizes sweep as shape groups, one program each"
            )
        try:
            sweep[name] = distinct_values("--sweep", name, text, float)
        except ConfigError:  # a ValueError too: the repeated values
            raise
        except ValueError:  # float() of a word
            raise ConfigError(f"--sweep {name}: values must be numbers, got {text!r}") from None
    groups = math.prod(len(v) for v in shapes.values())
    if groups > MAX_GROUPS:
        raise ConfigError(
            f"--sweep: {groups} shape groups, each its own program; at most {MAX_GROUPS}"
        )
    return sweep, shapes


def parse_env_params(specs: Sequence[str]) -> dict[str, Any]:
    """``["length=1.0", "masspole=0.2"]`` (``env.length=1.0`` too) -> ``{"length": 1.0,
    "masspole": 0.2}``, each value of its field's type.

    Raises:
        ConfigError: malformed, unknown, repeated or of the wrong type.
    """
    form = "NAME=VALUE, e.g. length=1.0"
    given = assignments(specs, "--env-param", form, prefix=physics.PREFIX)
    return {name: _env_value(name, text) for name, text in given}


_ENV_KINDS = {f.name: str(f.type) for f in dataclasses.fields(EnvParams)}
BOOLS = {"true": True, "on": True, "1": True, "false": False, "off": False, "0": False}
EXAMPLES = {"bool": "on", "int": "8", "float": "0.5", "tuple[int, ...]": "64x64"}
"""A value of each kind of field, as :func:`parse_value` reads it (a ``str`` takes any)."""


def parse_value(kind: str, text: str, option: str = "") -> Any:
    """``text`` as a value of a field annotated ``kind`` (``bool``: on/off, true/false, 1/0;
    ``int``: a whole number, ``1e5`` too; ``tuple[int, ...]``: widths joined by x, ``64x64``;
    ``float``; ``str``): the one reading of a single value that ``--env-param``, a
    structural ``--sweep`` and ``--space`` choices share.

    Raises:
        ConfigError: ``OPTION: 'TEXT' is not a value like EXAMPLE`` (without ``option``, the
            caller names the option).
    """
    text = text.strip()
    try:
        if kind == "bool":
            return BOOLS[text.lower()]
        if kind == "int":
            if not float(text).is_integer():
                raise ValueError
            return int(float(text))
        if kind == "tuple[int, ...]":
            return tuple(int(w) for w in text.split("x"))
        return float(text) if kind == "float" else text
    except (KeyError, ValueError):
        where = f"{option}: " if option else ""
        raise ConfigError(f"{where}{text!r} is not a value like {EXAMPLES[kind]}") from None


def _env_value(name: str, text: str) -> Any:
    """``text`` as physics field ``name``'s type (float, int, bool or the integrator's name).

    Raises:
        ConfigError: not a field of CartPole's params, or not a value of its type.
    """
    if name not in physics.FIELDS:
        raise ConfigError(
            f"CartPole has no env param {name!r}; choose one of: {', '.join(physics.FIELDS)}"
        )
    return parse_value(_ENV_KINDS[name], text, f"env param {name}")


def parse_randomize(specs: Sequence[str]) -> tuple[physics.Randomization, ...]:
    """``["env.length=0.5:1.5", "env.masspole=0.05:0.2:episode"]`` -> randomisations.

    Raises:
        ConfigError: malformed, not a continuous physics field, ``low > high``, repeated.
    """
    form = "env.NAME=LOW:HIGH[:episode], e.g. env.length=0.5:1.5"
    out = []
    for name, text in assignments(specs, "--randomize", form):
        parts = text.split(":")
        if not name.startswith(physics.PREFIX) or len(parts) not in (2, 3):
            raise ConfigError(f"malformed --randomize {name + '=' + text!r}; expected {form}")
        name = name[len(physics.PREFIX) :]
        physics.check_continuous(name, "--randomize")
        per = parts[2].strip() if len(parts) == 3 else "run"
        if per not in ("run", "episode"):
            raise ConfigError(f"--randomize env.{name}: the third part must be run or episode")
        try:
            low, high = float(parts[0]), float(parts[1])
        except ValueError:
            raise ConfigError(f"--randomize env.{name}: LOW and HIGH must be numbers") from None
        if not low <= high:
            raise ConfigError(f"--randomize env.{name}: low {low:g} is above high {high:g}")
        out.append(physics.Randomization(name, low, high, per))
    return tuple(out)


def check_option(ok: bool, option: str, problem: str) -> None:
    """Raises a ConfigError naming ``option`` unless ``ok``."""
    if not ok:
        raise ConfigError(f"{option} {problem}", option=option)


@dataclass(frozen=True)
class RunSpec:
    """What a new run trains; ``config.json`` records all of it."""

    config: PPOConfig = field(default_factory=PPOConfig)
    preset: str = "custom"
    """The preset the config started from (a label in config.json and the header)."""
    num_seeds: int = setting(1)
    """Independent seeds (per combination in a sweep)."""
    seed: int = setting(0, minimum=0, maximum=2**32 - 1)
    """Base seed: seed index i uses ``fold_in(PRNGKey(seed), i)``."""
    sweep: dict[str, list[float]] = field(default_factory=dict)
    """Traced float hyperparameter (or ``env.NAME``, a continuous physics field) -> values;
    every combination x seed trains in one program."""
    combinations: tuple[dict[str, float], ...] = ()
    """Explicit points instead of the sweep's grid (a search's trials): each one's traced float
    hyperparameters; every point x seed trains in one program, as a sweep does."""
    env_params: EnvParams = field(default_factory=EnvParams)
    """CartPole's physics for every run (config.json records the fields that differ from
    CartPole-v1's)."""
    randomize: tuple[physics.Randomization, ...] = ()
    """Physics fields drawn uniformly per run (from the seed) or per episode (at every reset)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):  # num_seeds and seed, as declared
            check_field(f, getattr(self, f.name), f.name)
        combos = len(self.combinations) or math.prod(len(v) for v in self.sweep.values())
        check_num_runs(self.num_seeds, combos)  # what the readers accept, before any list
        sweeps.validate_sweep(self.config, self.sweep)  # before anything is created
        if not self.takes_physics and (
            physics.overrides(self.env_params) or self.randomize or env_values(self.sweep)
        ):
            raise ConfigError(
                f"--env-param, env.* sweeps and --randomize set CartPole's physics; "
                f"{self.config.env} trains on its own (gymnax's default params)"
            )
        physics.check_physics(self.env_params)
        for name in ("max_episode_steps", "sutton_barto_reward"):
            if name in physics.overrides(self.env_params):
                raise ConfigError(
                    f"--env-param {name} changes what an episode scores, and a run directory "
                    "judges 500 as solved; train it through the Python API "
                    "(jaxcart.engine.loop.train(env_params=...))"
                )
        sweeps.validate_env_sweep(self.env_params, self.sweep)
        swept = env_values(self.sweep)
        for r in self.randomize:
            if r.name in swept:
                raise ConfigError(f"env.{r.name} is both swept and randomised; keep one")
            for bound in (r.low, r.high):
                try:
                    physics.check_physics(self.env_params.replace(**{r.name: bound}))
                except ConfigError as exc:
                    raise ConfigError(f"--randomize env.{r.name}: {exc}") from None
        if self.combinations:
            check_option(not self.sweep, "combinations", "and sweep cannot both be given")
            sweeps.validate_combinations(self.config, self.combinations)

    @classmethod
    def from_record(cls, info: dict) -> RunSpec:
        """The spec a run's ``config.json`` records (:meth:`record`; ``config`` already a
        PPOConfig): the one reading of a record, for ``--resume``, a replay and ``train
        --config RUN`` (:meth:`options`)."""
        sweep = {k: list(v) for k, v in (info.get("sweep") or {}).items()}
        return cls(
            config=info["config"],
            preset=info.get("preset", "custom"),
            num_seeds=int(info.get("num_seeds", 1)),
            seed=int(info.get("seed", 0)),
            sweep=sweep,
            combinations=() if sweep else tuple(dict(c) for c in info.get("combinations") or ()),
            env_params=physics.make_env_params(info.get("env_params") or {}),
            randomize=tuple(
                physics.Randomization(name, float(r["low"]), float(r["high"]), str(r["per"]))
                for name, r in (info.get("randomize") or {}).items()
            ),
        )

    def record(self) -> dict:
        """What ``config.json`` records of the spec besides its config (:meth:`from_record`
        reads it back): preset, seeds, sweep, the physics (``env_params``: the fields that
        differ from CartPole-v1's, and ``randomize``, each only when there is one, so a run on
        the default physics records what it always did) and a search's ``combinations``."""
        out = {"preset": self.preset, "num_seeds": self.num_seeds, "seed": self.seed}
        optional = {
            "env_params": physics.overrides(self.env_params),
            "randomize": {r.name: r.to_dict() for r in self.randomize},
            "combinations": [dict(c) for c in self.combinations],
        }
        return {**out, "sweep": self.sweep, **{k: v for k, v in optional.items() if v}}

    def options(self) -> dict:
        """The spec as the options that train it again, keyed by their names (``train
        --config`` of a run's config.json): preset, seeds, sweep, every config field that is
        not swept, ``env_param`` and ``randomize``.

        Raises:
            ConfigError: explicit combinations (a search's trials), which no option gives.
        """
        if self.combinations:
            raise ConfigError(
                "its runs are a search's trials, which no option of train gives; "
                "python -m jaxcart.tune searches again"
            )
        values = {**self.record(), **self.config.to_dict(), "sweep": self.sweep}
        for name in self.sweep:
            values.pop(name, None)
        values["env_param"] = values.pop("env_params", {})
        values["randomize"] = [r.option for r in self.randomize]
        return values

    @functools.cached_property
    def takes_physics(self) -> bool:
        """Whether the env's params (its ``default_params``, as the env protocol gives every
        env's) are the :class:`EnvParams` that ``env_params``, ``env.*`` sweeps and
        ``randomize`` set: CartPole's, and any env registered on them; another env trains on
        its own default params."""
        return isinstance(envs.make(self.config.env).default_params(), EnvParams)

    def run_env_params(self, runs: range) -> EnvParams | None:
        """The physics of ``runs`` (grid order) as they train: the run's env params, with
        each swept or per-run randomised field an array ``[len(runs)]``; None for an env whose
        params these are not (it trains on its own default params)."""
        if not self.takes_physics:
            return None
        values = sweeps.grid_env_values(self.grid, runs)
        indices = self.grid.seed_indices(runs)
        values.update(physics.randomized_values(self.randomize, self.seed, indices))
        return pytree.with_values(self.env_params, values)

    def eval_env_params(self, runs: range) -> EnvParams | None:
        """The physics ``runs`` are evaluated on: a sweep's own values per run, the nominal
        physics (``env_params``) for a randomised field; None for an env whose params these
        are not."""
        if not self.takes_physics:
            return None
        return pytree.with_values(self.env_params, sweeps.grid_env_values(self.grid, runs))

    @property
    def episode_ranges(self) -> dict[str, tuple[float, float]]:
        """The fields drawn at every reset, ``{name: (low, high)}`` (``{}``: none)."""
        return {r.name: (r.low, r.high) for r in self.randomize if r.per == "episode"}

    def seed_env_values(self) -> dict[str, list[float]]:
        """Each per-run randomised field's value for every seed index, as recorded."""
        drawn = physics.randomized_values(self.randomize, self.seed, range(self.num_seeds))
        return {n: [float(x) for x in v] for n, v in drawn.items()}

    @functools.cached_property
    def grid(self) -> sweeps.RunGrid:
        """Seeds x combinations (built once: a large sweep has a million combinations)."""
        combos = self.combinations or tuple(sweep_combinations(self.sweep))
        return sweeps.RunGrid(self.num_seeds, combos)

    def combo_config(self, combination: int) -> PPOConfig:
        """The config of one combination (the config itself without a sweep)."""
        if not self.grid.is_sweep:
            return self.config
        return combo_config(self.config, self.grid.combos[combination])


@dataclass(frozen=True)
class RunOptions:
    """How a run is carried out (a resume may choose them anew)."""

    checkpoint_every: float = 30.0
    """Seconds between checkpoints."""
    eval_episodes: int | None = setting(None)
    """Greedy Gymnasium evaluation episodes per seed (None: 20, or a resumed run's own)."""
    loggers: tuple[str, ...] = ()
    """Metric backends besides metrics.csv: ``tensorboard``, ``swanlab``, ``wandb``."""
    logger_dir: Path | None = None
    """One folder the loggers write into, shared with other runs (default: SwanLab's
    ``$SWANLAB_LOG_DIR`` or ``./swanlog``; see :func:`jaxcart.run.loggers.make_logger`)."""
    compile_cache: bool = True
    """Use JAX's persistent compilation cache."""
    chunk_size: int | None = setting(None)
    """Iterations per compiled call between progress reports (default: as many as take about
    2 s, measured as the run goes)."""
    wave_size: int | None = setting(None)
    """Runs trained at once in a new run (default: the fewest that fill the devices)."""
    score: Score | None = None
    """What ranks a sweep's combinations, as ``compare --score`` scores a run (None: eval, or
    the score a resumed sweep recorded in config.json)."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            check_field(f, getattr(self, f.name), f.name)
        check_option(
            0 < self.checkpoint_every <= 86_400 * 365,  # NaN fails too
            "checkpoint_every",
            f"must be in (0, 31536000] seconds, got {self.checkpoint_every}",
        )
        check_available(self.loggers)  # a LoggerUnavailable is a ConfigError


@dataclass
class Hooks:
    """Callbacks for a run's events; every one is optional."""

    on_start: Callable[[Run, int, str], None] | None = None  # run, device count, backend
    on_compiled: Callable[[float], None] | None = None  # compile seconds
    on_chunk: Callable[[Progress], None] | None = None
    on_diverged: Callable[[str, int], None] | None = None  # run name, iteration
    on_signal: Callable[[int], None] | None = None  # first SIGINT/SIGTERM
    on_init: Callable[[int, int], None] | None = None  # runs initialised so far, of all
    on_wave: Callable[[int, int, range], None] | None = None  # wave, of how many, its runs


@dataclass
class Evaluation:
    """Greedy evaluation of every run, returns ``[R, episodes]``."""

    episodes: int
    gym_returns: np.ndarray  # in gymnasium.make(env)
    jax_returns: np.ndarray  # in jaxcart's env
    seconds: float
    env: str = DEFAULT_ENV  # whose notion of solved applies
    best_gym_returns: np.ndarray | None = None  # keep_best's policies, in gymnasium.make(env)

    @property
    def solved(self) -> np.ndarray:
        return is_solved(self.gym_returns, self.env)

    @property
    def best_solved(self) -> np.ndarray | None:
        """Whether each run's kept best policy solved (None: the runs kept none)."""
        if self.best_gym_returns is None:
            return None
        return is_solved(self.best_gym_returns, self.env)


@dataclass
class Outcome:
    """What a call of :func:`run_new` / :func:`resume_run` did."""

    run: Run
    result: TrainResult | None  # the last wave's training; None if stopped before training
    diverged_at: np.ndarray | None = None  # [R]: -1, or the iteration that went non-finite
    final_return: np.ndarray | None = None  # [R]: rollout/ep_rew_mean at the last iteration
    evaluation: Evaluation | None = None  # None when stopped before the outputs were written
    ranking: list[dict] | None = None  # sweeps: the combinations, best first
    signum: int | None = None  # the signal that stopped it (or arrived while writing)
    stopped: bool = False  # stopped before the run directory was complete (resumable)
    compile_seconds: float = 0.0  # this session's, every wave
    train_seconds: float = 0.0  # this session's training, compile excluded
    env_steps: int = 0  # this session's, all runs
    num_devices: int = 1
    stopped_at: tuple[int, int] | None = None  # (wave, iteration) of the checkpoint on disk


@dataclass
class Run:
    """A run being carried out: what it trains, its directory, its ``config.json`` record
    (``info``, without the config itself) and the waves it trains in."""

    directory: RunDir
    spec: RunSpec
    info: dict
    plan: WavePlan
    resumed_from: int | None = None
    """The iteration of the checkpoint a resume continues from (None for a new run)."""
    resume_wave: int = 0
    """The wave a resume continues with."""
    trained_chunks: int = 0
    """Chunks this process has trained (a new run that fails with none is discarded)."""

    # the directory's and the spec's, as the run's own
    out = property(lambda self: self.directory.path)
    main_process = property(lambda self: self.directory.main_process)
    grid = property(lambda self: self.spec.grid)
    config = property(lambda self: self.spec.config)
    preset = property(lambda self: self.spec.preset)
    sweep = property(lambda self: self.spec.sweep)

    def close(self) -> None:
        """Releases the run directory for other processes."""
        self.directory.close()
