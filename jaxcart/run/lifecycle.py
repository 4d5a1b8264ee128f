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
from jaxcart.core.solved import NUM_EVAL_EPISODES
from jaxcart.engine import devices, distributed
from jaxcart.engine.loop import (
    CHUNK_SECONDS,
    Progress,
    TrainResult,
    TrainState,
    default_chunk_size,
    initial_state,
    metric_columns,
    train,
)
from jaxcart.engine.signals import Stopped, StopRequest
from jaxcart.run import sweep as sweeps
from jaxcart.run.greedy import evaluate_runs
from jaxcart.run.loggers import Logger, make_logger, sb3_extras
from jaxcart.run.progress import ProgressBar
from jaxcart.run.spec import (
    Evaluation,
    Hooks,
    Outcome,
    Run,
    RunOptions,
    RunSpec,
    check_option,
)
from jaxcart.run.waves import WavePlan, available_bytes, bytes_per_run, plan_waves
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.directory import Block, RunDir, check_versions, overlapping, package_versions
from jaxcart.rundir.files import RunDirError, UnverifiedRunWarning

RESUME_HINT = "python -m jaxcart.train --resume {out}"


MAX_RECORDED_SEEDS = 10_000
"""config.json lists each seed's randomised physics (``env_per_seed``) up to this many seeds;
above it the values are drawn again from the seed when needed
(:meth:`~jaxcart.run.spec.RunSpec.seed_env_values`), as training drew them."""


class RunFinished(RunDirError):
    """``--resume`` of a run (or sweep) that finished: nothing to resume."""


def create_run(
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
    plan = plan or plan_run(spec)
    out = Path(out) if out is not None else layout.default_run_dir(spec.preset)
    info = {
        "format_version": layout.FORMAT_VERSION,
        "preset": spec.preset,
        "num_seeds": spec.num_seeds,
        "seed": spec.seed,
        "sweep": spec.sweep,
        **spec.record(),
        **(
            {"env_per_seed": spec.seed_env_values()}
            if spec.num_seeds <= MAX_RECORDED_SEEDS and spec.seed_env_values()
            else {}
        ),
        **({"combinations": [dict(c) for c in spec.combinations]} if spec.combinations else {}),
        "versions": package_versions(),
        "backend": jax.default_backend(),
        "device_count": jax.device_count(),
        "wave_size": plan.wave_size,
        **({reader.X64_KEY: True} if float_dtype() == np.float64 else {}),
        **(extra or {}),
    }
    return Run(RunDir.create(out, info, spec.config, main_process), spec, info, plan)


def open_run(
    out: str | Path,
    main_process: bool = True,
    extend_to: int | None = None,
    allow_device_change: bool = False,
    network: type | None = None,
    trust_code: bool = False,
) -> Run:
    """An existing, unfinished run directory, to resume; or, with ``extend_to`` env steps
    per seed, an interrupted or finished one to train further.

    A run trained with code of its own (a network, metric functions) needs it: ``network``
    passed, or its recorded names imported with ``trust_code``; either only after every
    other check of the directory passed (:func:`~jaxcart.core.config.resolve_code`).

    A run continues on the device layout it trained on (a different one gives other
    numbers): another device count is refused unless ``allow_device_change``, which
    config.json then records under ``device_changes``.

    Raises:
        RunDirError: not a run, unreadable, edited (digest), another package version or
            device count, or already finished.
        ConfigError: an extension that cannot be done (fewer steps, a run trained in
            waves).
    """
    out = Path(out)
    with warnings.catch_warnings():  # said once, by the read below
        warnings.simplefilter("ignore", UnverifiedRunWarning)
        reader.read_run_config(out)  # a clear error for what is not a run, before the lock
    directory = RunDir.open(out, main_process)
    try:  # config.json again, through the directory the run resumes in
        info = reader.read_run_config(directory.dir or out, verify=True)
        changed = _device_change(out, info, allow_device_change)
        if extend_to is not None:
            meta = directory.read_checkpoint_meta()
            info = _extend(out, info, extend_to, int(meta["iteration"]) if meta else 0)
        run = _resumable(directory, dict(info), network, trust_code)
        if extend_to is not None and main_process:
            directory.mark_unfinished()  # until the extension finishes, readers say so
        if (extend_to is not None or changed) and main_process:
            directory.write_config(info, run.config)
    except BaseException:
        directory.close()
        raise
    return run


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
            "--allow-device-change "
            "to continue on this one (config.json records it)"
        )
    info["device_changes"] = [*info.get("device_changes", []), {"from": recorded, "to": now}]
    info["device_count"] = now
    return True


