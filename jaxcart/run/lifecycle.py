"""The run lifecycle as a library: plan a new run or a resume, then carry it out: train
(wave by wave when the runs do not fit in memory at once), evaluate and write the run
directory. Nothing here prints.

The command line (:mod:`jaxcart.train`), notebooks and benchmarks all go through it::

    from jaxcart.run.lifecycle import run_new, resume_run
    from jaxcart.run.spec import RunSpec
    outcome = run_new(RunSpec(config=preset("fast"), num_seeds=8), out="runs/fast8")
    outcome.evaluation.solved            # [8] bool, Gymnasium greedy evaluation
    outcome = resume_run("runs/fast8")   # after an interruption

A :class:`~jaxcart.run.spec.Hooks` receives the events (start, compiled, each chunk,
divergences, signals); :class:`jaxcart.report.ConsoleReport` is the one that prints. The
values (:class:`~jaxcart.run.spec.RunSpec`, ...) are in :mod:`jaxcart.run.spec`, the files in
:class:`~jaxcart.rundir.directory.RunDir`.
"""

from __future__ import annotations

import dataclasses
import shlex
import signal
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from jaxcart.analysis.summary import Score
from jaxcart.core.config import ConfigError, float_dtype, resolve_code
from jaxcart.core.ppo import RunnerState
from jaxcart.core.solved import NUM_EVAL_EPISODES
from jaxcart.engine import devices, distributed, loop
from jaxcart.engine.loop import CHUNK_SECONDS, Progress, TrainResult, TrainState
from jaxcart.engine.signals import Stopped, StopRequest
from jaxcart.run import sweep as sweeps
from jaxcart.run.greedy import CrossCheck
from jaxcart.run.loggers import make_logger
from jaxcart.run.progress import ProgressBar, chain_hooks
from jaxcart.run.spec import Evaluation, Hooks, Outcome, Run, RunOptions, RunSpec, check_option
from jaxcart.run.waves import WavePlan, available_bytes, bytes_per_run, plan_waves
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.directory import Block, RunDir, check_versions, overlapping, package_versions
from jaxcart.rundir.files import RunDirError, UnverifiedRunWarning

RESUME_HINT = "python -m jaxcart.train --resume {out}"
TIMING = ("compile_seconds", "train_seconds", "eval_seconds")
"""The seconds a block records of its wave, summed over the waves in ``evaluation.json``."""


MAX_RECORDED_SEEDS = 10_000
"""config.json lists each seed's randomised physics (``env_per_seed``) up to this many seeds;
above it the values are drawn again from the seed when needed
(:meth:`~jaxcart.run.spec.RunSpec.seed_env_values`), as training drew them."""


class RunFinished(RunDirError):
    """``--resume`` of a run (or sweep) that finished: nothing to resume."""


# Starting: a new run, or a run directory opened again -----------------------------------------
def run_new(
    spec: RunSpec,
    out: str | Path | None = None,
    options: RunOptions | None = None,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
    command: list[str] | None = None,
    progress: bool = False,
) -> Outcome:
    """Creates a run directory for ``spec`` (:func:`create_run`) and carries the run out
    (:func:`carry_out`).

    The runs train in waves when they do not all fit in memory (:mod:`jaxcart.run.waves`);
    ``command`` (the command line, when there is one) is recorded in ``config.json``.
    ``progress=True`` shows a progress bar (``tqdm.auto``: a widget in a notebook, text on a
    terminal; see :class:`jaxcart.run.progress.ProgressBar`), besides ``hooks``.
    """
    options = _prepare(options, stop)
    return carry_out(create_run(spec, out, options, command), options, hooks, stop, progress)


