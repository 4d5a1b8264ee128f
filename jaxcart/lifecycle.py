"""The run lifecycle as a library: plan a new run or a resume, initialise, checkpoint, train in
chunks with callbacks, gather, evaluate and write the run directory. Nothing here prints.

The command line (:mod:`jaxcart.train`), notebooks and benchmarks all go through it::

    from jaxcart.lifecycle import RunSpec, run_new, resume_run
    outcome = run_new(RunSpec(config=preset("fast"), num_seeds=8), out="runs/fast8")
    outcome.evaluation.solved            # [8] bool, Gymnasium greedy evaluation
    outcome = resume_run("runs/fast8")   # after an interruption

A :class:`Hooks` receives the events (start, compiled, each chunk, divergences, signals);
:class:`jaxcart.report.ConsoleReport` is the one that prints.
"""

from __future__ import annotations

import dataclasses
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import jax
import numpy as np

from jaxcart import checkpoint, devices, distributed, rundir
from jaxcart import sweep as sweeps
from jaxcart.config import ConfigError, PPOConfig
from jaxcart.evaluate import SOLVED_DEFINITION, evaluate_runs, is_solved
from jaxcart.files import RunDirError
from jaxcart.loggers import Logger, LoggerUnavailable, check_available, make_logger
from jaxcart.ppo import Hyperparams
from jaxcart.runlock import RunLock
from jaxcart.signals import Stopped, StopRequest
from jaxcart.trainer import Progress, TrainResult, TrainState, initial_state, train

RESUME_HINT = "python -m jaxcart.train --resume {out}"


def _check(ok: bool, option: str, problem: str) -> None:
    if not ok:
        raise ConfigError(f"{option} {problem}", option=option)


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


@dataclass(frozen=True)
class RunSpec:
    """What a new run trains; ``config.json`` records all of it."""

    config: PPOConfig = field(default_factory=PPOConfig)
    preset: str = "custom"
    """The preset the config started from (a label in config.json and the header)."""
    num_seeds: int = 1
    """Independent seeds (per combination in a sweep)."""
    seed: int = 0
    """Base seed: seed index i uses ``fold_in(PRNGKey(seed), i)``."""
    sweep: dict[str, list[float]] = field(default_factory=dict)
    """Traced float hyperparameter -> values; every combination x seed trains in one program."""

    def __post_init__(self) -> None:
        _check(
            _is_int(self.num_seeds) and self.num_seeds > 0,
            "num_seeds",
            f"must be a positive integer, got {self.num_seeds}",
        )
        _check(
            _is_int(self.seed) and 0 <= self.seed < 2**32,
            "seed",
            f"must be in [0, 2**32), got {self.seed}",
        )
        self.combo_configs()  # every combination valid before anything is created

    @property
    def grid(self) -> sweeps.RunGrid:
        combos = sweeps.combinations(self.sweep) if self.sweep else []
        return sweeps.RunGrid(self.num_seeds, tuple(combos))

    def combo_configs(self) -> list[PPOConfig]:
        """One config per combination (the config alone without a sweep)."""
        if not self.sweep:
            return [self.config]
        return sweeps.validate_combinations(self.config, list(self.grid.combos))


@dataclass(frozen=True)
class RunOptions:
    """How a run is carried out (a resume may choose them anew)."""

    checkpoint_every: float = 30.0
    """Seconds between checkpoints."""
    eval_episodes: int = 20
    """Greedy Gymnasium evaluation episodes per seed."""
    loggers: tuple[str, ...] = ()
    """Metric backends besides metrics.csv: ``tensorboard``, ``swanlab``."""
    compile_cache: bool = True
    """Use JAX's persistent compilation cache."""
    chunk_size: int | None = None
    """Iterations per compiled call between progress reports (default: about 20 reports)."""

    def __post_init__(self) -> None:
        _check(
            _is_int(self.eval_episodes) and self.eval_episodes > 0,
            "eval_episodes",
            f"must be a positive integer, got {self.eval_episodes}",
        )
        _check(
            self.checkpoint_every > 0,
            "checkpoint_every",
            f"must be > 0 seconds, got {self.checkpoint_every}",
        )
        _check(
            self.chunk_size is None or (_is_int(self.chunk_size) and self.chunk_size > 0),
            "chunk_size",
            f"must be a positive integer, got {self.chunk_size}",
        )
        if self.loggers:
            try:
                check_available(self.loggers)
            except LoggerUnavailable as exc:
                raise ConfigError(str(exc)) from None


