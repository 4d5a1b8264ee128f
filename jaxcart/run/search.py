"""Hyperparameter search as a library, on Optuna's ask-and-tell interface. Nothing here prints.

A search space names config fields and how to draw them (:func:`parse_space`). A study is
driven a batch at a time (:class:`Tuner`): ``batch_trials`` trials are asked at once, grouped
by their shape settings (static fields: ``num_envs``, ``hidden_sizes``, ...), and each group
trains as one run of :func:`jaxcart.run.lifecycle.run_new` whose explicit combinations are the
group's trials: its float hyperparameters are traced, so trials x seeds are one vmapped program.
Each trial is told its score over its seeds (the IQM of :class:`jaxcart.analysis.summary.Score`,
the score ``compare`` ranks by), and every group leaves a sweep-shaped run directory that
``plot``, ``compare`` and ``evaluate`` read.

A space is Optuna's own distributions, keyed by parameter name: a parameter is a config
field, or ``one_minus_FIELD`` (:func:`field_of`, :func:`config_value`). Optuna is an optional
dependency (``pip install -e '.[tune]'``), imported when a space is parsed (one line when it
is missing: :func:`require_optuna`), never when this module is. Only Optuna's public API is
used: the heartbeat, which Optuna keeps for ``Study.optimize``, is recorded through the
storage's own methods (:func:`heartbeat`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import difflib
import math
import shutil
import threading
import time
import warnings
import zlib
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from jaxcart.analysis import stats
from jaxcart.analysis.summary import Score, auc
from jaxcart.core.config import TRACED_FIELDS, ConfigError, PPOConfig, config_fields
from jaxcart.engine.loop import Progress
from jaxcart.engine.signals import StopRequest
from jaxcart.run.lifecycle import run_new
from jaxcart.run.progress import chain_hooks
from jaxcart.run.spec import Hooks, Outcome, RunOptions, RunSpec, assignments, parse_value
from jaxcart.run.structural import by_shape, group_config, group_spec
from jaxcart.run.sweep import RETURN_METRIC
from jaxcart.rundir import layout
from jaxcart.rundir.reader import load_runs, sweep_combinations

RUNGS = 8
"""Intermediate scores reported to the pruner per trial, at evenly spaced iterations."""
HEARTBEAT_SECONDS = 60
"""How often a running trial tells the storage it is alive (Optuna's heartbeat)."""
STALE_GRACE_SECONDS = 300
"""A trial silent this long belonged to a process that died; it is marked failed."""
WAIT_SECONDS = 5
"""How often a study whose last trials run elsewhere is checked while this process waits."""


SPACE_PRESETS: dict[str, tuple[str, ...]] = {
    # rl-zoo3 v2.6+ (sample_ppo_params): 1 - gamma and 1 - lambda on a log scale, no vf_coef
    "rl-zoo3": (
        "learning_rate=log:1e-5:0.002",
        "clip_coef=0.1:0.4",
        "ent_coef=log:1e-8:1e-1",
        "one_minus_gamma=log:1e-4:0.03",
        "one_minus_gae_lambda=log:1e-4:0.1",
        "max_grad_norm=0.3:2.0",
    ),
    # rl-zoo3 up to v2.5.0, its choices as ranges; the learning rate up to 1e-2, not 1
    "rl-zoo3-v2.5": (
        "learning_rate=log:1e-5:1e-2",
        "clip_coef=0.1:0.4",
        "ent_coef=log:1e-8:1e-1",
        "gamma=0.9:0.9999",
        "gae_lambda=0.8:1.0",
        "max_grad_norm=0.3:5.0",
        "vf_coef=0.1:1.0",
    ),
}
"""Named spaces, each a ``--space`` value: rl-zoo3's PPO float ranges (``sample_ppo_params``),
all traced, so a batch is one program. rl-zoo3's clip choices 0.1 to 0.4 are the range; its
shape settings (n_steps, batch size, epochs, network) are left out."""
DEFAULT_SPACE = SPACE_PRESETS["rl-zoo3"]
"""Without ``--space``: rl-zoo3's current (v2.6 and later) PPO float ranges."""
ONE_MINUS = "one_minus_"
"""``one_minus_gamma=log:1e-4:0.03`` draws ``1 - gamma``: log-uniform near 1."""
SPACE_FORM = "NAME=LOW:HIGH, NAME=log:LOW:HIGH or NAME=A,B,C"
_KINDS = {f.name: str(f.type) for f in config_fields()}  # "int", "float", "bool", ...


# -- search spaces --------------------------------------------------------------------------
def require_optuna() -> Any:
    """The ``optuna`` module, its logging quiet, or a one-line error naming the extra."""
    try:
        import optuna
    except ImportError:
        raise ConfigError(
            "jaxcart.tune needs Optuna: pip install -e '.[tune]' (or pip install optuna)"
        ) from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    # Optuna flags the heartbeat (what fails a dead process's trials) experimental, and warns
    # that it is meant for Study.optimize; ask-and-tell records it by hand (heartbeat())
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    warnings.filterwarnings("ignore", message="Heartbeat of storage")
    return optuna


def field_of(param: str) -> str:
    """The config field an Optuna parameter draws: its own, or for ``one_minus_FIELD`` (a
    traced float) ``FIELD``."""
    name = param.removeprefix(ONE_MINUS)
    return name if name in TRACED_FIELDS else param


def config_value(param: str, value: Any) -> Any:
    """A value drawn for ``param`` as its config field takes it (``"64x64"`` -> ``(64, 64)``,
    ``one_minus_gamma`` 0.01 -> 0.99)."""
    name = field_of(param)
    if name == "hidden_sizes":
        return tuple(int(n) for n in str(value).split("x"))
    if name != param:
        return 1.0 - float(value)
    return float(value) if name in TRACED_FIELDS else value


def split_params(params: dict[str, Any]) -> tuple[dict, dict]:
    """A trial's params as ``(shape settings, traced floats)``, in config values by field."""
    static, traced = {}, {}
    for param, value in params.items():
        name = field_of(param)
        (traced if name in TRACED_FIELDS else static)[name] = config_value(param, value)
    return static, traced


def _choice(name: str, text: str) -> Any:
    """One categorical value of config field ``name``, from its text, of the field's kind
    (:func:`~jaxcart.run.spec.parse_value`; ``hidden_sizes`` as Optuna stores it: widths
    joined by x)."""
    value = parse_value(_KINDS[name], text)
    return "x".join(map(str, value)) if name == "hidden_sizes" else value


def _distribution(optuna: Any, param: str, text: str) -> Any:
    """The Optuna distribution of one ``--space PARAM=TEXT`` (PARAM as
    :func:`~jaxcart.run.spec.assignments` read it).

    Raises:
        ConfigError: an unknown field, a low not below its high, a log range through zero,
            a repeated or invalid choice (one line).
    """
    name, dists = field_of(param), optuna.distributions
    if name not in _KINDS:
        near = difflib.get_close_matches(param, list(_KINDS), n=1)
        hint = f" (did you mean {near[0]}?)" if near else ""
        raise ConfigError(f"--space {param}: no such config field{hint}")
    parts = text.strip().split(":")
    try:
        if len(parts) == 1 or "," in text:
            choices = [_choice(name, c) for c in text.split(",") if c.strip()]
            if len(set(choices)) != len(choices) or not choices:
                raise ValueError(f"give distinct choices, got {text!r}")
            return dists.CategoricalDistribution(choices)
        prefix = parts[0] if len(parts) == 3 else ""
        if len(parts) not in (2, 3) or prefix not in ("", "log", "int", "log-int"):
            raise ValueError(f"expected LOW:HIGH, log:LOW:HIGH, int:LOW:HIGH, got {text!r}")
        low, high = float(parts[-2]), float(parts[-1])
    except ValueError as exc:
        raise ConfigError(f"--space {param}: {exc}") from None
    integer, log = "int" in prefix or _KINDS[name] == "int", prefix.startswith("log")
    if not (name in TRACED_FIELDS or integer):
        raise ConfigError(f"--space {param}: a range needs a number field; give choices A,B,C")
    if not (math.isfinite(low) and math.isfinite(high)) or low >= high:
        raise ConfigError(f"--space {param}: low {low:g} must be below high {high:g}")
    if integer and not (low.is_integer() and high.is_integer()):
        raise ConfigError(f"--space {param}: an integer range needs integer bounds")
    if log and low <= 0:
        raise ConfigError(f"--space {param}: a log range must be above zero, got {low:g}:{high:g}")
    if integer:
        return dists.IntDistribution(int(low), int(high), log=log)
    return dists.FloatDistribution(low, high, log=log)


def _checked_values(dist: Any) -> tuple:
    """A dimension's values checked alone against the base config: every choice, every value
    of a small integer range (a shape value between its ends may not divide), else its ends."""
    if hasattr(dist, "choices"):
        return dist.choices
    if isinstance(dist.low, int) and dist.high - dist.low <= 4096:
        return tuple(range(dist.low, dist.high + 1))
    return (dist.low, dist.high)


def parse_space(
    specs: Sequence[str], config: PPOConfig, score: Score | None = None
) -> dict[str, Any]:
    """Every ``--space`` option as Optuna distributions, keyed by parameter name:
    ``learning_rate=log:1e-5:1e-2``, ``clip_coef=0.1:0.3``, ``num_envs=1,4,8``,
    ``num_steps=int:32:512`` (``log-int:`` too), ``hidden_sizes=64x64,32x32``; a float field
    named ``one_minus_FIELD`` draws ``1 - FIELD``. None: :data:`DEFAULT_SPACE`; a name of
    :data:`SPACE_PRESETS` stands for its specs. Checked against ``config`` (the trials' base)
    before anything compiles: each dimension's values (:func:`_checked_values`), and each
    combination of the shape settings' choices, must make a valid config, and a ``score``
    ``return-at:STEPS`` must not be past the end of any (:func:`check_score`).

    Raises:
        ConfigError: Optuna missing, a malformed spec, a field given twice, or a value that
            makes an invalid config (one line).
    """
    optuna, space = require_optuna(), {}
    expanded = [s for spec in specs for s in SPACE_PRESETS.get(spec.strip(), (spec,))]
    for param, text in assignments(expanded or DEFAULT_SPACE, "--space", SPACE_FORM):
        dist = _distribution(optuna, param, text)
        if field_of(param) in map(field_of, space):
            raise ConfigError(f"--space {field_of(param)} given twice; keep one")
        space[param] = dist
    configs, choices = [config], {}
    for param, dist in space.items():
        name = field_of(param)
        for value in _checked_values(dist):
            try:
                changed = dataclasses.replace(config, **{name: config_value(param, value)})
            except (TypeError, ValueError) as exc:  # ConfigError is a ValueError
                raise ConfigError(f"--space {param}={value}: {exc}") from None
            configs += [] if name in TRACED_FIELDS else [changed]
        if name not in TRACED_FIELDS and hasattr(dist, "choices"):
            choices[name] = [config_value(param, v) for v in dist.choices]
    # num_envs x num_steps must divide into minibatches, ...: the one shape-group check
    for shape in sweep_combinations(choices, limit=10_000) if len(choices) > 1 else []:
        group_config(config, shape, "--space")
    if score is not None:
        check_score(score, configs)
    return space


def check_score(score: Score, configs: Sequence[PPOConfig]) -> None:
    """Refuses a ``return-at:STEPS`` past the end of one of ``configs`` (a run's, or a search
    space's shape values'): one line, before anything compiles."""
    short = min(c.env_steps_per_seed for c in configs)
    if score.steps is not None and score.steps > short:
        raise ConfigError(
            f"--score {score.label}: some trials end at {short:,} env steps per seed; "
            "choose fewer steps or a larger --total-timesteps"
        )


# -- the study --------------------------------------------------------------------------------
@contextlib.contextmanager
def storage_errors(storage: str, also: tuple[type[Exception], ...] = ()) -> Iterator[None]:
    """Optuna's storage errors (SQLAlchemy's and the drivers', and ``also``) in the block as
    one :class:`ConfigError` line naming ``storage``, with the first line of what the driver
    said (``attempt to write a readonly database``): Optuna and SQLAlchemy wrap it in generic
    messages.

    Raises:
        ConfigError: a storage read or write failed (a read-only database, a lost server).
    """
    import optuna
    import sqlalchemy

    try:
        yield
    except (optuna.exceptions.StorageInternalError, sqlalchemy.exc.SQLAlchemyError, *also) as exc:
        while exc.__cause__ is not None:
            exc = exc.__cause__
        text = str(exc).strip()
        line = text.splitlines()[0] if text else type(exc).__name__
        raise ConfigError(f"--storage {storage}: {line}") from None


def open_study(
    storage: str,
    study_name: str,
    sampler: str = "tpe",
    pruner: str = "none",
    sampler_seed: int | None = None,
) -> tuple[Any, Any]:
    """Opens (or creates) a study in ``storage`` (any URL Optuna's RDB storage accepts).

    Returns:
        ``(study, its RDBStorage)``: the storage records the trials' heartbeat.

    Raises:
        ConfigError: Optuna missing, an in-memory SQLite database (the study would end with the
            process), a storage that cannot be opened or written, or a study that exists with
            another direction.
    """
    optuna = require_optuna()
    if storage.startswith("sqlite:"):
        from sqlalchemy.engine import make_url

        with storage_errors(storage):
            url = make_url(storage)
        path = (url.database or "").removeprefix("file:")
        if path in ("", ":memory:") or url.query.get("mode") == "memory":
            raise ConfigError(
                f"--storage {storage}: an in-memory database ends with this process, so the "
                "study could not be continued; give a file, e.g. sqlite:///runs/study.db"
            )
        Path(path).parent.mkdir(parents=True, exist_ok=True)
    # SQLAlchemy's and the drivers' many errors (a closed port, a missing driver): all one line
    with storage_errors(storage, also=(Exception,)):
        rdb = optuna.storages.RDBStorage(
            storage, heartbeat_interval=HEARTBEAT_SECONDS, grace_period=STALE_GRACE_SECONDS
        )
    samplers = {
        # constant_liar: trials asked together (a batch, or another process) spread out
        "tpe": lambda: optuna.samplers.TPESampler(seed=sampler_seed, constant_liar=True),
        "random": lambda: optuna.samplers.RandomSampler(seed=sampler_seed),
    }
    pruners = {
        "none": optuna.pruners.NopPruner,
        "median": lambda: optuna.pruners.MedianPruner(n_startup_trials=5, n_warmup_steps=1),
        "halving": optuna.pruners.SuccessiveHalvingPruner,
    }
    with storage_errors(storage):  # a read-only database fails here
        try:
            study = optuna.create_study(
                storage=rdb,
                study_name=study_name,
                sampler=samplers[sampler](),
                pruner=pruners[pruner](),
                direction="maximize",
                load_if_exists=True,
            )
        except ValueError as exc:
            raise ConfigError(f"--study-name {study_name}: {exc}") from None
    return study, rdb


def check_study_space(study: Any, space: dict[str, Any]) -> None:
    """Refuses a space that draws a field the study's trials drew from another kind of
    distribution (a choice where they drew a float, another log setting or choices): Optuna
    would refuse each new trial's draw, after creating it. Refuses too a field they drew
    under another name (``gamma`` against ``one_minus_gamma``), which would mix two spaces.

    Raises:
        ConfigError: the first such field (one line).
    """
    import optuna

    drawn_as = {field_of(param): param for param in space}
    for trial in study.get_trials(deepcopy=False):
        for name, old in trial.distributions.items():
            field_ = name.removeprefix(ONE_MINUS)
            if drawn_as.get(field_, name) != name:
                raise ConfigError(
                    f"--space {drawn_as[field_]}: study {study.study_name!r} draws {field_} as "
                    f"{name} (--space rl-zoo3-v2.5: the default before rl-zoo3 v2.6's); search "
                    "it so, or give another --study-name"
                )
            try:
                if name in space:
                    optuna.distributions.check_distribution_compatibility(old, space[name])
            except ValueError as exc:
                raise ConfigError(
                    f"--space {name}: study {study.study_name!r} draws it from {old} ({exc}); "
                    "search it so, or give another --study-name"
                ) from None


def record_heartbeats(storage: Any, study: Any, trials: Sequence[Any]) -> None:
    """Tells ``storage`` (the study's RDBStorage) that ``trials`` are alive, through the
    storage's public methods (an Optuna trial names its storage id only privately)."""
    study_id = storage.get_study_id_from_name(study.study_name)
    for trial in trials:
        storage.record_heartbeat(
            storage.get_trial_id_from_study_id_trial_number(study_id, trial.number)
        )


@contextlib.contextmanager
def heartbeat(storage: Any, study: Any, trials: Sequence[Any]) -> Iterator[None]:
    """Records the trials' heartbeat every :data:`HEARTBEAT_SECONDS` from a thread while the
    block runs (compile, training and evaluation alike), as ``Study.optimize`` does, so that
    only the trials of a process that died go stale."""
    done = threading.Event()

    def beat() -> None:
        while True:
            # a finished trial, or the database busy: the next beat
            with contextlib.suppress(Exception):
                record_heartbeats(storage, study, trials)
            if done.wait(HEARTBEAT_SECONDS):
                return

    thread = threading.Thread(target=beat, daemon=True, name="jaxcart-heartbeat")
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


def heldout_seed(study: Any, seed: int) -> int:
    """A base seed for held-out runs, derived from the search's base ``seed`` (the same one
    every time), such that neither it nor the next one (for a retrain) is the base seed of
    any of the study's trials: seed index i trains from ``fold_in(PRNGKey(base), i)``, so
    another base gives other keys."""
    used = {seed} | {t.user_attrs.get("seed") for t in study.get_trials(deepcopy=False)}
    fresh = zlib.crc32(f"jaxcart heldout {seed}".encode()) % 2**31  # fresh + 1 < 2**32 too
    while fresh in used or fresh + 1 in used:
        fresh += 2
    return fresh


@dataclass
class TrialResult:
    """One finished trial: its number, per-seed scores and where its runs are."""

    number: int
    scores: np.ndarray  # [num_seeds]
    run_dir: Path  # the trial's own run directory (a combination of its batch's sweep)
    pruned: bool = False


@dataclass
class BatchStopped(Exception):
    """A signal stopped a batch; its trials were marked failed."""

    signum: int


@dataclass
class Tuner:
    """Runs a study's batches until it holds ``n_trials`` finished trials.

    Attributes:
        study: an Optuna study, and storage: its RDBStorage (:func:`open_study`).
        space: the search space (:func:`parse_space`).
        spec: the trials' base: config, preset, seeds and base seed.
        out: the folder that holds one run directory per batch group.
        score: what a trial is told (over its seeds: the IQM).
        on_batch: told each group's run directory and its trial results.
        on_wait: told the number of trials running elsewhere when this process starts
            waiting for them (and again when that number changes).
    """

    study: Any
    storage: Any
    space: dict[str, Any]  # Optuna distributions by parameter name
    spec: RunSpec
    out: Path
    options: RunOptions = field(default_factory=RunOptions)
    score: Score = field(default_factory=lambda: Score("auc"))
    hooks: Hooks = field(default_factory=Hooks)
    on_batch: Callable[[Path, list[TrialResult]], None] | None = None
    on_wait: Callable[[int], None] | None = None
    pruned_seconds_saved: float = 0.0

    def run(self, n_trials: int, batch_trials: int) -> int:
        """Asks, trains and tells batches until the study has ``n_trials`` finished (complete
        or pruned) trials. When the trials running elsewhere would finish it, waits for them:
        another process's finish, and a killed process's are marked failed after
        :data:`STALE_GRACE_SECONDS` and asked again. Returns the trials this process finished.

        Raises:
            ConfigError: the space draws a field the study drew otherwise
                (:func:`check_study_space`).
            BatchStopped: a signal stopped a batch (its trials are marked failed, so that a
                later call finishes the study without them).
        """
        check_study_space(self.study, self.space)
        done, waited_for = 0, 0
        while True:
            self._fail_stale_trials()
            states = [t.state.name for t in self.study.get_trials(deepcopy=False)]
            finished = states.count("COMPLETE") + states.count("PRUNED")
            running = states.count("RUNNING") + states.count("WAITING")
            if finished >= n_trials:
                return done
            remaining = n_trials - finished - running
            if remaining > 0:
                done += self._run_batch(self._ask(min(batch_trials, remaining), n_trials))
                continue
            if self.on_wait and running != waited_for:
                self.on_wait(running)
            waited_for = running
            time.sleep(WAIT_SECONDS)

    def _fail_stale_trials(self) -> None:
        """Marks failed the trials of a process that died (Optuna's heartbeat), and removes
        their group's half-trained run directory when it is under :attr:`out` and holds no
        told trial's runs: it would stop ``compare`` and ``plot`` reading the folder, and its
        trials are asked again."""
        import optuna

        trials = self.study.get_trials(deepcopy=False)
        running = {t.number for t in trials if t.state.name == "RUNNING"}
        optuna.storages.fail_stale_trials(self.study)
        stale, kept = set(), set()
        for t in self.study.get_trials(deepcopy=False):
            if "run_dir" in t.user_attrs:
                run_dir = Path(t.user_attrs["run_dir"]).resolve()
                if t.state.name != "FAIL":
                    kept.update((run_dir, *run_dir.parents))
                elif t.number in running:
                    stale.add(run_dir)
        for run_dir in stale - kept:
            if self.out.resolve() in run_dir.parents:
                shutil.rmtree(run_dir, ignore_errors=True)

    def _ask(self, k: int, n_trials: int) -> list[Any]:
        """``k`` new trials; one asked past the study's ``n_trials`` (another process asked at
        the same moment) is told failed at once, marked ``surplus``."""
        import optuna

        trials = []
        for _ in range(k):
            trial = self.study.ask(fixed_distributions=self.space)
            # at once, not when the batch starts: a process killed while asking leaves trials
            # that go stale, rather than trials that run forever
            record_heartbeats(self.storage, self.study, [trial])
            ahead = sum(
                t.number < trial.number and t.state.name != "FAIL"
                for t in self.study.get_trials(deepcopy=False)
            )
            if ahead >= n_trials:
                trial.set_user_attr("surplus", True)
                self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
                break
            trials.append(trial)
        return trials

    def _run_batch(self, trials: list[Any]) -> int:
        """Trains the trials group by group and tells each its IQM over its seeds (a pruned
        trial: pruned); any trial left untold (a signal, an error) is told failed before this
        returns or raises."""
        import optuna

        states = optuna.trial.TrialState
        untold = {t.number: t for t in trials}
        try:
            with heartbeat(self.storage, self.study, trials):
                for spec, out, group in self._groups(trials, self.spec.seed, "trials"):
                    for trial in group:
                        trial.set_user_attr("run_dir", str(out))
                        trial.set_user_attr("seed", spec.seed)  # what held-out seeds must avoid
                    results = self._train(spec, out, group)
                    for trial, result in zip(group, results):
                        value = None
                        if result.run_dir != out:  # trained to its end: scored
                            est = stats.bootstrap_ci(result.scores, stats.iqm)
                            trial.set_user_attr("scores", [float(s) for s in result.scores])
                            trial.set_user_attr("iqm_ci", [est.ci_low, est.ci_high])
                            trial.set_user_attr("run_dir", str(result.run_dir))
                            value = None if result.pruned else est.value
                        state = states.PRUNED if result.pruned else states.COMPLETE
                        self.study.tell(trial, value, state=state)
                        del untold[trial.number]
                    if self.on_batch:
                        self.on_batch(out, results)
        finally:
            for trial in untold.values():
                self.study.tell(trial, state=states.FAIL)
        return len(trials)

    def _groups(self, trials: list[Any], seed: int, prefix: str) -> Iterator[tuple]:
        """``(spec, out, trials)`` for the trials grouped by their shape settings
        (:func:`by_shape`): each group's run is the base config with its shape settings, each
        trial's traced floats an explicit combination, from base seed ``seed``, into a fresh
        ``PREFIX-FIRST-LAST`` directory under :attr:`out` (trial numbers: a study made anew
        numbers its trials from 0 again, and the old one's directories stay)."""
        points = [split_params(t.params) for t in trials]
        for shape, members in by_shape([{**static, **traced} for static, traced in points]):
            combos = tuple(points[i][1] for i in members)
            group = [trials[i] for i in members]
            name = f"{prefix}-{group[0].number:05d}-{group[-1].number:05d}"
            spec = group_spec(self.spec, shape, combinations=combos, seed=seed)
            yield spec, layout.fresh_dir(self.out / name), group

    def _train(self, spec: RunSpec, out: Path, trials: list[Any]) -> list[TrialResult]:
        """One group's ``trials`` trained as the run ``spec`` into ``out``, each scored from
        its combination's directory as ``compare`` scores it, with the pruner asked at each
        rung (:class:`RungReporter`; finished trials, as :meth:`heldout` trains, are never
        pruned). A group whose every trial is pruned stops: its results are the last rung's,
        ``run_dir`` ``out``.

        Raises:
            BatchStopped: a signal stopped the training.
        """
        pruning = RungReporter(trials, spec, self.hooks.on_signal)
        hooks = chain_hooks(self.hooks, Hooks(on_chunk=pruning.on_chunk))
        outcome = run_new(spec, out, self.options, hooks, stop=pruning)
        if pruning.all_pruned:
            self.pruned_seconds_saved += pruning.seconds_saved(outcome)
            if outcome.stopped:  # the group stopped at its last rung
                last = pruning.last_scores
                return [TrialResult(t.number, last[t.number], out, True) for t in trials]
        if outcome.stopped:
            raise BatchStopped(outcome.signum or 15)
        scores = [self.score.of_run(run) for run in load_runs([out])]
        return [
            TrialResult(t.number, s, out / f"combo-{c:03d}", t.number in pruning.pruned)
            for c, (t, s) in enumerate(zip(trials, scores))
        ]

    def heldout(self, trials: list[Any], seed: int) -> list[TrialResult]:
        """Trains finished ``trials`` again from base seed ``seed`` (fresh seeds: see
        :func:`heldout_seed`), :attr:`spec`'s number of seeds each, as their batches trained
        (one program per shape group), each group a sweep-shaped run directory
        ``heldout-SEED-trials-FIRST-LAST`` under :attr:`out` that ``compare`` and ``plot``
        read. Nothing is told to the study.

        Returns:
            Each trial's result (per-seed scores ``[num_seeds]``), group by group.

        Raises:
            BatchStopped: a signal stopped the training.
        """
        groups = self._groups(trials, seed, f"heldout-{seed}-trials")
        return [result for group in groups for result in self._train(*group)]


class RungReporter(StopRequest):
    """At chunk boundaries, reports each trial's partial area under its learning curve
    (:func:`jaxcart.analysis.summary.auc` of the iterations so far, as ``--score auc`` scores
    a whole run; IQM over its seeds) at :data:`RUNGS` evenly spaced iterations, and asks the
    pruner. A pruned trial is marked; when every trial of the group is pruned, the group stops
    (as this stop request, which a signal sets too) and saves the rest of its compute. The
    step reported is the per-mille of training done, so that trials of other shapes (other
    iterations) are compared at the same point. A finished trial (Optuna's ``FrozenTrial``)
    ignores the reports and is never pruned."""

    def __init__(
        self, trials: list[Any], spec: RunSpec, on_signal: Callable[[int], None] | None = None
    ) -> None:
        super().__init__(on_signal)
        self.trials, self.spec = trials, spec
        n = spec.config.num_iterations
        self.rungs = {n * r // RUNGS for r in range(1, RUNGS)} - {0}
        self.returns: list[np.ndarray] = []  # per chunk, [iterations, trials x seeds]
        self.iteration = 0  # the last rung reported
        self.pruned: set[int] = set()
        self.last_scores: dict[int, np.ndarray] = {}  # [num_seeds] by trial number

    @property
    def all_pruned(self) -> bool:
        return len(self.pruned) == len(self.trials)

    def __call__(self) -> bool:
        """``should_stop`` for the training: a signal, or every trial pruned."""
        return self.signum is not None or self.all_pruned

    def on_chunk(self, progress: Progress) -> None:
        """The chunk's returns kept; each rung passed reported."""
        self.returns.append(np.asarray(progress.metrics[RETURN_METRIC], float))
        first = progress.iteration - len(self.returns[-1]) + 1
        for iteration in sorted(self.rungs.intersection(range(first, progress.iteration + 1))):
            self._report(iteration)

    def _report(self, iteration: int) -> None:
        config, step = self.spec.config, 1000 * iteration // self.spec.config.num_iterations
        so_far = np.concatenate(self.returns)[:iteration]
        partial = auc(so_far, config.env).reshape(len(self.trials), self.spec.num_seeds)
        for trial, scores in zip(self.trials, partial):
            self.last_scores[trial.number] = scores
            if trial.number not in self.pruned:
                trial.report(float(stats.iqm(scores)), step=step)
                if trial.should_prune():
                    self.pruned.add(trial.number)
        self.iteration = iteration

    def seconds_saved(self, outcome: Outcome) -> float:
        """The training time the rest of the group's iterations would have taken, at the
        speed its trained ones ran."""
        done, total = self.iteration, self.spec.config.num_iterations
        return outcome.train_seconds / done * (total - done) if done > 0 else 0.0


__all__ = [
    "TrialResult",
    "Tuner",
    "heldout_seed",
    "open_study",
    "parse_space",
]
