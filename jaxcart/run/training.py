"""The training steps of one wave of a run: its starting state, training it in chunks with
periodic checkpoints and logging, and evaluating it greedily.

:mod:`jaxcart.run.lifecycle` strings these together; the files are the run directory's
(:class:`~jaxcart.rundir.directory.RunDir`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable

import jax
import numpy as np

from jaxcart.core.config import PPOConfig
from jaxcart.engine import distributed
from jaxcart.engine.signals import Stopped, StopRequest
from jaxcart.engine.trainer import (
    CHUNK_SECONDS,
    Progress,
    TrainResult,
    TrainState,
    initial_state,
    train,
)
from jaxcart.run import sweep as sweeps
from jaxcart.run.evaluation import evaluate_runs
from jaxcart.run.loggers import Logger, make_logger
from jaxcart.run.spec import Evaluation, Hooks, Run, RunOptions
from jaxcart.rundir.directory import package_versions


def run_configs(run: Run) -> PPOConfig:
    """Every run's config, its traced fields ``[R]``."""
    return sweeps.grid_config(run.config, run.grid)


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
        template = initial_state(run.config, 1, run.spec.seed, chunk_size=chunk_size)
        saved = run.directory.load_checkpoint(template, num_runs=len(runs))
        run.directory.open_metrics(len(runs), saved.iteration)  # rows after it are cut
        return dataclasses.replace(saved, chunk_seconds=adapt)
    configs = jax.tree.map(lambda x: x[runs.start : runs.stop], run_configs(run))
    fresh = initial_state(
        configs,
        len(runs),
        run.spec.seed,
        chunk_size=chunk_size,
        seed_indices=run.grid.seed_indices()[runs.start : runs.stop],
        on_progress=on_progress,
    )
    run.directory.open_metrics(len(runs), 0)
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
    logger = make_logger(loggers, run.out, names, info)
    handler = ChunkHandler(run, options, hooks, logger, runs, wave)
    try:
        return train(
            run.config,
            len(runs),
            run.spec.seed,
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
        run.grid.seed_indices()[runs.start : runs.stop],
        episodes,
        should_stop=stop,
    )
    return Evaluation(episodes, gym_returns, jax_returns, time.perf_counter() - start)


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
        run.directory.stream.append(progress.metrics)
        count = len(progress.metrics["time/fps"])
        first = progress.iteration - count
        steps = (first + 1 + np.arange(count)) * run.config.batch_size
        self.logger.log(first, steps, progress.metrics)
        due = time.monotonic() - self.last_save >= self.options.checkpoint_every
        due = distributed.any_process(due)  # every process must agree on when to gather
        if due and progress.iteration < run.config.num_iterations:
            save_state(run, progress.state(), self.wave)
            self.last_save = time.monotonic()
        if self.hooks.on_chunk:
            self.hooks.on_chunk(progress)
