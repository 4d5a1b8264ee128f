"""Metric logging to TensorBoard, SwanLab and Weights & Biases, off the training hot path.

The host gets metrics after every compiled chunk of iterations. :meth:`Logger.log` only
validates, copies the arrays and puts them on a queue; one daemon thread per backend does the
writing, so a slow disk (or a slow library) never stalls training. A backend that fails is
reported once on stderr, switched off for the rest of the run, and its error is raised again
by :meth:`Logger.close`; training itself never sees it.

Every backend logs Stable-Baselines3's names (``rollout/ep_rew_mean``, ``train/approx_kl``,
``time/time_elapsed``, ``train/clip_range``, ``train/n_updates``, ...: :data:`SB3_NAMES`) plus
``time/iterations``, at step = env steps of that run, so jaxcart's curves and SB3's sit on the
same axes. ``log_dir`` (the commands' ``--logger-dir``) is one folder that several runs share.

Backends (each imported when its logger is made, and run in its own thread):

- ``tensorboard``: TensorBoard event files written with ``tensorboardX``, one TensorBoard run
  per training run in ``out_dir/tensorboard/<run_name>/``, or with ``log_dir`` in
  ``log_dir/<run directory's name>/<run_name>/``. View with ``tensorboard --logdir`` that
  folder.
- ``swanlab``: SwanLab without a server (nothing leaves the machine), written under
  ``log_dir``, else ``$SWANLAB_LOG_DIR``, else ``./swanlog`` (SwanLab's own default, so that
  ``swanlab watch swanlog`` shows every run started from this folder), one
  ``run-<time>-<id>/`` per experiment, named after the run directory. SwanLab allows one
  active experiment per process, so the R runs share one experiment: with R > 1 each run's
  metrics go under ``<run_name>/<metric>`` and the mean over runs (of those that have a value)
  under the plain SB3 names, for runs logged apart (SB3's seeds) once every run has logged
  that step; ``time/*`` is the same for every run and logged once. With R = 1
  only the plain names are logged. Each batch SwanLab writes is flushed to its records file
  at once (SwanLab itself flushes it only at the end), so the curve grows on disk as the run
  trains. Mode ``offline`` by default: records for ``swanlab sync``
  (uploads; needs an account or a self-hosted server). With ``pip install
  'swanlab[dashboard]'`` the mode is ``local`` instead, which also fills the database that
  ``swanlab watch swanlog`` serves on localhost.
- ``wandb``: Weights & Biases, one W&B run per training run (named after it), grouped by the
  run directory's name, in project ``$WANDB_PROJECT`` (default ``jaxcart``) and entity
  ``$WANDB_ENTITY`` (default: the account's), under ``log_dir/wandb/``, else
  ``$WANDB_DIR/wandb/``, else ``out_dir/wandb/``. Offline by default (nothing leaves the
  machine; ``wandb sync .../wandb/offline-run-*`` uploads later); ``WANDB_MODE`` (``online``,
  ``offline``, ``disabled``) is respected when set.

NaN values (``rollout/ep_rew_mean`` before the first episode ends) are skipped, not logged.
"""

from __future__ import annotations

import atexit
import contextlib
import importlib.util
import io
import json
import os
import queue
import sys
import textwrap
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from jaxcart.core.config import ConfigError, PPOConfig
from jaxcart.rundir import files

SB3_NAMES = {"time/elapsed": "time/time_elapsed"}
"""jaxcart metric name -> the name Stable-Baselines3 logs it under, where they differ."""


class LoggerUnavailable(ConfigError):
    """A requested logger's package is not installed (the message says which extra to add):
    a user's mistake, as every :class:`ConfigError` is (one line from a command)."""


class LoggerError(RuntimeError):
    """One or more backends failed while training; raised by :meth:`Logger.close`."""