@dataclass
class Hooks:
    """Callbacks for a run's events; every one is optional."""

    on_start: Callable[[Run, int, str], None] | None = None  # run, device count, backend
    on_compiled: Callable[[float], None] | None = None  # compile seconds
    on_chunk: Callable[[Progress], None] | None = None
    on_diverged: Callable[[str, int], None] | None = None  # run name, iteration
    on_signal: Callable[[int], None] | None = None  # first SIGINT/SIGTERM
    on_init: Callable[[int, int], None] | None = None  # runs initialised so far, of all


@dataclass
class Evaluation:
    """Greedy evaluation of every run, returns ``[R, episodes]``."""

    episodes: int
    gym_returns: np.ndarray  # in gymnasium.make("CartPole-v1")
    jax_returns: np.ndarray  # in jaxcart's env
    seconds: float

    @property
    def solved(self) -> np.ndarray:
        return is_solved(self.gym_returns)


@dataclass
class Outcome:
    """What a call of :func:`run_new` / :func:`resume_run` did."""

    run: Run
    result: TrainResult | None  # None when stopped before training started
    diverged_at: np.ndarray  # [R]: -1, or the iteration where that run went non-finite
    evaluation: Evaluation | None = None  # None when stopped before the outputs were written
    ranking: list[dict] | None = None  # sweeps: the combinations, best first
    signum: int | None = None  # the signal that stopped it (or arrived while writing)
    stopped: bool = False  # stopped before the run directory was complete (resumable)