def _check_precision(out: Path, info: dict) -> None:
    """Refuses to continue a float64 (x64) run in float32, or the other way round."""
    trained, now = reader.params_dtype(info), float_dtype()
    if trained != now:
        setting = "JAX_ENABLE_X64=1" if trained == np.float64 else "JAX_ENABLE_X64 unset"
        raise RunDirError(
            f"{out} trained in {trained}, this process runs {now}; resume it with {setting}"
        )


def _resumable(
    directory: RunDir, info: dict, network: type | None = None, trust_code: bool = False
) -> Run:
    """The run a directory's ``info`` (its config.json) and checkpoint describe, at the wave
    and iteration it continues from; its code (:func:`resolve_code`) resolved last."""
    meta = directory.read_checkpoint_meta()
    check_versions(directory.path, (meta or info).get("versions", {}))
    _check_precision(directory.path, info)
    config = info.pop("config")
    if meta and meta["iteration"] >= config.num_iterations and directory.finished():
        raise RunFinished(
            f"{directory.path} already finished all {config.num_iterations} iterations; "
            "nothing to resume"
        )
    # the run's own code, only now that the directory is checked, and only if asked
    config = resolve_code(config, network, trust_code, str(directory.path))
    spec = RunSpec.from_record({**info, "config": config})
    num_runs = spec.grid.num_runs
    plan = WavePlan(num_runs, info.get("wave_size") or num_runs, 0, 0)
    if plan.num_waves > 1:  # the plan it was started with, and today's estimate
        plan = WavePlan(num_runs, plan.wave_size, bytes_per_run(config), available_bytes())
    wave = _first_unfinished_wave(directory, plan)
    same_wave = meta is not None and meta.get("wave", 0) == wave
    resumed_from = int(meta["iteration"]) if same_wave else 0
    return Run(directory, spec, info, plan, resumed_from=resumed_from, resume_wave=wave)


def _first_unfinished_wave(directory: RunDir, plan: WavePlan) -> int:
    """The first wave without a saved block (0 for a run trained in one wave)."""
    if plan.num_waves == 1:
        return 0
    return next((w for w in range(plan.num_waves) if not directory.has_wave(w)), plan.num_waves)


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
    config = spec.combo_config(combination)
    return train(
        config,
        1,
        spec.seed,
        env_params=spec.run_env_params(range(run, run + 1)),
        episode_ranges=spec.episode_ranges,
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
    progress: bool = False,
) -> Outcome:
    """Creates a run directory for ``spec`` and carries the run out (see :func:`carry_out`).

    The runs train in waves when they do not all fit in memory (:mod:`jaxcart.run.waves`);
    ``command`` (the command line, when there is one) is recorded in ``config.json``.
    ``progress=True`` shows a progress bar (``tqdm.auto``: a widget in a notebook, text on a
    terminal; see :class:`jaxcart.run.progress.ProgressBar`), besides ``hooks``.
    """
    options = _with_defaults(options)
    if stop is not None:
        stop.check()
    run = new_run(spec, out, options, command)
    return carry_out(run, options, hooks, stop, progress)


def _with_defaults(options: RunOptions | None) -> RunOptions:
    """``options`` with the evaluation episodes defaulted (and the compilation cache on when
    asked)."""
    options = options or RunOptions()
    if options.compile_cache:
        devices.enable_compilation_cache()
    episodes = options.eval_episodes or NUM_EVAL_EPISODES
    return dataclasses.replace(options, eval_episodes=episodes)


