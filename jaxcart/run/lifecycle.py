"""The run lifecycle as a library: plan a new run or a resume, initialise, checkpoint, train in
chunks with callbacks, gather, evaluate and write the run directory. Nothing here prints.

The command line (:mod:`jaxcart.train`), notebooks and benchmarks all go through it::

    from jaxcart.run.lifecycle import RunSpec, run_new, resume_run
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

from jaxcart.core.config import ConfigError, PPOConfig
from jaxcart.core.solved import NUM_EVAL_EPISODES, is_solved
from jaxcart.core.tricks import Hyperparams
from jaxcart.engine import devices, distributed
from jaxcart.engine.signals import Stopped, StopRequest
from jaxcart.engine.trainer import Progress, TrainResult, TrainState, initial_state, train
from jaxcart.run import sweep as sweeps
from jaxcart.run.evaluation import evaluate_runs
from jaxcart.run.loggers import Logger, LoggerUnavailable, check_available, make_logger
from jaxcart.run.waves import WavePlan, available_bytes, bytes_per_run, plan_waves
from jaxcart.rundir import checkpoint, files, outputs
from jaxcart.rundir import layout as rundir
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.lock import RunLock

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
    eval_episodes: int | None = None
    """Greedy Gymnasium evaluation episodes per seed (None: 20, or a resumed run's own)."""
    loggers: tuple[str, ...] = ()
    """Metric backends besides metrics.csv: ``tensorboard``, ``swanlab``."""
    compile_cache: bool = True
    """Use JAX's persistent compilation cache."""
    chunk_size: int | None = None
    """Iterations per compiled call between progress reports (default: about 20 reports)."""

    def __post_init__(self) -> None:
        _check(
            self.eval_episodes is None or (_is_int(self.eval_episodes) and self.eval_episodes > 0),
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
    on_wave: Callable[[int, int, range], None] | None = None  # wave, of how many, its runs


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


class Run:
    """One run directory and its lifecycle. Build it with :meth:`create` or :meth:`open`."""

    def __init__(self, out: Path, spec: RunSpec, info: dict, main_process: bool = True) -> None:
        self.out, self.spec, self.info, self.main_process = Path(out), spec, info, main_process
        self.grid = spec.grid
        self.resumed_from: int | None = None  # iteration of the checkpoint resumed from
        self.checkpoint_meta: dict | None = None  # of the checkpoint on disk, when there is one
        self.resume_wave = 0  # the wave a resume continues with
        self.plan = WavePlan(self.grid.num_runs, info.get("wave_size") or self.grid.num_runs, 0, 0)
        self.lock = RunLock(out)  # held by the main process from create/open to close

    def close(self) -> None:
        """Releases the run directory for other processes."""
        self.lock.release()

    config = property(lambda self: self.spec.config)
    preset = property(lambda self: self.spec.preset)
    sweep = property(lambda self: self.spec.sweep)

    @classmethod
    def create(
        cls,
        spec: RunSpec,
        out: str | Path | None = None,
        main_process: bool = True,
        plan: WavePlan | None = None,
        extra: dict | None = None,
    ) -> Run:
        """A new run directory (refusing a non-empty one) with its ``config.json``.

        ``plan`` says how many runs train at once (default: as many as fit in memory);
        ``extra`` is recorded in config.json too (the command line, evaluation episodes).
        """
        plan = plan or plan_waves(spec.config, spec.grid.num_runs, jax.device_count())
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
            "wave_size": plan.wave_size,
            **(extra or {}),
        }
        run = cls(out, spec, info, main_process)
        run.plan, run.lock = plan, lock
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
    def open(cls, out: str | Path, main_process: bool = True, extend_to: int | None = None) -> Run:
        """An existing, unfinished run directory, to resume; or, with ``extend_to`` env steps
        per seed, an interrupted or finished one to train further.

        Raises:
            RunDirError: not a run, unreadable, another package version, or already finished.
            ConfigError: an extension that cannot be done (annealed learning rate, fewer
                steps, a run trained in waves).
        """
        out = Path(out)
        info = rundir.read_run_config(out)
        lock = RunLock(out)
        if main_process:
            lock.acquire()  # before reading the checkpoint another process may be writing
        try:
            if extend_to is not None:
                info = _extend(out, info, extend_to)
            run = cls._from_info(out, dict(info), main_process)
            if extend_to is not None and main_process:
                rundir.write_json(
                    out / rundir.CONFIG_FILE, {**info, "config": run.config.to_dict()}
                )
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
        if run.plan.num_waves > 1:  # the plan it was started with, and today's estimate
            per_run = bytes_per_run(config)
            run.plan = WavePlan(run.grid.num_runs, run.plan.wave_size, per_run, available_bytes())
        run.checkpoint_meta = meta
        run.resume_wave = run.first_unfinished_wave()
        same_wave = meta is not None and meta.get("wave", 0) == run.resume_wave
        run.resumed_from = int(meta["iteration"]) if same_wave else 0
        return run

    def first_unfinished_wave(self) -> int:
        """The first wave without a saved block (0 for a run trained in one wave)."""
        waves = self.plan.num_waves
        if waves == 1:
            return 0
        return next(
            (w for w in range(waves) if not outputs.block_path(self.out, w).exists()), waves
        )

    def hyperparams(self) -> Hyperparams:
        """Every run's traced hyperparameters, leaves ``[R]``."""
        return sweeps.sweep_hyperparams(self.spec.combo_configs(), self.grid)

    def initial_state(
        self,
        runs: range,
        wave: int = 0,
        chunk_size: int | None = None,
        on_progress: Callable[[int, int], None] | None = None,
    ) -> TrainState:
        """The state of ``runs`` (wave ``wave``) from the checkpoint when it holds that wave;
        else a fresh state, saved at once as the wave's iteration-0 checkpoint, so that a run
        killed at any moment can be resumed. ``on_progress(done, total)`` follows the
        initialisation of large runs."""
        meta = self.checkpoint_meta
        if meta is not None and meta.get("wave", 0) == wave:
            # a one-run template names the arrays; the file has them all
            template = initial_state(self.config, 1, self.spec.seed, chunk_size=chunk_size)
            path = self.out / checkpoint.CHECKPOINT_FILE
            return checkpoint.load_checkpoint(path, template, num_runs=len(runs))
        hps = jax.tree.map(lambda x: x[runs.start : runs.stop], self.hyperparams())
        fresh = initial_state(
            self.config,
            len(runs),
            self.spec.seed,
            hps,
            chunk_size=chunk_size,
            seed_indices=self.grid.seed_indices()[runs.start : runs.stop],
            on_progress=on_progress,
        )
        self.save_checkpoint(fresh, wave)
        return fresh

    def save_checkpoint(self, state: TrainState, wave: int = 0) -> None:
        """Every process takes part in gathering the state; process 0 writes it."""
        arrays = distributed.gather({"runners": state.runners, "hyperparams": state.hyperparams})
        if not self.main_process:
            return
        gathered = dataclasses.replace(
            state, runners=arrays["runners"], hyperparams=arrays["hyperparams"]
        )
        meta = {
            "num_runs": len(arrays["runners"].diverged_at),
            "wave": wave,
            "config": self.config.to_dict(),
            "versions": _package_versions(),
        }
        checkpoint.save_checkpoint(self.out / checkpoint.CHECKPOINT_FILE, gathered, meta)
        self.checkpoint_meta = {**meta, "iteration": state.iteration}

    def train(
        self,
        options: RunOptions,
        hooks: Hooks,
        should_stop: Callable[[], bool] | None = None,
        runs: range | None = None,
        wave: int = 0,
    ) -> TrainResult:
        """Trains ``runs`` (default: all; wave ``wave`` of the plan) from
        :meth:`initial_state` to the end or until ``should_stop``, logging metrics and
        checkpointing every ``options.checkpoint_every`` seconds.

        Raises:
            Stopped: ``should_stop`` turned true during the initialisation.
        """
        runs = runs if runs is not None else range(self.grid.num_runs)

        def on_progress(done: int, total: int) -> None:
            if should_stop is not None and should_stop():
                raise Stopped("initialisation interrupted")
            if hooks.on_init:
                hooks.on_init(done, total)

        state = self.initial_state(runs, wave, options.chunk_size, on_progress)
        names = [self.grid.run_name(r) for r in runs]
        loggers = list(options.loggers) if self.main_process else []
        info = {**self.info, "config": self.config.to_dict()}
        logger = make_logger(loggers, self.out, names, info)
        handler = _ChunkHandler(self, options, hooks, logger, runs, wave)
        try:
            return train(
                self.config,
                len(runs),
                self.spec.seed,
                resume=state,
                on_compiled=hooks.on_compiled,
                on_chunk=handler,
                should_stop=should_stop,
            )
        finally:
            logger.close()

    def evaluate(
        self,
        params: dict,
        episodes: int,
        runs: range | None = None,
        stop: StopRequest | None = None,
    ) -> Evaluation:
        """Greedy returns of ``runs`` (default all) in Gymnasium's CartPole-v1 and in jaxcart
        (raises :class:`~jaxcart.engine.signals.Stopped` when ``stop`` is requested meanwhile)."""
        runs = runs if runs is not None else range(self.grid.num_runs)
        start = time.perf_counter()
        gym_returns, jax_returns = evaluate_runs(
            params,
            self.config,
            self.spec.seed,
            self.grid.seed_indices()[runs.start : runs.stop],
            episodes,
            should_stop=stop,
        )
        return Evaluation(episodes, gym_returns, jax_returns, time.perf_counter() - start)

    def write_outputs(self, blocks: list, episodes: int, timing: dict) -> None:
        """metrics.csv, params.npz and evaluation.json from the runs' blocks (per
        combination for a sweep, with its own config.json; :meth:`write_ranking` adds
        sweep.json)."""
        configs = self.spec.combo_configs()
        for c, combo in enumerate(self.grid.combos or ({},)):
            directory = rundir.combo_dir(self.out, c) if self.grid.is_sweep else self.out
            directory.mkdir(parents=True, exist_ok=True)
            runs = self.grid.runs_of(c)
            runs = range(runs.start, runs.stop)
            if combo:
                info = {**self.info, "combination": combo, "sweep": {}, "combinations": []}
                config = configs[c].to_dict()
                rundir.write_json(directory / rundir.CONFIG_FILE, {**info, "config": config})
            batch = self.config.batch_size
            outputs.write_metrics_csv(directory / rundir.METRICS_FILE, blocks, runs, batch)
            outputs.write_params(directory / rundir.PARAMS_FILE, blocks, runs)
            path = directory / rundir.EVALUATION_FILE
            outputs.write_evaluation(path, blocks, runs, episodes, timing)

    def write_ranking(
        self,
        evaluation: Evaluation,
        final_return: np.ndarray,
        steps_to_500: np.ndarray,
        diverged_at: np.ndarray,
    ) -> list[dict]:
        """``sweep.json``: the combinations ranked by IQM (per-run arrays ``[R]``)."""
        score, solved = evaluation.gym_returns.mean(-1), evaluation.solved
        ranking = sweeps.rank(self.grid, score, solved, final_return, steps_to_500, diverged_at)
        data = {"sweep": self.sweep, "num_seeds": self.grid.num_seeds, "ranking": ranking}
        rundir.write_json(self.out / rundir.SWEEP_FILE, data)
        return ranking


class _ChunkHandler:
    """What happens after every chunk: loggers, periodic checkpoints, divergence reports,
    then the caller's ``on_chunk``."""

    def __init__(
        self, run: Run, options: RunOptions, hooks: Hooks, logger: Logger, runs: range, wave: int
    ) -> None:
        self.run, self.options, self.hooks, self.logger = run, options, hooks, logger
        self.runs, self.wave = runs, wave  # progress.diverged_at is indexed within the wave
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
                name = run.grid.run_name(self.runs.start + r)
                self.hooks.on_diverged(name, int(progress.diverged_at[r]))
        count = len(progress.metrics["time/fps"])
        first = progress.iteration - count
        steps = (first + 1 + np.arange(count)) * run.config.batch_size
        self.logger.log(first, steps, progress.metrics)
        due = time.monotonic() - self.last_save >= self.options.checkpoint_every
        due = distributed.any_process(due)  # every process must agree on when to gather
        if due and progress.iteration < run.config.num_iterations:
            run.save_checkpoint(progress.state(), self.wave)
            self.last_save = time.monotonic()
        if self.hooks.on_chunk:
            self.hooks.on_chunk(progress)


def _extend(out: Path, info: dict, total_timesteps: int) -> dict:
    """``config.json``'s contents for a run extended to ``total_timesteps`` env steps per
    seed."""
    config = info["config"]
    if config.anneal_lr:
        raise ConfigError(
            f"cannot extend {out}: its learning rate anneals to 0 at its last iteration "
            "(anneal_lr), so there is no schedule to continue; start a new run instead"
        )
    if (info.get("wave_size") or info.get("num_seeds")) < info.get("num_seeds", 1) * max(
        1, len(info.get("combinations", []))
    ):
        raise ConfigError(f"cannot extend {out}: it trained in waves, which keep no final state")
    extended = dataclasses.replace(config, total_timesteps=total_timesteps)
    if extended.num_iterations <= config.num_iterations:
        raise ConfigError(
            f"--total-timesteps {total_timesteps:,} does not extend {out}: it already trains "
            f"{config.env_steps_per_seed:,} env steps per seed"
        )
    history = [*info.get("extended_from", []), config.total_timesteps]
    return {**info, "config": extended, "extended_from": history}


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


def replay_seed(run_dir: str | Path, seed_index: int, combination: int = 0) -> TrainResult:
    """Trains one seed of a run again, alone, bit-identical to how it trained in its batch:
    the seed is padded to the per-device batch width it had (the padding is discarded).

    Needs the run's device count (``XLA_FLAGS=--xla_force_host_platform_device_count=N``)
    and package versions; costs that width's compute, not one seed's.

    Raises:
        RunDirError: not a run, or another device count.
        ConfigError: a seed index or combination out of range.
    """
    info = rundir.read_run_config(run_dir)
    spec = RunSpec(
        info["config"],
        info["preset"],
        int(info["num_seeds"]),
        int(info["seed"]),
        {k: list(v) for k, v in info.get("sweep", {}).items()},
    )
    grid, devices_now = spec.grid, jax.device_count()
    if info.get("device_count") != devices_now:
        raise RunDirError(
            f"{run_dir} trained on {info.get('device_count')} device(s), this process has "
            f"{devices_now}; set XLA_FLAGS=--xla_force_host_platform_device_count="
            f"{info.get('device_count')} to replay it"
        )
    _check(0 <= seed_index < grid.num_seeds, "seed_index", f"must be in [0, {grid.num_seeds})")
    _check(0 <= combination < grid.num_combos, "combination", f"must be in [0, {grid.num_combos})")
    run = grid.run_index(combination, seed_index)
    plan = WavePlan(grid.num_runs, int(info.get("wave_size") or grid.num_runs), 0, 0)
    wave = len(plan.wave(run // plan.wave_size))
    used = min(devices_now, wave)  # fewer runs than devices trained on that many devices
    config = spec.combo_configs()[combination]
    hps = sweeps.sweep_hyperparams([config], sweeps.RunGrid(1))
    return train(
        config,
        1,
        spec.seed,
        hyperparams=hps,
        seed_indices=np.array([seed_index]),
        devices=jax.devices()[:used],
        runs_per_device=-(-wave // used),
    )


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
    command: list[str] | None = None,
) -> Outcome:
    """Creates a run directory for ``spec`` and carries the run out (see :func:`carry_out`).

    The runs train in waves when they do not all fit in memory (:mod:`jaxcart.run.waves`);
    ``command`` (the command line, when there is one) is recorded in ``config.json``.
    """
    options = options or RunOptions()
    if options.compile_cache:
        devices.enable_compilation_cache()
    episodes = options.eval_episodes or NUM_EVAL_EPISODES
    options = dataclasses.replace(options, eval_episodes=episodes)
    plan = plan_waves(spec.config, spec.grid.num_runs, jax.device_count(), episodes)
    if stop is not None:
        stop.check()
    extra = {"eval_episodes": episodes, **({"command": list(command)} if command else {})}
    run = Run.create(spec, out, distributed.is_main_process(), plan, extra)
    return carry_out(run, options, hooks, stop)


def resume_run(
    out: str | Path,
    options: RunOptions | None = None,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
    total_timesteps: int | None = None,
) -> Outcome:
    """Continues an interrupted run from its last checkpoint, bit-identically; with
    ``total_timesteps``, extends an interrupted or finished run to that many env steps per
    seed (constant learning rates only), as SB3's ``learn(more, reset_num_timesteps=False)``.
    """
    options = options or RunOptions()
    if options.compile_cache:
        devices.enable_compilation_cache()
    if stop is not None:
        stop.check()
    run = Run.open(out, main_process=distributed.is_main_process(), extend_to=total_timesteps)
    recorded = run.info.get("eval_episodes")
    if recorded and options.eval_episodes and options.eval_episodes != recorded:
        run.close()
        raise ConfigError(
            f"{out} evaluates {recorded} episodes per seed (config.json); drop --eval-episodes",
        )
    episodes = options.eval_episodes or recorded or NUM_EVAL_EPISODES
    return carry_out(run, dataclasses.replace(options, eval_episodes=episodes), hooks, stop)


def carry_out(
    run: Run, options: RunOptions, hooks: Hooks | None = None, stop: StopRequest | None = None
) -> Outcome:
    """Trains (wave by wave), evaluates every run and writes the run directory; holds the
    run's lock throughout and releases it at the end.

    SIGINT and SIGTERM (handled here unless the caller passes its own ``stop``) stop at the
    next safe point: the state is checkpointed and the outcome is ``stopped``, resumable.
    A stopped run keeps its checkpoint (and, trained in one wave, a partial metrics.csv).
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
    outcome = Outcome(run, None, num_devices=jax.device_count())
    blocks: list = []
    num_waves = run.plan.num_waves
    for wave, runs in enumerate(run.plan.waves()):
        path = outputs.block_path(run.out, wave)
        if num_waves > 1 and path.exists():
            blocks.append(path)  # finished before an interruption
            continue
        if hooks.on_wave:
            hooks.on_wave(wave, num_waves, runs)
        block = _train_wave(run, options, hooks, stop, outcome, runs, wave)
        if block is None:
            meta = run.checkpoint_meta or {}
            same_wave = meta.get("wave", 0) == wave
            outcome.stopped_at = (wave, int(meta.get("iteration", 0)) if same_wave else 0)
            outcome.stopped = True
            outcome.signum = (
                stop.signum or signal.SIGTERM
            )  # another process may have been signalled
            return outcome
        if num_waves > 1 and run.main_process:
            path.parent.mkdir(exist_ok=True)
            block.save(path)
            blocks.append(path)
        else:
            blocks.append(block)
    if run.main_process:
        _finish(run, blocks, options.eval_episodes, outcome)
    return outcome  # signum set when a signal came while writing: the run finished all the same


def _train_wave(
    run: Run,
    options: RunOptions,
    hooks: Hooks,
    stop: StopRequest,
    outcome: Outcome,
    runs: range,
    wave: int,
) -> outputs.Block | None:
    """Trains and evaluates one wave; None when stopped (its state checkpointed)."""
    try:
        result = run.train(options, hooks, should_stop=stop, runs=runs, wave=wave)
    except Stopped:  # during initialisation: the checkpoint on disk (if any) is untouched
        return None
    outcome.result, outcome.num_devices = result, result.num_devices
    outcome.compile_seconds += result.compile_seconds
    outcome.train_seconds += result.run_seconds
    outcome.env_steps += result.env_steps
    run.save_checkpoint(result.state, wave)
    diverged = np.asarray(distributed.gather(result.state.runners.diverged_at))
    if result.stopped:
        if run.main_process and run.plan.num_waves == 1:
            path = run.out / rundir.METRICS_FILE
            rundir.write_metrics_csv(path, result.metrics, run.config.batch_size)
        return None
    params = distributed.gather(result.params)
    evaluation = Evaluation(
        options.eval_episodes, np.zeros((len(runs), 0)), np.zeros((len(runs), 0)), 0.0
    )
    if run.main_process:
        try:
            stop.check()
            evaluation = run.evaluate(params, options.eval_episodes, runs, stop)
        except Stopped:
            return None
    timing = {
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.state.elapsed,
        "eval_seconds": evaluation.seconds,
    }
    return outputs.Block(
        runs.start,
        runs.stop,
        files.flatten(params),
        result.metrics,
        diverged,
        evaluation.gym_returns,
        evaluation.jax_returns,
        timing,
    )


def _finish(run: Run, blocks: list, episodes: int, outcome: Outcome) -> None:
    """The run directory's outputs and the outcome's per-run summary, from every block."""
    config = run.config
    steps = np.arange(1, config.num_iterations + 1) * config.batch_size
    columns: dict[str, list] = {k: [] for k in ("gym", "jax", "div", "final", "reach")}
    timing = {"compile_seconds": 0.0, "train_seconds": 0.0, "eval_seconds": 0.0}
    for block, take in outputs._overlapping(blocks, range(run.grid.num_runs)):
        columns["gym"].append(block.gym_returns[take])
        columns["jax"].append(block.jax_returns[take])
        columns["div"].append(block.diverged_at[take])
        columns["final"].append(block.metrics["rollout/ep_rew_mean"][-1, take])
        reached = sweeps.first_reach(block.metrics["rollout/ep_rew_max"][:, take], steps)
        columns["reach"].append(reached)
        for k in timing:
            timing[k] += float(block.timing.get(k, 0.0))
    gym, jax_returns, div, final, reach = (np.concatenate(columns[k]) for k in columns)
    outcome.evaluation = Evaluation(episodes, gym, jax_returns, timing["eval_seconds"])
    outcome.diverged_at, outcome.final_return = div, final
    run.write_outputs(
        blocks, episodes, {**timing, "devices": outcome.num_devices, "waves": len(blocks)}
    )
    if run.grid.is_sweep:
        outcome.ranking = run.write_ranking(outcome.evaluation, final, reach, div)