@dataclass(frozen=True)
class MetricBatch:
    """One chunk's metrics, owned by the logger (copied from the caller's arrays).

    Attributes:
        first_iteration: iterations completed before the chunk (the first row is iteration
            ``first_iteration + 1``, counted from 1 as SB3's ``time/iterations`` is).
        env_steps: ``[n]`` env steps of each run after each iteration (the step axis).
        metrics: name -> ``[n, len(runs)]`` float64, one column per run in ``runs``.
        runs: the runs the columns belong to (every run, or one trained apart: an SB3 seed).
    """

    first_iteration: int
    env_steps: np.ndarray
    metrics: dict[str, np.ndarray]
    runs: tuple[int, ...]

    @property
    def iterations(self) -> np.ndarray:
        """``[n]`` SB3's ``time/iterations`` of each row."""
        return self.first_iteration + 1 + np.arange(len(self.env_steps))

    def rows(self, column: int) -> Iterator[tuple[int, dict[str, float]]]:
        """``(env steps, {"time/iterations": ..., name: value})`` of each row of column
        ``column`` (run ``runs[column]``), its NaN values left out."""
        for i, step in enumerate(self.env_steps):
            row: dict[str, float] = {"time/iterations": int(self.iterations[i])}
            for name, values in self.metrics.items():
                if not np.isnan(values[i, column]):
                    row[name] = float(values[i, column])
            yield int(step), row


class Backend:
    """A writer for one library (``name``: also the pip extra of jaxcart that installs it).
    ``__init__`` (cheap) keeps :func:`make_logger`'s arguments, which also imports ``module``
    in the caller's thread; a subclass's ``open()``, ``write(batch: MetricBatch)`` and
    ``close()`` run in the backend's own thread, in that order."""

    name: ClassVar[str]
    module: ClassVar[str | None]  # package that must be importable (None: nothing needed)

    def __init__(
        self, out_dir: Path, run_names: list[str], config: dict, log_dir: Path | None = None
    ) -> None:
        self.out_dir, self.run_names = Path(out_dir), run_names
        self.config = json.loads(json.dumps(config, default=str))  # every value JSON-able
        self.log_dir = log_dir  # the folder shared with other runs (None: the library's own)
        # the name the logs go under: the run directory's
        self.experiment = self.out_dir.resolve().name or "jaxcart"
        self.per_run: list[Any] = []  # each run's writer (TensorBoard) or W&B run


class TensorBoardBackend(Backend):
    """One event file per run in ``out_dir/tensorboard/<run_name>/`` (or
    ``log_dir/<run directory's name>/<run_name>/``); each iteration is one event per run
    holding all its scalars, at ``global_step`` = env steps."""

    name = "tensorboard"
    module = "tensorboardX"

    def open(self) -> None:
        from tensorboardX import FileWriter
        from tensorboardX.summary import text

        # Markdown: indenting by four spaces shows the JSON as a code block in the Text tab.
        config_text = textwrap.indent(json.dumps(self.config, indent=2), "    ")
        if self.log_dir is None:
            base = files.subdir(self.out_dir, "tensorboard", create=True)  # never through a link
        else:  # the user's own folder, shared with other runs
            base = Path(self.log_dir) / self.experiment
            base.mkdir(parents=True, exist_ok=True)
        for run in self.run_names:
            files.subdir(base, run, create=True)
            writer = FileWriter(str(base / run), max_queue=1024, flush_secs=30)
            self.per_run.append(writer)
            writer.add_summary(text("config", config_text), global_step=0)

    def write(self, batch: MetricBatch) -> None:
        from tensorboardX.proto.summary_pb2 import Summary

        for c, r in enumerate(batch.runs):
            for step, row in batch.rows(c):
                values = [Summary.Value(tag=k, simple_value=v) for k, v in row.items()]
                self.per_run[r].add_summary(Summary(value=values), global_step=step)
            self.per_run[r].flush()  # TensorBoard sees every chunk as soon as it is written

    def close(self) -> None:
        for writer in self.per_run:
            writer.close()
        self.per_run = []