def new_run(
    spec: RunSpec,
    out: str | Path | None,
    options: RunOptions | None = None,
    command: list[str] | None = None,
    extra: dict | None = None,
) -> Run:
    """A new run directory for ``spec``, planned (:func:`plan_run`), its ``config.json``
    recording the evaluation episodes, ``command`` and ``extra``; not yet trained
    (:func:`carry_out` trains it, or :func:`resume_run` once it is closed)."""
    options = _with_defaults(options)
    plan = plan_run(spec, options)
    extra = {
        "eval_episodes": options.eval_episodes,
        **({"command": list(command)} if command else {}),
        **({"score": options.score.label} if options.score and spec.grid.is_sweep else {}),
        **(extra or {}),
    }  # a resumed sweep ranks by its score too
    return create_run(spec, out, distributed.is_main_process(), plan, extra)


def plan_run(spec: RunSpec, options: RunOptions | None = None) -> WavePlan:
    """How ``spec`` would train here (waves, memory, estimated time), without training:
    ``--dry-run`` prints it; :func:`run_new` follows it."""
    options = options or RunOptions()
    return plan_waves(
        spec.config,
        spec.grid.num_runs,
        jax.device_count(),
        options.eval_episodes or NUM_EVAL_EPISODES,
        backend=jax.default_backend(),
        wave_size=options.wave_size,
    )


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
    options = options or RunOptions()
    if options.compile_cache:
        devices.enable_compilation_cache()
    if stop is not None:
        stop.check()
    run = open_run(
        out,
        distributed.is_main_process(),
        total_timesteps,
        allow_device_change,
        network,
        trust_code,
    )
    recorded = run.info.get("eval_episodes")
    if recorded and options.eval_episodes and options.eval_episodes != recorded:
        run.close()
        raise ConfigError(
            f"{out} evaluates {recorded} episodes per seed (config.json); drop --eval-episodes",
        )
    episodes = options.eval_episodes or recorded or NUM_EVAL_EPISODES
    options = dataclasses.replace(options, eval_episodes=episodes)
    return carry_out(run, options, hooks, stop, progress)