def resume_run(
    out: str | Path,
    options: RunOptions | None = None,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
    total_timesteps: int | None = None,
    allow_device_change: bool = False,
    progress: bool = False,
    network: type | None = None,
    trust_code: bool = False,
) -> Outcome:
    """Continues an interrupted run from its last checkpoint, bit-identically; with
    ``total_timesteps``, extends an interrupted or finished run to that many env steps per
    seed, as SB3's ``learn(more, reset_num_timesteps=False)``: an annealed learning rate then
    anneals over the new total from the checkpoint on (recorded as ``lr_schedule`` in
    ``config.json``).
    ``allow_device_change`` continues on another device count (see :func:`open_run`);
    ``progress`` as for :func:`run_new`. A run trained with its own network or metrics
    needs ``network`` (the class) or ``trust_code`` to import them (:func:`open_run`).
    """
    options = _prepare(options, stop)
    run = open_run(out, total_timesteps, allow_device_change, network, trust_code)
    return carry_out(run, options, hooks, stop, progress)


def _prepare(options: RunOptions | None, stop: StopRequest | None) -> RunOptions:
    """``options`` (default :class:`RunOptions`), the compilation cache turned on when they
    ask; raises :class:`Stopped` when ``stop`` was already requested."""
    options = options or RunOptions()
    if options.compile_cache:
        devices.enable_compilation_cache()
    if stop is not None:
        stop.check()
    return options


def plan_run(spec: RunSpec, options: RunOptions | None = None) -> WavePlan:
    """How ``spec`` would train here (waves, memory, estimated time), without training:
    ``--dry-run`` prints it; :func:`create_run` follows it."""
    options = options or RunOptions()
    return plan_waves(
        spec.config,
        spec.grid.num_runs,
        jax.device_count(),
        options.eval_episodes or NUM_EVAL_EPISODES,
        backend=jax.default_backend(),
        wave_size=options.wave_size,
    )


def create_run(
    spec: RunSpec,
    out: str | Path | None = None,
    options: RunOptions | None = None,
    command: list[str] | None = None,
    extra: dict | None = None,
) -> Run:
    """A new run directory (refusing a non-empty one) with its ``config.json``, planned
    (:func:`plan_run`: how many runs train at once) and not yet trained (:func:`carry_out`
    trains it, or :func:`resume_run` once it is closed).

    config.json records, besides ``spec`` and the plan, the evaluation episodes when
    ``options`` are given (default 20), ``command``, a sweep's ``options.score`` (a resumed
    sweep ranks by it too) and ``extra``.
    """
    plan = plan_run(spec, options)
    score = options and options.score
    drawn = spec.seed_env_values() if spec.num_seeds <= MAX_RECORDED_SEEDS else {}
    info = {
        "format_version": layout.FORMAT_VERSION,
        **spec.record(),
        **({"env_per_seed": drawn} if drawn else {}),
        "versions": package_versions(),
        "backend": jax.default_backend(),
        "device_count": jax.device_count(),
        "wave_size": plan.wave_size,
        **({reader.X64_KEY: True} if float_dtype() == np.float64 else {}),
        **({"eval_episodes": options.eval_episodes or NUM_EVAL_EPISODES} if options else {}),
        **({"command": list(command)} if command else {}),
        **({"score": score.label} if score and spec.grid.is_sweep else {}),
        **(extra or {}),
    }
    out = Path(out) if out is not None else layout.default_run_dir(spec.preset)
    directory = RunDir.create(out, info, spec.config, distributed.is_main_process())
    return Run(directory, spec, info, plan)