def swanlab_mode() -> str:
    """``"local"`` when SwanLab's dashboard (``swanboard``, from ``pip install
    'swanlab[dashboard]'``) is installed at the version SwanLab asks for: the run is then also
    written to the database that ``swanlab watch`` serves. Otherwise ``"offline"`` (records
    only, for ``swanlab sync``). Both stay on this machine."""
    from importlib import metadata

    try:
        installed = metadata.version("swanboard")
    except metadata.PackageNotFoundError:
        return "offline"
    if os.environ.get("SWANLAB_SKIP_SWANBOARD_VERSION_CHECK") == "1":
        return "local"
    # SwanLab refuses any swanboard but the one its "dashboard" extra pins.
    pins = (r.replace(" ", "") for r in metadata.requires("swanlab") or [])
    wanted = {r.split("==")[1].split(";")[0] for r in pins if r.startswith("swanboard==")}
    return "local" if installed in wanted else "offline"


class SwanLabBackend(Backend):
    """One SwanLab experiment for all runs (SwanLab allows one per process): with R > 1,
    ``<run_name>/<metric>`` per run plus the mean over runs under the plain names."""

    name = "swanlab"
    module = "swanlab"

    run: Any = None
    pending: dict[int, dict[int, dict[str, float]]]  # step -> run -> name -> value

    def open(self) -> None:
        # log_dir, else $SWANLAB_LOG_DIR, else ./swanlog
        folder = Path(self.log_dir or os.environ.get("SWANLAB_LOG_DIR") or "swanlog").absolute()
        folder.mkdir(parents=True, exist_ok=True)
        self.pending = {}
        import swanlab

        Settings = swanlab.Settings
        settings = Settings(
            # offline/local: write records locally and never contact a server;
            # interactive=False: never prompt (no TTY in CI); no terminal proxy: SwanLab would
            # otherwise wrap sys.stdout/sys.stderr (the progress bar's stream); no
            # hardware-monitor thread; no webhook even if SWANLAB_WEBHOOK is set.
            mode=swanlab_mode(),
            interactive=False,
            log_dir=folder,
            terminal=Settings.Terminal(proxy_type="none"),
            probe=Settings.Probe(monitor=False),
            integration=Settings.Integration(webhook=Settings.Integration.Webhook(url="")),
        )
        # Started from this (non-main) thread on purpose: SwanLab then leaves SIGINT handling
        # to the training CLI instead of installing its own handler.
        self.run = swanlab.init(
            project="jaxcart",
            name=self.experiment,
            description=f"{len(self.run_names)} run(s): {', '.join(self.run_names)}",
            config={**self.config, "run_names": self.run_names},
            settings=settings,
            callbacks=[self._flush_records(swanlab.Callback)],
        )

    def _flush_records(self, base: type) -> Any:
        """A SwanLab callback that puts each batch of scalars into the run's ``.swanlab``
        file as soon as SwanLab has written it. SwanLab 0.10 keeps its records file open with
        Python's buffer and flushes it only when the run finishes, so without this a run's
        curve would appear on disk (for ``swanlab sync``, or any reader) only at the end. It
        runs in SwanLab's own writer thread, right after the batch is written; where a SwanLab
        version has no such writer (``run._core._store``), it does nothing."""
        backend = self

        class FlushRecords(base):
            name = "jaxcart-flush-records"

            def on_scalar_flush(self, *args, **kwargs) -> None:
                store = getattr(getattr(backend.run, "_core", None), "_store", None)
                if store is not None and hasattr(store, "ensure_flushed"):
                    store.ensure_flushed()

        return FlushRecords()

    def write(self, batch: MetricBatch) -> None:
        columns = range(len(batch.runs) if len(self.run_names) > 1 else 0)
        per_run = [list(batch.rows(c)) for c in columns]
        for i, step in enumerate(batch.env_steps):
            data: dict[str, float] = {"time/iterations": int(batch.iterations[i])}
            for name, row in (self._every_run(batch, i) or {}).items():
                present = row[~np.isnan(row)]
                if present.size:
                    data[name] = float(present.mean())
            for r, rows in zip(batch.runs, per_run):
                name = self.run_names[r]
                data |= {f"{name}/{k}": v for k, v in rows[i][1].items() if k[:5] != "time/"}
            self.run.log(data, step=int(step))

    def _every_run(self, batch: MetricBatch, i: int) -> dict[str, np.ndarray] | None:
        """name -> ``[R]``: row ``i``'s values of every run, once every run has logged its
        step (a batch of one run, an SB3 seed, waits for the others: SwanLab keeps the first
        value logged at a step, so the mean is logged once); None while some have not."""
        if len(batch.runs) == len(self.run_names):  # a training's batch: every run at once
            return {name: values[i] for name, values in batch.metrics.items()}
        step = int(batch.env_steps[i])
        seen = self.pending.setdefault(step, {})
        for c, r in enumerate(batch.runs):
            seen[r] = {name: values[i, c] for name, values in batch.metrics.items()}
        if len(seen) < len(self.run_names):
            return None
        del self.pending[step]
        every = range(len(self.run_names))
        return {n: np.array([seen[r].get(n, np.nan) for r in every]) for n in batch.metrics}

    def close(self) -> None:
        if self.run is not None:
            # SwanLab prints its sync/watch hint when the run starts and again here: one is
            # enough. What else finish prints (its warnings and errors) is passed on. The
            # caller waits in Logger.close meanwhile, so nothing else is printing.
            printed = io.StringIO()
            with contextlib.redirect_stdout(printed):
                self.run.finish()
            if "WARNING" in printed.getvalue() or "ERROR" in printed.getvalue():
                sys.stdout.write(printed.getvalue())
            self.run = None