class Run:
    """One run directory and its lifecycle. Build it with :meth:`create` or :meth:`open`."""

    def __init__(self, out: Path, spec: RunSpec, info: dict, main_process: bool = True) -> None:
        self.out, self.spec, self.info, self.main_process = Path(out), spec, info, main_process
        self.grid = spec.grid
        self.resumed_from: int | None = None  # iteration of the checkpoint resumed from
        self.has_checkpoint = False
        self.lock = RunLock(out)  # held by the main process from create/open to close

    def close(self) -> None:
        """Releases the run directory for other processes."""
        self.lock.release()

    config = property(lambda self: self.spec.config)
    preset = property(lambda self: self.spec.preset)
    sweep = property(lambda self: self.spec.sweep)

    @classmethod
    def create(cls, spec: RunSpec, out: str | Path | None = None, main_process: bool = True) -> Run:
        """A new run directory (refusing a non-empty one) with its ``config.json``."""
        out = Path(out) if out is not None else default_out_dir(spec.preset)
        lock = RunLock(out)
        if main_process:
            prepare_out_dir(out)
            lock.acquire()
        info = {
            "format_version": rundir.FORMAT_VERSION,
            "preset": spec.preset,
            "num_seeds": spec.num_seeds,
            "seed": spec.seed,
            "sweep": spec.sweep,
            "combinations": list(spec.grid.combos),
            "versions": rundir.package_versions(),
            "backend": jax.default_backend(),
            "device_count": jax.device_count(),
        }
        run = cls(out, spec, info, main_process)
        run.lock = lock
        if main_process:
            try:
                rundir.write_json(
                    out / rundir.CONFIG_FILE, {**info, "config": spec.config.to_dict()}
                )
            except BaseException:
                lock.release()
                raise
        return run

    @classmethod
    def open(cls, out: str | Path, main_process: bool = True) -> Run:
        """An existing, unfinished run directory, to resume.

        Raises:
            RunDirError: not a run, unreadable, another package version, or already finished.
        """
        out = Path(out)
        info = rundir.read_run_config(out)
        lock = RunLock(out)
        if main_process:
            lock.acquire()  # before reading the checkpoint another process may be writing
        try:
            run = cls._from_info(out, info, main_process)
        except BaseException:
            lock.release()
            raise
        run.lock = lock
        return run

    @classmethod
    def _from_info(cls, out: Path, info: dict, main_process: bool) -> Run:
        path = out / checkpoint.CHECKPOINT_FILE
        # No checkpoint yet (stopped while starting up): nothing was trained, start at 0.
        meta = checkpoint.read_checkpoint_meta(path) if path.exists() else None
        _check_versions(out, (meta or info).get("versions", {}))
        config = info.pop("config")
        if (
            meta
            and meta["iteration"] >= config.num_iterations
            and (out / rundir.EVALUATION_FILE).exists()
        ):
            raise RunDirError(
                f"{out} already finished all {config.num_iterations} iterations; nothing to resume"
            )
        sweep = {k: list(v) for k, v in info.get("sweep", {}).items()}
        spec = RunSpec(config, info["preset"], int(info["num_seeds"]), int(info["seed"]), sweep)
        run = cls(out, spec, info, main_process)
        run.has_checkpoint = meta is not None
        run.resumed_from = int(meta["iteration"]) if meta else 0
        return run

    def hyperparams(self) -> Hyperparams:
        """Every run's traced hyperparameters, leaves ``[R]``."""
        return sweeps.sweep_hyperparams(self.spec.combo_configs(), self.grid)

    def initial_state(
        self, chunk_size: int | None = None, on_progress: Callable[[int, int], None] | None = None
    ) -> TrainState:
        """The checkpoint's state when there is one; else a fresh state, saved at once as the
        iteration-0 checkpoint so that a run killed at any moment can be resumed.
        ``on_progress(done, total)`` follows the initialisation of large runs."""
        grid = self.grid
        if self.has_checkpoint:  # a one-run template names the arrays; the file has them all
            template = initial_state(self.config, 1, self.spec.seed, chunk_size=chunk_size)
            path = self.out / checkpoint.CHECKPOINT_FILE
            return checkpoint.load_checkpoint(path, template, num_runs=grid.num_runs)
        fresh = initial_state(
            self.config,
            grid.num_runs,
            self.spec.seed,
            self.hyperparams(),
            chunk_size=chunk_size,
            seed_indices=grid.seed_indices(),
            on_progress=on_progress,
        )
        self.save_checkpoint(fresh)
        self.has_checkpoint = True
        return fresh

    def save_checkpoint(self, state: TrainState) -> None:
        """Every process takes part in gathering the state; process 0 writes it."""
        arrays = distributed.gather({"runners": state.runners, "hyperparams": state.hyperparams})
        if not self.main_process:
            return
        gathered = dataclasses.replace(
            state, runners=arrays["runners"], hyperparams=arrays["hyperparams"]
        )
        meta = {
            "num_runs": self.grid.num_runs,
            "config": self.config.to_dict(),
            "versions": _package_versions(),
        }
        checkpoint.save_checkpoint(self.out / checkpoint.CHECKPOINT_FILE, gathered, meta)

    def train(
        self, options: RunOptions, hooks: Hooks, should_stop: Callable[[], bool] | None = None
    ) -> TrainResult:
        """Trains from :meth:`initial_state` to the end (or until ``should_stop``), logging
        metrics and checkpointing every ``options.checkpoint_every`` seconds.

        Raises:
            Stopped: ``should_stop`` turned true during the initialisation.
        """

        def on_progress(done: int, total: int) -> None:
            if should_stop is not None and should_stop():
                raise Stopped("initialisation interrupted")
            if hooks.on_init:
                hooks.on_init(done, total)

        state = self.initial_state(options.chunk_size, on_progress)
        loggers = list(options.loggers) if self.main_process else []
        logger = make_logger(
            loggers, self.out, self.grid.run_names(), {**self.info, "config": self.config.to_dict()}
        )
        handler = _ChunkHandler(self, options, hooks, logger)
        try:
            return train(
                self.config,
                self.grid.num_runs,
                self.spec.seed,
                resume=state,
                seed_indices=self.grid.seed_indices(),
                on_compiled=hooks.on_compiled,
                on_chunk=handler,
                should_stop=should_stop,
            )
        finally:
            logger.close()

    def evaluate(self, params: dict, episodes: int, stop: StopRequest | None = None) -> Evaluation:
        """Greedy returns of every run in Gymnasium's CartPole-v1 and in jaxcart (raises
        :class:`~jaxcart.signals.Stopped` when ``stop`` is requested meanwhile)."""
        start = time.perf_counter()
        gym_returns, jax_returns = evaluate_runs(
            params,
            self.config,
            self.spec.seed,
            self.grid.seed_indices(),
            episodes,
            should_stop=stop,
        )
        return Evaluation(episodes, gym_returns, jax_returns, time.perf_counter() - start)

    def write_outputs(
        self, result: TrainResult, params: dict, evaluation: Evaluation, diverged_at: np.ndarray
    ) -> list[dict] | None:
        """metrics.csv, params.npz and evaluation.json (per combination for a sweep, with
        its own config.json, and sweep.json ranking them). Returns the ranking of a sweep.

        ``params`` are every run's parameters gathered to the host, leaves ``[R, ...]``.
        """
        timing = {
            "compile_seconds": result.compile_seconds,
            "train_seconds": result.state.elapsed,
            "eval_seconds": evaluation.seconds,
            "devices": result.num_devices,
        }
        configs = self.spec.combo_configs()
        for c, combo in enumerate(self.grid.combos or ({},)):
            directory = rundir.combo_dir(self.out, c) if self.grid.is_sweep else self.out
            runs = self.grid.runs_of(c)
            directory.mkdir(parents=True, exist_ok=True)
            if combo:
                info = {**self.info, "combination": combo, "sweep": {}, "combinations": []}
                rundir.write_json(
                    directory / rundir.CONFIG_FILE, {**info, "config": configs[c].to_dict()}
                )
            metrics = {k: v[:, runs] for k, v in result.metrics.items()}
            rundir.write_metrics_csv(
                directory / rundir.METRICS_FILE, metrics, self.config.batch_size
            )
            rundir.save_params(directory / rundir.PARAMS_FILE, _take(params, runs))
            record = evaluation_record(
                evaluation, runs, metrics["rollout/ep_rew_mean"][-1], diverged_at[runs]
            )
            rundir.write_json(directory / rundir.EVALUATION_FILE, {**record, **timing})
        return self._write_ranking(result, evaluation, diverged_at) if self.grid.is_sweep else None

    def _write_ranking(
        self, result: TrainResult, evaluation: Evaluation, diverged_at: np.ndarray
    ) -> list[dict]:
        steps = np.arange(1, self.config.num_iterations + 1) * self.config.batch_size
        ranking = sweeps.rank(
            self.grid,
            evaluation.gym_returns.mean(-1),
            evaluation.solved,
            result.metrics["rollout/ep_rew_mean"][-1],
            sweeps.first_reach(result.metrics["rollout/ep_rew_max"], steps),
            diverged_at,
        )
        data = {"sweep": self.sweep, "num_seeds": self.grid.num_seeds, "ranking": ranking}
        rundir.write_json(self.out / rundir.SWEEP_FILE, data)
        return ranking