def open_run(
    out: str | Path,
    extend_to: int | None = None,
    allow_device_change: bool = False,
    network: type | None = None,
    trust_code: bool = False,
) -> Run:
    """An existing, unfinished run directory, to resume at the wave and iteration it
    continues from; or, with ``extend_to`` env steps per seed, an interrupted or finished
    one to train further.

    A run trained with code of its own (a network, metric functions) needs it: ``network``
    passed, or its recorded names imported with ``trust_code``; either only after every
    other check of the directory passed (:func:`~jaxcart.core.config.resolve_code`).

    A run continues on the device layout it trained on (a different one gives other
    numbers): another device count is refused unless ``allow_device_change``, which
    config.json then records under ``device_changes``.

    Raises:
        RunDirError: not a run, unreadable, edited (digest), another package version,
            device count or float type, or already finished.
        ConfigError: an extension that cannot be done (fewer steps, a run trained in
            waves).
    """
    out = Path(out)
    with warnings.catch_warnings():  # said once, by the read below
        warnings.simplefilter("ignore", UnverifiedRunWarning)
        reader.read_run_config(out)  # a clear error for what is not a run, before the lock
    directory = RunDir.open(out, distributed.is_main_process())
    try:  # config.json again, through the directory the run resumes in
        info = reader.read_run_config(directory.dir or out, verify=True)
        changed = _device_change(out, info, allow_device_change)
        meta = directory.read_checkpoint_meta()
        if extend_to is not None:
            info = _extend(out, info, extend_to, int(meta["iteration"]) if meta else 0)
        check_versions(out, (meta or info).get("versions", {}))
        trained, now = reader.params_dtype(info), float_dtype()
        if trained != now:
            setting = "JAX_ENABLE_X64=1" if trained == np.float64 else "JAX_ENABLE_X64 unset"
            raise RunDirError(
                f"{out} trained in {trained}, this process runs {now}; resume it with {setting}"
            )
        config = info["config"]
        if meta and meta["iteration"] >= config.num_iterations and directory.finished():
            raise RunFinished(
                f"{out} already finished all {config.num_iterations} iterations; nothing to "
                f"resume{_extend_hint(out, info)}"
            )
        # the run's own code, only now that the directory is checked, and only if asked
        config = resolve_code(config, network, trust_code, str(out))
        spec = RunSpec.from_record({**info, "config": config})
        num_runs, wave = spec.grid.num_runs, 0
        plan = WavePlan(num_runs, info.get("wave_size") or num_runs, 0, 0)
        if plan.num_waves > 1:  # the plan it was started with, and today's estimate
            if extend_to is not None:
                raise ConfigError(
                    f"cannot extend {out}: it trained in waves, which keep no final state"
                )
            plan = WavePlan(num_runs, plan.wave_size, bytes_per_run(config), available_bytes())
            waves = range(plan.num_waves)
            wave = next((w for w in waves if not directory.has_wave(w)), plan.num_waves)
        resumed_from = int(meta["iteration"]) if meta and meta.get("wave", 0) == wave else 0
        if directory.main_process and extend_to is not None:
            directory.mark_unfinished()  # until the extension finishes, readers say so
        if directory.main_process and (extend_to is not None or changed):
            directory.write_config(info, config)
    except BaseException:
        directory.close()
        raise
    info = {k: v for k, v in info.items() if k != "config"}
    return Run(directory, spec, info, plan, resumed_from=resumed_from, resume_wave=wave)


def _device_change(out: Path, info: dict, allowed: bool) -> bool:
    """Whether this process has another device count than the run trained on (recorded in
    ``info`` when ``allowed``); refused otherwise, with the command that matches."""
    recorded, now = int(info.get("device_count", jax.device_count())), jax.device_count()
    if recorded == now:
        return False
    if not allowed:
        raise RunDirError(
            f"{out} trained on {recorded} {info.get('backend', '')} device(s), this process has "
            f"{now}: continuing would give other numbers. Resume with the layout it had: "
            f"XLA_FLAGS=--xla_force_host_platform_device_count={recorded} "
            f"python -m jaxcart.train --resume {shlex.quote(str(out))} (on CPU), or pass "
            "--allow-device-change to continue on this one (config.json records it)"
        )
    info["device_changes"] = [*info.get("device_changes", []), {"from": recorded, "to": now}]
    info["device_count"] = now
    return True