def carry_out(
    run: Run,
    options: RunOptions,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
    progress: bool = False,
) -> Outcome:
    """Trains (wave by wave), evaluates every run and writes the run directory; holds the
    run's lock throughout and releases it at the end.

    SIGINT and SIGTERM (handled here unless the caller passes its own ``stop``) stop at the
    next safe point: the state is checkpointed and the outcome is ``stopped``, resumable.
    A stopped run keeps its checkpoint (and, trained in one wave, a partial metrics.csv).
    ``progress=True`` adds a :class:`~jaxcart.run.progress.ProgressBar` to ``hooks``.
    """
    bar = ProgressBar() if progress else None
    hooks = bar.hooks(hooks) if bar is not None else hooks or Hooks()
    stop = stop or StopRequest(hooks.on_signal)
    try:
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
    the outputs from every block."""
    if hooks.on_start:
        hooks.on_start(run, jax.device_count(), jax.default_backend())
    outcome = Outcome(run, None, num_devices=jax.device_count())
    blocks: list = []
    num_waves = run.plan.num_waves
    for wave, runs in enumerate(run.plan.waves()):
        if num_waves > 1 and run.directory.has_wave(wave):
            # finished before an interruption: checked before the outputs are built from it
            blocks.append(
                run.directory.finished_wave(wave, runs, options.eval_episodes, run.config)
            )
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
        if num_waves > 1 and run.main_process:
            blocks.append(run.directory.save_wave(block, wave))
        else:
            blocks.append(block)
    if run.main_process:
        _finish(run, blocks, options.eval_episodes, outcome, options.score)
    return outcome  # signum set when a signal came while writing: the run finished all the same


# One wave: its start state, training in chunks with checkpoints and logging, evaluation --
def wave_start_state(
    run: Run,
    runs: range,
    wave: int = 0,
    chunk_size: int | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    chunk_seconds: float = CHUNK_SECONDS,
) -> TrainState:
    """The state of ``runs`` (wave ``wave``) from the checkpoint when it holds that wave;
    else a fresh state, saved at once as the wave's iteration-0 checkpoint, so that a run
    killed at any moment can be resumed. ``on_progress(done, total)`` follows the
    initialisation of large runs. Without ``chunk_size`` its chunks adapt to take about
    ``chunk_seconds`` each (chunk lengths change no number); with several processes the
    chunks stay fixed, since every process must run the same chunk lengths."""
    adapt = None if chunk_size or jax.process_count() > 1 else chunk_seconds
    meta = run.directory.checkpoint_meta
    if meta is not None and meta.get("wave", 0) == wave:
        # a one-run template names the arrays; the file has them all
        template = initial_state(
            run.config,
            1,
            run.spec.seed,
            chunk_size=chunk_size,
            episode_ranges=run.spec.episode_ranges,
        )
        saved = run.directory.load_checkpoint(template, num_runs=len(runs))
        # a chunk runs at most the run's iterations (or the default chunk): a larger one from
        # a crafted checkpoint would build [chunk_size, R] metrics in the compiled call
        most = max(run.config.num_iterations, default_chunk_size(run.config.num_iterations, 1))
        if saved.chunk_size > most:
            raise RunDirError(
                f"{run.directory.checkpoint_path} is corrupted: chunk_size {saved.chunk_size} "
                f"is more than the {most} iterations a chunk of this run can run"
            )
        columns = metric_columns(run.config)
        run.directory.open_metrics(len(runs), saved.iteration, columns)  # rows after it are cut
        return dataclasses.replace(saved, chunk_seconds=adapt)
    fresh = initial_state(
        sweeps.grid_config(run.config, run.grid, runs),
        len(runs),
        run.spec.seed,
        env_params=run.spec.env_params if run.spec.is_cartpole else None,
        chunk_size=chunk_size,
        episode_ranges=run.spec.episode_ranges,
        seed_indices=run.grid.seed_indices(runs),
        on_progress=on_progress,
    )
    run.directory.open_metrics(len(runs), 0, metric_columns(run.config))
    save_state(run, fresh, wave)
    return dataclasses.replace(fresh, chunk_seconds=adapt)


def save_state(run: Run, state: TrainState, wave: int = 0) -> None:
    """Checkpoints ``state``: every process takes part in gathering it; process 0 writes."""
    arrays = distributed.gather({"runners": state.runners, "config": state.config})
    if not run.main_process:
        return
    gathered = dataclasses.replace(state, runners=arrays["runners"], config=arrays["config"])
    meta = {
        "num_runs": len(arrays["runners"].diverged_at),
        "wave": wave,
        "config": run.config.to_dict(),
        "versions": package_versions(),
    }
    run.directory.save_checkpoint(gathered, meta)


def train_wave(
    run: Run,
    options: RunOptions,
    hooks: Hooks,
    should_stop: Callable[[], bool] | None = None,
    runs: range | None = None,
    wave: int = 0,
) -> TrainResult:
    """Trains ``runs`` (default: all; wave ``wave`` of the plan) from
    :func:`wave_start_state` to the end or until ``should_stop``, logging metrics and
    checkpointing every ``options.checkpoint_every`` seconds.

    Raises:
        Stopped: ``should_stop`` turned true during the initialisation.
    """
    runs = runs if runs is not None else range(run.grid.num_runs)

    def on_progress(done: int, total: int) -> None:
        if should_stop is not None and should_stop():
            raise Stopped("initialisation interrupted")
        if hooks.on_init:
            hooks.on_init(done, total)

    # chunks no longer than the checkpoint interval, so that checkpoints come on time
    seconds = min(CHUNK_SECONDS, options.checkpoint_every)
    state = wave_start_state(run, runs, wave, options.chunk_size, on_progress, seconds)
    names = [run.grid.run_name(r) for r in runs]
    loggers = list(options.loggers) if run.main_process else []
    info = {**run.info, "config": run.config.to_dict()}
    logger = make_logger(loggers, run.out, names, info, options.logger_dir)
    handler = ChunkHandler(run, options, hooks, logger, runs, wave)
    try:
        return train(
            run.config,
            len(runs),
            run.spec.seed,
            env_params=run.spec.run_env_params(runs),
            resume=state,
            on_compiled=hooks.on_compiled,
            on_chunk=handler,
            should_stop=should_stop,
            keep_metrics=False,  # streamed to disk by the handler, chunk by chunk
        )
    finally:
        logger.close()


def evaluate_wave(
    run: Run,
    params: dict,
    episodes: int,
    runs: range | None = None,
    stop: StopRequest | None = None,
) -> Evaluation:
    """Greedy returns of ``runs`` (default all) in Gymnasium's CartPole-v1 and in jaxcart
    (raises :class:`~jaxcart.engine.signals.Stopped` when ``stop`` is requested meanwhile)."""
    runs = runs if runs is not None else range(run.grid.num_runs)
    start = time.perf_counter()
    gym_returns, jax_returns = evaluate_runs(
        params,
        run.config,
        run.spec.seed,
        run.grid.seed_indices(runs),
        episodes,
        should_stop=stop,
        env_params=run.spec.eval_env_params(runs),
    )
    seconds = time.perf_counter() - start
    return Evaluation(episodes, gym_returns, jax_returns, seconds, env=run.config.env)


class ChunkHandler:
    """What happens after every chunk: the metrics appended to the run directory's stream,
    loggers, periodic checkpoints, divergence reports, then the caller's ``on_chunk``."""

    def __init__(
        self, run: Run, options: RunOptions, hooks: Hooks, logger: Logger, runs: range, wave: int
    ) -> None:
        self.run, self.options, self.hooks, self.logger = run, options, hooks, logger
        self.runs, self.wave = runs, wave  # progress.diverged_at is indexed within the wave
        self.last_save = time.monotonic()
        self.reported: set[int] = set()
        grid = run.grid
        self.clip_ranges = np.array(
            [
                grid.combos[grid.combo_of(r)].get("clip_coef", run.config.clip_coef)
                if grid.is_sweep
                else run.config.clip_coef
                for r in runs
            ],
            np.float64,
        )

    def __call__(self, progress: Progress) -> None:
        run = self.run
        run.trained_chunks += 1
        new = [
            int(r) for r in np.flatnonzero(progress.diverged_at >= 0) if int(r) not in self.reported
        ]
        self.reported.update(new)
        if self.hooks.on_diverged and run.main_process:
            for r in new:
                name = run.grid.run_name(self.runs.start + r)
                self.hooks.on_diverged(name, int(progress.diverged_at[r]))
        run.directory.stream.append(progress.metrics)
        count = len(progress.metrics["time/fps"])
        first = progress.iteration - count
        steps = (first + 1 + np.arange(count)) * run.config.batch_size
        extras = sb3_extras(first, count, run.config.update_epochs, self.clip_ranges)
        self.logger.log(first, steps, {**progress.metrics, **extras})
        due = time.monotonic() - self.last_save >= self.options.checkpoint_every
        due = distributed.any_process(due)  # every process must agree on when to gather
        if due and progress.iteration < run.config.num_iterations:
            save_state(run, progress.state(), self.wave)
            self.last_save = time.monotonic()
        if self.hooks.on_chunk:
            self.hooks.on_chunk(progress)