def _take(params: dict, runs: slice) -> dict:
    return jax.tree.map(lambda x: x[runs], params)


def evaluation_record(
    evaluation: Evaluation, runs: slice, final_return: np.ndarray, diverged_at: np.ndarray
) -> dict:
    """``evaluation.json`` of one run directory (the seeds in ``runs``)."""
    g, j, solved = (
        evaluation.gym_returns[runs],
        evaluation.jax_returns[runs],
        evaluation.solved[runs],
    )
    seeds = [
        {
            "seed_index": s,
            "gymnasium_returns": g[s].tolist(),
            "gymnasium_mean": float(g[s].mean()),
            "gymnasium_min": float(g[s].min()),
            "solved": bool(solved[s]),
            "jaxcart_returns": j[s].tolist(),
            "jaxcart_mean": float(j[s].mean()),
            "final_ep_rew_mean": float(final_return[s]),
            "diverged_at_iteration": int(diverged_at[s]) if diverged_at[s] >= 0 else None,
        }
        for s in range(len(g))
    ]
    return {
        "episodes": evaluation.episodes,
        "solved_definition": SOLVED_DEFINITION.format(episodes=evaluation.episodes),
        "seeds": seeds,
        "solved_seeds": int(solved.sum()),
    }


class _ChunkHandler:
    """What happens after every chunk: loggers, periodic checkpoints, divergence reports,
    then the caller's ``on_chunk``."""

    def __init__(self, run: Run, options: RunOptions, hooks: Hooks, logger: Logger) -> None:
        self.run, self.options, self.hooks, self.logger = run, options, hooks, logger
        self.last_save = time.monotonic()
        self.reported: set[int] = set()

    def __call__(self, progress: Progress) -> None:
        run = self.run
        new = [
            int(r) for r in np.flatnonzero(progress.diverged_at >= 0) if int(r) not in self.reported
        ]
        self.reported.update(new)
        if self.hooks.on_diverged and run.main_process:
            for r in new:
                self.hooks.on_diverged(run.grid.run_name(r), int(progress.diverged_at[r]))
        count = len(progress.metrics["time/fps"])
        first = progress.iteration - count
        steps = (first + 1 + np.arange(count)) * run.config.batch_size
        self.logger.log(first, steps, progress.metrics)
        due = time.monotonic() - self.last_save >= self.options.checkpoint_every
        due = distributed.any_process(due)  # every process must agree on when to gather
        if due and progress.iteration < run.config.num_iterations:
            run.save_checkpoint(progress.state())
            self.last_save = time.monotonic()
        if self.hooks.on_chunk:
            self.hooks.on_chunk(progress)


def _package_versions() -> dict[str, str]:
    """The package versions, looked up once per process (recorded in every checkpoint)."""
    global _versions
    if _versions is None:
        _versions = rundir.package_versions()
    return _versions


_versions: dict[str, str] | None = None