def _extend_hint(out: Path, info: dict) -> str:
    """For a run that finished (:class:`RunFinished`): how to train it further
    (``--total-timesteps`` above its current total), or why it cannot be (as :func:`_extend`
    and :func:`open_run` decide)."""
    config, total = info["config"], info["config"].env_steps_per_seed
    runs = int(info.get("num_seeds", 1)) * max(1, len(info.get("combinations", [])))
    if (info.get("wave_size") or runs) < runs:
        return (
            ". It trained in waves, which keep no final state, so it cannot be extended: start "
            f"a new run with a --total-timesteps above its {total:,}"
        )
    annealed = (
        "; its annealed learning rate then anneals over N from here on, as SB3's "
        "learn(reset_num_timesteps=False) does"
        if config.anneal_lr
        else ""
    )
    return (
        f". To train it further, give a larger total: {RESUME_HINT.format(out=shlex.quote(str(out)))}"
        f" --total-timesteps N, with N above its current {total:,} env steps per seed{annealed}"
    )


def _extend(out: Path, info: dict, total_timesteps: int, from_iteration: int) -> dict:
    """``config.json``'s contents for a run extended, from its checkpoint at
    ``from_iteration``, to ``total_timesteps`` env steps per seed.

    An annealed learning rate (``anneal_lr``) measures its progress against the new total
    from then on, as SB3's ``learn(reset_num_timesteps=False)`` does: iteration ``i`` (from 0)
    trains at ``learning_rate * (1 - i / new_iterations)``, a step back up from the near-0
    rate the run ended at. ``lr_schedule`` records each piece of the schedule, ``{"from_iteration",
    "num_iterations"}``: from that iteration on, the rate anneals over that many iterations.
    """
    config = info["config"]
    extended = dataclasses.replace(config, total_timesteps=total_timesteps)
    if extended.num_iterations <= config.num_iterations:
        raise ConfigError(
            f"--total-timesteps {total_timesteps:,} does not extend {out}: it already trains "
            f"{config.env_steps_per_seed:,} env steps per seed"
        )
    history = [*info.get("extended_from", []), config.total_timesteps]
    info = {**info, "config": extended, "extended_from": history}
    if config.anneal_lr:
        pieces = info.get("lr_schedule") or [
            {"from_iteration": 0, "num_iterations": config.num_iterations}
        ]
        # a piece that no iteration trained under is replaced, not kept
        pieces = [p for p in pieces if p["from_iteration"] < from_iteration]
        piece = {"from_iteration": from_iteration, "num_iterations": extended.num_iterations}
        info["lr_schedule"] = [*pieces, piece]
    return info