class WandbBackend(Backend):
    """One W&B run per training run, grouped by the run directory; offline unless
    ``WANDB_MODE`` says otherwise; ``WANDB_PROJECT``, ``WANDB_ENTITY`` and ``WANDB_DIR``
    (below ``log_dir``) are honoured."""

    name = "wandb"
    module = "wandb"

    def open(self) -> None:
        import wandb

        folder = Path(self.log_dir or os.environ.get("WANDB_DIR") or self.out_dir)
        if folder == self.out_dir:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            files.subdir(self.out_dir, "wandb", create=True)  # W&B writes here; never via a link
        else:
            (folder / "wandb").mkdir(parents=True, exist_ok=True)
        # offline unless the user chose otherwise; no console capture (it would wrap the
        # progress bar's stream), no system-metrics sampling thread
        settings = wandb.Settings(
            mode=os.environ.get("WANDB_MODE") or "offline",
            console="off",
            x_disable_stats=True,
            silent=True,
        )
        for run in self.run_names:
            self.per_run.append(
                wandb.init(
                    project=os.environ.get("WANDB_PROJECT") or "jaxcart",
                    entity=os.environ.get("WANDB_ENTITY") or None,
                    group=self.experiment,
                    name=f"{self.experiment}-{run}",
                    job_type="train",
                    dir=str(folder),
                    config={**self.config, "run_name": run},
                    settings=settings,
                    reinit="create_new",  # every seed's run open at once
                )
            )

    def write(self, batch: MetricBatch) -> None:
        for c, r in enumerate(batch.runs):
            for step, row in batch.rows(c):
                self.per_run[r].log(row, step=step)

    def close(self) -> None:
        import wandb

        for run in self.per_run:
            run.finish()
        if self.per_run:
            # finish() can return before W&B's service process has written a run's last
            # records (seen with 0.31: the second of two offline runs still empty); stopping
            # the service waits for it, so the files are complete when training returns
            wandb.teardown()
        self.per_run = []


BACKENDS: dict[str, type[Backend]] = {
    backend.name: backend for backend in (TensorBoardBackend, SwanLabBackend, WandbBackend)
}
"""Logger name -> backend class (tests may register more)."""

_STOP = object()