def _one_wave(
    run: Run,
    options: RunOptions,
    hooks: Hooks,
    stop: StopRequest,
    outcome: Outcome,
    runs: range,
    wave: int,
) -> Block | None:
    """Trains, checkpoints and evaluates one wave; None when stopped (its state
    checkpointed, and, for a run in one wave, its metrics so far written)."""
    try:
        result = train_wave(run, options, hooks, should_stop=stop, runs=runs, wave=wave)
    except Stopped:  # during initialisation: the checkpoint on disk (if any) is untouched
        return None
    outcome.result, outcome.num_devices = result, result.num_devices
    outcome.compile_seconds += result.compile_seconds
    outcome.train_seconds += result.run_seconds
    outcome.env_steps += result.env_steps
    save_state(run, result.state, wave)
    diverged = np.asarray(distributed.gather(result.state.runners.diverged_at))
    if result.stopped:
        if run.main_process and run.plan.num_waves == 1:
            run.directory.write_metrics(run.config.batch_size)
        return None
    params = distributed.gather(result.params)
    best_params = best = None
    if run.config.keep_best:
        kept = distributed.gather(result.state.runners.best)
        best_params = files.flatten(kept.params)
        best = {"best_iteration": np.asarray(kept.iteration), "best_score": np.asarray(kept.score)}
    evaluation = Evaluation(
        options.eval_episodes, np.zeros((len(runs), 0)), np.zeros((len(runs), 0)), 0.0
    )
    if run.main_process:
        try:
            stop.check()
            evaluation = evaluate_wave(run, params, options.eval_episodes, runs, stop)
            if best is not None:  # the Gymnasium verdict of the best policies too
                verdict = evaluate_wave(run, kept.params, options.eval_episodes, runs, stop)
                best["best_gym_returns"] = verdict.gym_returns
        except Stopped:
            return None
    timing = {
        "compile_seconds": result.compile_seconds,
        "train_seconds": result.state.elapsed,
        "eval_seconds": evaluation.seconds,
    }
    return Block(
        runs.start,
        runs.stop,
        files.flatten(params),
        run.directory.stream.read(),  # memory-mapped from the stream
        diverged,
        evaluation.gym_returns,
        evaluation.jax_returns,
        timing,
        best_params,
        best,
    )