def replay_seed(
    run_dir: str | Path,
    seed_index: int,
    combination: int = 0,
    network: type | None = None,
    trust_code: bool = False,
) -> TrainResult:
    """Trains one seed of a run again, alone, bit-identical to how it trained in its batch:
    the seed is padded to the per-device batch width it had (the padding is discarded).

    Needs the run's device count (``XLA_FLAGS=--xla_force_host_platform_device_count=N``)
    and package versions; costs that width's compute, not one seed's. A run trained with
    its own code needs ``network`` or ``trust_code`` (:func:`open_run`).

    Raises:
        RunDirError: not a run, or another device count.
        ConfigError: a seed index or combination out of range.
    """
    info = reader.read_run_config(run_dir)
    info["config"] = resolve_code(info["config"], network, trust_code, str(run_dir))
    spec = RunSpec.from_record(info)
    grid, devices_now = spec.grid, jax.device_count()
    if info.get("device_count") != devices_now:
        raise RunDirError(
            f"{run_dir} trained on {info.get('device_count')} device(s), this process has "
            f"{devices_now}; set XLA_FLAGS=--xla_force_host_platform_device_count="
            f"{info.get('device_count')} to replay it"
        )
    check_option(
        0 <= seed_index < grid.num_seeds, "seed_index", f"must be in [0, {grid.num_seeds})"
    )
    check_option(
        0 <= combination < grid.num_combos, "combination", f"must be in [0, {grid.num_combos})"
    )
    run = grid.run_index(combination, seed_index)
    plan = WavePlan(grid.num_runs, int(info.get("wave_size") or grid.num_runs), 0, 0)
    wave = len(plan.wave(run // plan.wave_size))
    used = min(devices_now, wave)  # fewer runs than devices trained on that many devices
    return loop.train(
        spec.combo_config(combination),
        1,
        spec.seed,
        env_params=spec.run_env_params(range(run, run + 1)),
        episode_ranges=spec.episode_ranges,
        seed_indices=np.array([seed_index]),
        devices=jax.devices()[:used],
        runs_per_device=-(-wave // used),
    )


start_distributed = distributed.initialize
"""Joins a ``jax.distributed`` run (before any JAX work); a failure is a ConfigError."""


def carry_out(
    run: Run,
    options: RunOptions,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
    progress: bool = False,
) -> Outcome:
    """Trains (wave by wave), evaluates every run and writes the run directory, a new run's
    or a resumed one's alike; holds the run's lock throughout and releases it at the end.
    The evaluation episodes are ``options``', else the run's (config.json), else 20.

    SIGINT and SIGTERM (handled here unless the caller passes its own ``stop``) stop at the
    next safe point: the state is checkpointed and the outcome is ``stopped``, resumable.
    A stopped run keeps its checkpoint (and, trained in one wave, a partial metrics.csv).
    ``progress=True`` adds a :class:`~jaxcart.run.progress.ProgressBar` to ``hooks``.

    Raises:
        ConfigError: ``options`` evaluate another number of episodes than the run records.
    """
    bar = ProgressBar() if progress else None
    hooks = chain_hooks(hooks, bar)
    stop = stop or StopRequest(hooks.on_signal)
    try:
        recorded = run.info.get("eval_episodes")
        if recorded and options.eval_episodes and options.eval_episodes != recorded:
            raise ConfigError(
                f"{run.out} evaluates {recorded} episodes per seed (config.json); "
                "drop --eval-episodes"
            )
        episodes = options.eval_episodes or recorded or NUM_EVAL_EPISODES
        options = dataclasses.replace(options, eval_episodes=episodes)
        with stop.installed():
            return _carry_out(run, options, hooks, stop)
    except Exception:
        if _nothing_trained(run):  # a new run that failed before its first chunk trained
            run.directory.discard()
        raise
    finally:
        if bar is not None:
            bar.close()
        run.close()


def _nothing_trained(run: Run) -> bool:
    """Whether ``run`` is a new run, owned by this process, none of whose iterations trained
    (its only checkpoint, if any, is the one written before the first iteration)."""
    if run.resumed_from is not None or not run.main_process or run.trained_chunks:
        return False
    meta = run.directory.checkpoint_meta or {}
    return int(meta.get("iteration", 0)) == 0 and int(meta.get("wave", 0)) == 0


def _carry_out(run: Run, options: RunOptions, hooks: Hooks, stop: StopRequest) -> Outcome:
    """Each wave in turn (one for most runs): trained, evaluated and kept as a block; then
    the outputs from every block (:func:`_finish`)."""
    if hooks.on_start:
        hooks.on_start(run, jax.device_count(), jax.default_backend())
    outcome = Outcome(run, None, num_devices=jax.device_count())
    blocks: list = []
    num_waves = run.plan.num_waves
    for wave, runs in enumerate(run.plan.waves()):
        if num_waves > 1 and run.directory.has_wave(wave):
            # finished before an interruption: checked before the outputs are built from it
            episodes = options.eval_episodes
            blocks.append(run.directory.finished_wave(wave, runs, episodes, run.config))
            continue
        if hooks.on_wave:
            hooks.on_wave(wave, num_waves, runs)
        block = _one_wave(run, options, hooks, stop, outcome, runs, wave)
        if block is None:
            meta = run.directory.checkpoint_meta or {}
            same_wave = meta.get("wave", 0) == wave
            outcome.stopped_at = (wave, int(meta.get("iteration", 0)) if same_wave else 0)
            outcome.stopped = True
            outcome.signum = stop.signum or signal.SIGTERM  # another process may have had it
            return outcome
        keep = num_waves > 1 and run.main_process  # on disk until the outputs are written
        blocks.append(run.directory.save_wave(block, wave) if keep else block)
    if run.main_process:
        _finish(run, blocks, options, outcome)
    return outcome  # signum set when a signal came while writing: the run finished all the same


# One wave: its start state, training in chunks with checkpoints and logging, evaluation --
def wave_start_state(
    run: Run,
    runs: range,
    wave: int = 0,
    chunk_size: int | None = None,
    on_progress: Callable[[int, int], None] | None = None,
) -> TrainState:
    """The state of ``runs`` (wave ``wave``) from the checkpoint when it holds that wave;
    else a fresh state, saved at once as the wave's iteration-0 checkpoint, so that a run
    killed at any moment can be resumed. ``on_progress(done, total)`` follows the
    initialisation of large runs."""
    meta, spec, columns = run.directory.checkpoint_meta, run.spec, loop.metric_columns(run.config)
    if meta is not None and meta.get("wave", 0) == wave:
        # a one-run template names the arrays; the file has them all
        template = loop.initial_state(
            run.config, 1, spec.seed, chunk_size=chunk_size, episode_ranges=spec.episode_ranges
        )
        state = run.directory.load_checkpoint(template, num_runs=len(runs))
        # a chunk runs at most the run's iterations (or the default chunk): a larger one from
        # a crafted checkpoint would build [chunk_size, R] metrics in the compiled call
        iterations = run.config.num_iterations
        most = max(iterations, loop.default_chunk_size(iterations, 1))
        if state.chunk_size > most:
            raise RunDirError(
                f"{run.directory.path / layout.CHECKPOINT_FILE} is corrupted: chunk_size {state.chunk_size} "
                f"is more than the {most} iterations a chunk of this run can run"
            )
        run.directory.open_metrics(len(runs), state.iteration, columns)  # rows after it are cut
    else:
        state = loop.initial_state(
            sweeps.grid_config(run.config, run.grid, runs),
            len(runs),
            spec.seed,
            env_params=spec.run_env_params(runs),
            chunk_size=chunk_size,
            episode_ranges=spec.episode_ranges,
            seed_indices=run.grid.seed_indices(runs),
            on_progress=on_progress,
        )
        run.directory.open_metrics(len(runs), 0, columns)
        save_state(run, state, wave)
    return state


def save_state(run: Run, state: TrainState, wave: int = 0) -> RunnerState:
    """Checkpoints ``state``: every process takes part in gathering it; process 0 writes.
    Returns the runners gathered (NumPy, every run's, on every process)."""
    arrays = distributed.gather({"runners": state.runners, "config": state.config})
    if not run.main_process:
        return arrays["runners"]
    gathered = dataclasses.replace(state, runners=arrays["runners"], config=arrays["config"])
    meta = {
        "num_runs": len(arrays["runners"].diverged_at),
        "wave": wave,
        "config": run.config.to_dict(),
        "versions": package_versions(),
    }
    run.directory.save_checkpoint(gathered, meta)
    return arrays["runners"]


def train_wave(
    run: Run,
    options: RunOptions,
    hooks: Hooks,
    should_stop: Callable[[], bool] | None = None,
    runs: range | None = None,
    wave: int = 0,
    cross_check: CrossCheck | None = None,
) -> TrainResult:
    """Trains ``runs`` (default: all; wave ``wave`` of the plan) from
    :func:`wave_start_state` to the end or until ``should_stop``. After every chunk its
    metrics are appended to the run directory's stream and logged, divergences reported
    (``hooks.on_diverged``), a checkpoint saved every ``options.checkpoint_every`` seconds,
    then ``hooks.on_chunk`` called. ``cross_check`` (the final evaluation's JAX program)
    starts compiling beside the training once the training's program has compiled.

    Raises:
        Stopped: ``should_stop`` turned true during the initialisation.
    """
    runs = runs if runs is not None else range(run.grid.num_runs)
    grid, config = run.grid, run.config

    def on_progress(done: int, total: int) -> None:
        if should_stop is not None and should_stop():
            raise Stopped("initialisation interrupted")
        if hooks.on_init:
            hooks.on_init(done, total)

    # without a chunk_size, chunks adapt to take about CHUNK_SECONDS each (chunk lengths change
    # no number), no longer than the checkpoint interval, so that checkpoints come on time;
    # with several processes they stay fixed: every process must run the same chunk lengths
    fixed = options.chunk_size or jax.process_count() > 1
    state = wave_start_state(run, runs, wave, options.chunk_size, on_progress)
    state.chunk_seconds = None if fixed else min(CHUNK_SECONDS, options.checkpoint_every)
    loggers = list(options.loggers) if run.main_process else []
    info = {**run.info, "config": config.to_dict()}
    names = [grid.run_name(r) for r in runs]
    logger = make_logger(loggers, run.out, names, info, options.logger_dir)
    clip_ranges = sweeps.grid_values(grid, runs, "clip_coef", config.clip_coef)
    last_save, reported = time.monotonic(), set()

    def on_compiled(seconds: float) -> None:
        if cross_check is not None:
            cross_check.compile_for(state.runners.params)
        if hooks.on_compiled:
            hooks.on_compiled(seconds)

    def on_chunk(progress: Progress) -> None:
        nonlocal last_save
        run.trained_chunks += 1
        new = set(np.flatnonzero(progress.diverged_at >= 0).tolist()) - reported
        reported.update(new)  # indexed within the wave
        if hooks.on_diverged and run.main_process:
            for r in sorted(new):
                hooks.on_diverged(grid.run_name(runs.start + r), int(progress.diverged_at[r]))
        run.directory.stream.append(progress.metrics)
        first = progress.iteration - len(progress.metrics["time/fps"])
        logger.log_iterations(first, progress.metrics, config, clip_ranges)
        # every process must agree on when to gather
        due = distributed.any_process(time.monotonic() - last_save >= options.checkpoint_every)
        if due and progress.iteration < config.num_iterations:
            save_state(run, progress.state(), wave)
            last_save = time.monotonic()
        if hooks.on_chunk:
            hooks.on_chunk(progress)

    try:
        return loop.train(
            config,
            len(runs),
            run.spec.seed,
            env_params=run.spec.run_env_params(runs),
            resume=state,
            on_compiled=on_compiled,
            on_chunk=on_chunk,
            should_stop=should_stop,
            keep_metrics=False,  # streamed to disk chunk by chunk
        )
    finally:
        logger.close()


def _one_wave(
    run: Run,
    options: RunOptions,
    hooks: Hooks,
    stop: StopRequest,
    outcome: Outcome,
    runs: range,
    wave: int,
) -> Block | None:
    """Trains, checkpoints and evaluates one wave (:class:`~jaxcart.run.greedy.CrossCheck`:
    Gymnasium's verdict and jaxcart's cross-check, of the final and the kept-best policies);
    None when stopped (its state checkpointed, and, for a run in one wave, its metrics so far
    written)."""
    check, episodes = None, options.eval_episodes
    if run.main_process:  # compiled beside the training, so that the evaluation finds it ready
        seeds, physics = run.grid.seed_indices(runs), run.spec.eval_env_params(runs)
        check = CrossCheck(run.config, run.spec.seed, seeds, episodes, physics)
    try:
        result = train_wave(run, options, hooks, stop, runs, wave, check)
    except Stopped:  # during initialisation: the checkpoint on disk (if any) is untouched
        return None
    outcome.result, outcome.num_devices = result, result.num_devices
    outcome.compile_seconds += result.compile_seconds
    outcome.train_seconds += result.run_seconds
    outcome.env_steps += result.env_steps
    runners = save_state(run, result.state, wave)  # the final state, gathered once
    if result.stopped:
        if run.main_process and run.plan.num_waves == 1:
            run.directory.write_metrics(run.config.batch_size)
        return None
    best_params = best = None
    if run.config.keep_best:
        kept = runners.best
        best_params = files.flatten(kept.params)
        best = {"best_iteration": np.asarray(kept.iteration), "best_score": np.asarray(kept.score)}
    gym = jax_returns = np.zeros((len(runs), 0))  # other processes: process 0 evaluates
    seconds = 0.0
    if run.main_process:
        try:
            stop.check()
            start = time.perf_counter()
            gym, jax_returns = check.evaluate(runners.params, stop)
            seconds = time.perf_counter() - start
            if best is not None:  # the Gymnasium verdict of the best policies too
                best["best_gym_returns"] = check.verdict(kept.params, stop)
        except Stopped:
            return None
    timing = dict(zip(TIMING, (result.compile_seconds, result.state.elapsed, seconds)))
    return Block(
        runs.start,
        runs.stop,
        files.flatten(runners.params),
        run.directory.stream.read(),  # memory-mapped from the stream
        np.asarray(runners.diverged_at),
        gym,
        jax_returns,
        timing,
        best_params,
        best,
    )


def _finish(run: Run, blocks: list, options: RunOptions, outcome: Outcome) -> None:
    """The run directory's outputs from every block (metrics.csv, params.npz and
    evaluation.json; per combination for a sweep, each with its own config.json) and the
    outcome's per-run summary; then a sweep's ranking (``sweep.json``), read back from its
    combinations' directories (:func:`jaxcart.run.sweep.rank_dirs`, as a structural sweep's
    groups are ranked) by ``options.score`` (None: the one config.json records, else eval)."""
    episodes = options.eval_episodes
    pieces = list(overlapping(blocks, range(run.grid.num_runs)))  # (block, its runs' rows)

    def joined(rows: Callable[[Block], np.ndarray]) -> np.ndarray:
        """Every run's rows of ``rows(block)``, block after block."""
        return np.concatenate([rows(block)[take] for block, take in pieces])

    gym, jax_returns = joined(lambda b: b.gym_returns), joined(lambda b: b.jax_returns)
    outcome.diverged_at = joined(lambda b: b.diverged_at)
    outcome.final_return = joined(lambda b: b.metrics[sweeps.RETURN_METRIC][-1])
    timing = {k: sum(float(block.timing.get(k, 0.0)) for block, _ in pieces) for k in TIMING}
    env = run.config.env
    outcome.evaluation = Evaluation(episodes, gym, jax_returns, timing["eval_seconds"], env=env)
    if run.config.keep_best:
        outcome.evaluation.best_gym_returns = joined(lambda b: b.best["best_gym_returns"])
    timing |= {"devices": outcome.num_devices, "waves": len(blocks)}
    swept = run.grid.is_sweep
    for c, combo in enumerate(run.grid.combos or ({},)):
        # a combination of no float values too (tune's shape trials): its own directory
        info = {**run.info, "combination": combo, "sweep": {}, "combinations": []}
        runs = run.grid.runs_of(c)
        run.directory.write_outputs(
            blocks,
            range(runs.start, runs.stop),
            run.spec.combo_config(c),
            episodes,
            timing,
            (c, info) if swept else None,
        )
    if swept:
        ranked = sweeps.rank_dirs(
            [run.out], options.score or Score.parse(run.info.get("score", "eval"))
        )
        outcome.ranking = ranked["ranking"]
        record = {"sweep": run.sweep, "num_seeds": run.grid.num_seeds, **ranked}
        run.directory.write_ranking(record)