class _Worker:
    """A backend, its queue and the daemon thread that drains it."""

    def __init__(self, backend: Backend) -> None:
        self.backend = backend
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.error: BaseException | None = None
        self.thread = threading.Thread(
            target=self._run, name=f"jaxcart-logger-{backend.name}", daemon=True
        )
        self.thread.start()

    def _run(self) -> None:
        self._attempt(self.backend.open)
        while (item := self.queue.get()) is not _STOP:
            if self.error is None:
                self._attempt(self.backend.write, item)
        # Closed even after a failure: flushes what was written and releases the files.
        self._attempt(self.backend.close)

    def _attempt(self, fn, *args) -> None:
        try:
            fn(*args)
        except Exception as exc:
            if self.error is None:
                self.error = exc
                print(
                    f"jaxcart: warning: {self.backend.name} logging failed and is off for the rest "
                    f"of this run ({type(exc).__name__}: {exc}); logger.close() will raise it",
                    file=sys.stderr,
                    flush=True,
                )


class Logger(contextlib.AbstractContextManager):
    """Fans each chunk's metrics out to the backends' queues; see :func:`make_logger`.

    Use as a context manager or call :meth:`close`; a logger with no backends does nothing.
    """

    def __init__(self, backends: Sequence[Backend], num_runs: int) -> None:
        self.num_runs = num_runs
        self._workers = [_Worker(b) for b in backends]
        self._closed = False
        if self._workers:
            atexit.register(self._close_at_exit)

    @property
    def names(self) -> list[str]:
        """The active backends' names."""
        return [w.backend.name for w in self._workers]

    @property
    def errors(self) -> dict[str, BaseException]:
        """Backend name -> the first error it raised (empty while all is well)."""
        return {w.backend.name: w.error for w in self._workers if w.error is not None}

    def log(
        self,
        first_iteration: int,
        env_steps: np.ndarray,
        metrics: dict[str, np.ndarray],
        run: int | None = None,
    ) -> None:
        """Queues one chunk's metrics and returns at once (the arrays are copied).

        Args:
            first_iteration: iterations completed before this chunk.
            env_steps: ``[n]`` env steps of each run after each of the chunk's iterations.
            metrics: name -> ``[n, R]`` (or ``[n]``, the same for every run); with ``run``,
                ``[n, 1]`` or ``[n]``.
            run: the metrics are of this run alone (runs trained apart, as SB3's seeds); the
                other runs log nothing at these steps.

        Raises:
            ValueError: a leaf's shape does not match ``[n, R]``, or ``run`` is not a run.
            RuntimeError: the logger is closed.
        """
        if self._closed:
            raise RuntimeError("Logger.log() called after close()")
        if run is not None and run not in range(self.num_runs):
            raise ValueError(f"run {run} is not one of the {self.num_runs} runs")
        if not self._workers:
            return
        runs = tuple(range(self.num_runs)) if run is None else (run,)
        steps = np.array(env_steps, dtype=np.int64).reshape(-1)
        n = len(steps)
        copied = {}
        for name, value in metrics.items():
            array = np.array(value, dtype=np.float64)
            if array.ndim == 1:
                array = np.repeat(array[:, None], len(runs), axis=1)
            if array.shape != (n, len(runs)):
                raise ValueError(
                    f"metric {name!r} has shape {array.shape}; expected ({n}, {len(runs)}) "
                    f"= (len(env_steps), number of runs)"
                )
            copied[SB3_NAMES.get(name, name)] = array
        if n == 0:
            return
        batch = MetricBatch(int(first_iteration), steps, copied, runs)
        for worker in self._workers:
            worker.queue.put(batch)

    def log_iterations(
        self, first: int, metrics: dict, config: PPOConfig, clip: np.ndarray, run: int | None = None
    ) -> None:
        """:meth:`log` of a training's ``metrics`` for the iterations after ``first`` (the
        ``config``'s batch size of env steps each), with the metrics SB3 logs that
        jaxcart's step does not compute: ``train/n_updates`` (epochs run so far, as SB3 counts
        them) and ``train/clip_range`` from each run's ``clip [R]``."""
        count = len(metrics["time/fps"])
        iterations = first + 1 + np.arange(count)
        clip = np.broadcast_to(np.asarray(clip, np.float64), (count, len(clip)))
        extras = {"train/n_updates": iterations * config.update_epochs, "train/clip_range": clip}
        self.log(first, iterations * config.batch_size, {**metrics, **extras}, run)

    def close(self) -> None:
        """Writes everything queued, closes the backends and waits for them. Idempotent.

        Raises:
            LoggerError: a backend failed during the run (it was already warned about once).
        """
        if self._closed:
            return
        self._closed = True
        for worker in self._workers:
            worker.queue.put(_STOP)
        for worker in self._workers:
            worker.thread.join()
        if self._workers:
            atexit.unregister(self._close_at_exit)
        errors = self.errors
        if errors:
            message = "; ".join(f"{name} logging failed: {exc!r}" for name, exc in errors.items())
            raise LoggerError(message) from next(iter(errors.values()))

    def _close_at_exit(self) -> None:
        with contextlib.suppress(LoggerError):  # already reported on stderr
            self.close()

    def __exit__(self, exc_type, *exc_info) -> None:
        try:
            self.close()
        except LoggerError:
            if exc_type is None:
                raise  # else already reported: let the original exception through


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def check_available(names: Sequence[str]) -> None:
    """Raises :class:`LoggerUnavailable` if a named backend's package is not installed
    (cheap: nothing is imported), so a CLI can refuse before it creates anything."""
    for name in dict.fromkeys(names):
        backend = BACKENDS.get(name)
        if backend is not None and backend.module is not None and not _installed(backend.module):
            raise LoggerUnavailable(
                f"the {name} logger needs the {backend.module} package: "
                f"pip install 'jaxcart[{name}]' (in a clone of jaxcart: "
                f"pip install -e '.[{name}]')"
            )