def _check_versions(out: Path, saved: dict) -> None:
    """A run continues bit-identically only with the packages that started it."""
    now = _package_versions()
    for name in ("jaxcart", "jax", "jaxlib"):
        if saved.get(name) != now[name]:
            raise RunDirError(
                f"{out} was trained with {name} {saved.get(name)}, this is {now[name]}; "
                f"reinstall {name}=={saved.get(name)} to continue it bit-identically"
            )


def default_out_dir(preset_name: str) -> Path:
    """``runs/<preset>-<YYYYmmdd-HHMMSS>``, suffixed when that exists already."""
    base = Path("runs") / f"{preset_name}-{time.strftime('%Y%m%d-%H%M%S')}"
    out, n = base, 1
    while out.exists():
        n += 1
        out = base.with_name(f"{base.name}-{n}")
    return out


def prepare_out_dir(out: Path) -> Path:
    """Creates ``out``; refuses a non-empty or unwritable one with a clear message."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a directory; choose another path")
    # leftovers of a run killed while writing its first file do not count
    if out.is_dir() and any(
        not (p.name.startswith(".") and p.name.endswith(".tmp")) for p in out.iterdir()
    ):
        raise ConfigError(
            f"--out {out} is not empty; choose a new directory so no earlier run is "
            f"overwritten (or continue it with --resume {out})"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    return out


def start_distributed(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
) -> None:
    """Joins a ``jax.distributed`` run (before any JAX work); a failure is a ConfigError."""
    try:
        distributed.initialize(coordinator_address, num_processes, process_id)
    except (ValueError, TypeError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"cannot start jax.distributed: {first}") from None


def run_new(
    spec: RunSpec,
    out: str | Path | None = None,
    options: RunOptions | None = None,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
) -> Outcome:
    """Creates a run directory for ``spec`` and carries the run out (see :func:`carry_out`)."""
    options = options or RunOptions()
    if options.compile_cache:
        devices.enable_compilation_cache()
    run = Run.create(spec, out, main_process=distributed.is_main_process())
    return carry_out(run, options, hooks, stop)


def resume_run(
    out: str | Path,
    options: RunOptions | None = None,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
) -> Outcome:
    """Continues an interrupted run from its last checkpoint, bit-identically."""
    options = options or RunOptions()
    if options.compile_cache:
        devices.enable_compilation_cache()
    run = Run.open(out, main_process=distributed.is_main_process())
    return carry_out(run, options, hooks, stop)


def carry_out(
    run: Run, options: RunOptions, hooks: Hooks | None = None, stop: StopRequest | None = None
) -> Outcome:
    """Trains, then evaluates every run and writes the run directory; holds the run's lock
    throughout and releases it at the end.

    SIGINT and SIGTERM (handled here unless the caller passes its own ``stop``) stop at the
    next safe point: the state is checkpointed and the outcome is ``stopped``, resumable.
    A stopped run keeps its checkpoint and a partial metrics.csv.
    """
    hooks = hooks or Hooks()
    stop = stop or StopRequest(hooks.on_signal)
    try:
        with stop.installed():
            return _carry_out(run, options, hooks, stop)
    finally:
        run.close()


def _carry_out(run: Run, options: RunOptions, hooks: Hooks, stop: StopRequest) -> Outcome:
    if hooks.on_start:
        hooks.on_start(run, jax.device_count(), jax.default_backend())
    try:
        result = run.train(options, hooks, should_stop=stop)
    except Stopped:  # during initialisation: the checkpoint on disk (if any) is untouched
        runs = np.full(run.grid.num_runs, -1)
        return Outcome(run, None, runs, signum=stop.signum or signal.SIGTERM, stopped=True)
    run.save_checkpoint(result.state)
    diverged_at = np.asarray(distributed.gather(result.state.runners.diverged_at))
    outcome = Outcome(run, result, diverged_at, signum=stop.signum, stopped=result.stopped)
    params = None if result.stopped else distributed.gather(result.params)
    if run.main_process and not result.stopped:
        try:
            stop.check()
            outcome.evaluation = run.evaluate(params, options.eval_episodes, stop)
        except Stopped:
            outcome.stopped = True
    if outcome.stopped:  # what there is so far, and a resumable state
        if run.main_process:
            metrics_path = run.out / rundir.METRICS_FILE
            rundir.write_metrics_csv(metrics_path, result.metrics, run.config.batch_size)
        outcome.signum = stop.signum or signal.SIGTERM  # another process may have been signalled
        return outcome
    if run.main_process:
        outcome.ranking = run.write_outputs(result, params, outcome.evaluation, diverged_at)
    return outcome  # signum set when a signal came while writing: the run finished all the same