def _finish(
    run: Run, blocks: list, episodes: int, outcome: Outcome, score: Score | None = None
) -> None:
    """The run directory's outputs and the outcome's per-run summary, from every block; a
    sweep's combinations ranked by ``score`` (None: the one config.json records, else eval)."""
    config = run.config
    steps = np.arange(1, config.num_iterations + 1) * config.batch_size
    columns: dict[str, list] = {k: [] for k in ("gym", "jax", "div", "final", "reach")}
    timing = {"compile_seconds": 0.0, "train_seconds": 0.0, "eval_seconds": 0.0}
    for block, take in overlapping(blocks, range(run.grid.num_runs)):
        columns["gym"].append(block.gym_returns[take])
        columns["jax"].append(block.jax_returns[take])
        columns["div"].append(block.diverged_at[take])
        columns["final"].append(block.metrics["rollout/ep_rew_mean"][-1, take])
        reached = sweeps.first_reach(block.metrics["rollout/ep_rew_max"][:, take], steps)
        columns["reach"].append(reached)
        for k in timing:
            timing[k] += float(block.timing.get(k, 0.0))
    gym, jax_returns, div, final, reach = (np.concatenate(columns[k]) for k in columns)
    outcome.evaluation = Evaluation(
        episodes, gym, jax_returns, timing["eval_seconds"], env=run.config.env
    )
    outcome.diverged_at, outcome.final_return = div, final
    _write_outputs(
        run, blocks, episodes, {**timing, "devices": outcome.num_devices, "waves": len(blocks)}
    )
    if run.grid.is_sweep:
        ranked_by = score or Score.parse(run.info.get("score", "eval"))
        curves = None  # [iterations, R], read only for a score that needs them
        if ranked_by.name != "eval":
            parts = overlapping(blocks, range(run.grid.num_runs))
            curves = np.concatenate([b.metrics["rollout/ep_rew_mean"][:, t] for b, t in parts], 1)
        try:
            scores = ranked_by.compute(gym.mean(-1), curves, steps, run.config.env)
        except ValueError as exc:  # return-at past the run's end (train checks it first)
            raise ConfigError(f"cannot rank by --score {ranked_by.label}: {exc}") from None
        solved = outcome.evaluation.solved
        outcome.ranking = sweeps.rank(
            run.grid, scores, solved, final, reach, div, score=ranked_by.label
        )
        data = {
            "sweep": run.sweep,
            "num_seeds": run.grid.num_seeds,
            "score": ranked_by.label,
            "score_definition": ranked_by.definition,
            "saturated": sweeps.saturated(outcome.ranking),
            "ranking": outcome.ranking,
        }
        run.directory.write_ranking(data)


def _write_outputs(run: Run, blocks: list, episodes: int, timing: dict) -> None:
    """metrics.csv, params.npz and evaluation.json from the runs' blocks: per combination
    for a sweep, each with its own config.json."""
    for c, combo in enumerate(run.grid.combos or ({},)):
        runs = run.grid.runs_of(c)
        record = None
        if run.grid.is_sweep:  # a combination of no float values too (tune's shape trials)
            info = {**run.info, "combination": combo, "sweep": {}, "combinations": []}
            record = (info, run.spec.combo_config(c))
        where = c if run.grid.is_sweep else None
        batch = run.config.batch_size
        span = range(runs.start, runs.stop)
        run.directory.write_outputs(
            where,
            blocks,
            span,
            episodes,
            timing,
            batch,
            record,
            best=run.config.keep_best,
            env_id=run.config.env,
        )