def make_logger(
    names: Sequence[str],
    out_dir: Path,
    run_names: Sequence[str],
    config: dict | None = None,
    log_dir: Path | None = None,
) -> Logger:
    """A :class:`Logger` writing to each named backend (``[]``: a logger that does nothing).

    Args:
        names: backends, a subset of :data:`BACKENDS` (``"tensorboard"``, ``"swanlab"``,
            ``"wandb"``).
        out_dir: the run directory; each backend writes in its own subdirectory.
        run_names: one name per run (the ``R`` axis of the metrics), used as directory names.
        config: JSON-able settings stored with the logs.
        log_dir: one folder for every backend, shared with other runs (default: SwanLab's
            ``$SWANLAB_LOG_DIR`` or ``./swanlog``, W&B's ``$WANDB_DIR`` or ``out_dir``,
            TensorBoard's ``out_dir/tensorboard``).

    Raises:
        LoggerUnavailable: a backend's package is not installed.
        ValueError: an unknown backend name or unusable run names.
    """
    names = list(dict.fromkeys(names))
    unknown = [n for n in names if n not in BACKENDS]
    if unknown:
        raise ValueError(f"unknown logger(s) {unknown}; choose from {', '.join(BACKENDS)}")
    run_names = [str(r) for r in run_names]
    if not run_names or len(set(run_names)) != len(run_names):
        raise ValueError(f"run_names must be non-empty and unique, got {run_names}")
    bad = [r for r in run_names if not r or r in (".", "..") or "/" in r or "\\" in r]
    if bad:
        raise ValueError(f"run names must be usable as directory names, got {bad}")
    check_available(names)
    for name in names:  # here, not first in a logger's thread: imports racing can deadlock
        if BACKENDS[name].module is not None:
            importlib.import_module(BACKENDS[name].module)
    backends = [BACKENDS[n](Path(out_dir), run_names, config or {}, log_dir) for n in names]
    return Logger(backends, len(run_names))
