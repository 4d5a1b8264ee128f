"""A run directory as the run that owns it sees it: created or opened under its lock, then
written as training goes (``config.json``, checkpoints, finished waves, outputs).

:class:`RunDir` is the run's persistence and nothing else: what to train and when to save
is decided by :mod:`jaxcart.run.lifecycle`. Every file goes through
:func:`jaxcart.rundir.files.atomic_file` and is read back through :mod:`jaxcart.rundir.reader`.
"""

from __future__ import annotations

import contextlib
import functools
import os
from importlib import metadata
from pathlib import Path

from jaxcart.core.config import ConfigError, PPOConfig, float_dtype
from jaxcart.engine.loop import METRIC_COLUMNS, TrainState
from jaxcart.rundir import checkpoint, files, layout, outputs, reader
from jaxcart.rundir.checkpoint import load_checkpoint, read_checkpoint_meta
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.lock import RunLock
from jaxcart.rundir.stream import MetricsStream, NoStream

VERSIONED_PACKAGES = ("jaxcart", "jax", "jaxlib", "flax", "optax", "distrax", "gymnasium", "numpy")
"""The packages that determine a run's numbers, recorded in config.json and checkpoints."""
RESUME_PACKAGES = ("jaxcart", "jax", "jaxlib")
"""Those a run must be continued with to continue bit-identically."""


@functools.cache
def _installed_versions() -> tuple[tuple[str, str], ...]:
    versions = []
    for name in VERSIONED_PACKAGES:
        try:
            versions.append((name, metadata.version(name)))
        except metadata.PackageNotFoundError:
            versions.append((name, "not installed"))
    return tuple(versions)


def package_versions() -> dict[str, str]:
    """Versions of the packages that determine a run's numbers (looked up once per process:
    every checkpoint records them)."""
    return dict(_installed_versions())


def check_versions(run_dir: str | os.PathLike, saved: dict) -> None:
    """Refuses to continue a run whose checkpoint (or config) was written by other versions
    of the packages in :data:`RESUME_PACKAGES`."""
    now = package_versions()
    for name in RESUME_PACKAGES:
        if saved.get(name) != now[name]:
            raise RunDirError(
                f"{run_dir} was trained with {name} {saved.get(name)}, this is {now[name]}; "
                f"reinstall {name}=={saved.get(name)} to continue it bit-identically"
            )


def _leftover(path: Path) -> bool:
    """Left by a start that failed before writing anything: a temporary or the lock."""
    return layout.is_temporary(path) or path.name == layout.LOCK_FILE


def prepare_out_dir(out: Path) -> Path:
    """Creates ``out``; refuses a non-empty or unwritable one with a clear message. A
    directory holding only what a failed start leaves (its ``.lock``, temporaries) is taken
    over (:meth:`RunDir.create` then takes its lock, so a live start is never taken over)."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a directory; choose another path")
    if out.is_dir():
        files.refuse_link(out / layout.LOCK_FILE)
    if out.is_dir() and any(not _leftover(p) for p in out.iterdir()):
        raise ConfigError(
            f"--out {out} is not empty; choose a new directory so no earlier run is "
            f"overwritten (or continue it with --resume {out})"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / layout.WRITE_PROBE
        files.refuse_link(probe)
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    return out


def _remove_failed_start(out: Path, created: bool) -> None:
    """Removes what a start that failed before its ``config.json`` left: the lock, and the
    directory when this start created it (a rerun then starts afresh)."""
    with contextlib.suppress(OSError):
        if not (out / layout.CONFIG_FILE).exists():
            (out / layout.LOCK_FILE).unlink(missing_ok=True)
            if created:
                out.rmdir()


class RunDir:
    """One run directory, locked by the main process from :meth:`create`/:meth:`open` to
    :meth:`close`. Only the main process writes; the others hold no lock."""

    def __init__(self, path: str | os.PathLike, main_process: bool = True) -> None:
        self.path, self.main_process = Path(path), main_process
        self.lock = RunLock(self.path)
        self.checkpoint_meta: dict | None = None  # of the checkpoint on disk, when there is one
        self.stream: MetricsStream | NoStream = NoStream()  # the metrics of the wave training

    @classmethod
    def create(
        cls, path: str | os.PathLike, info: dict, config: PPOConfig, main_process: bool = True
    ) -> RunDir:
        """A new run directory (refusing a non-empty one), locked, with its ``config.json``
        (``info`` and ``config``)."""
        directory = cls(path, main_process)
        if main_process:
            created = not directory.path.exists()
            prepare_out_dir(directory.path)
            directory.lock.acquire()
            try:
                directory.write_config(info, config)
            except BaseException:
                _remove_failed_start(directory.path, created)  # while holding the lock
                directory.close()
                raise
        return directory

    @classmethod
    def open(cls, path: str | os.PathLike, main_process: bool = True) -> RunDir:
        """An existing run directory, locked before its checkpoint is read (another process
        may be writing it); :class:`RunInUse` when another process holds it."""
        directory = cls(path, main_process)
        if main_process:
            directory.lock.acquire()
        return directory

    def read_checkpoint_meta(self) -> dict | None:
        """:attr:`checkpoint_meta` read from the checkpoint on disk; None when there is none
        (stopped while starting up: nothing was trained)."""
        path = self.checkpoint_path
        self.checkpoint_meta = read_checkpoint_meta(path) if layout.present(path) else None
        return self.checkpoint_meta

    def close(self) -> None:
        """Releases the run directory for other processes."""
        self.stream.close()
        self.lock.release()

    def write_config(self, info: dict, config: PPOConfig, directory: Path | None = None) -> None:
        """``config.json``: ``info`` with ``config`` as a dict (in a combination's
        ``directory`` when given); a sweep's combinations are left to the reader to derive
        from its ``sweep`` (:func:`~jaxcart.rundir.reader.sweep_combinations`)."""
        path = (directory or self.path) / layout.CONFIG_FILE
        data = {k: v for k, v in info.items() if k != layout.DIGEST_KEY}
        if data.get("sweep"):  # the reader derives them: a million would be 70 MB of JSON
            data.pop("combinations", None)
        data["config"] = config.to_dict()
        files.write_json(path, {**data, layout.DIGEST_KEY: files.json_digest(data)})

    @property
    def checkpoint_path(self) -> Path:
        return self.path / layout.CHECKPOINT_FILE

    def save_checkpoint(self, state: TrainState, meta: dict) -> None:
        """Writes a (gathered) training state and its ``meta`` over the last checkpoint,
        once the metrics stream holds (durably) as many rows as the state has iterations."""
        self.stream.sync(state.iteration)
        checkpoint.save_checkpoint(self.checkpoint_path, state, meta)
        self.checkpoint_meta = {**meta, "iteration": state.iteration}

    def open_metrics(self, runs: int, rows: int) -> None:
        """:attr:`stream` for the wave about to train (``runs`` runs) cut to ``rows`` rows
        (the checkpoint's iterations; 0: a new wave). Only the main process keeps one."""
        self.stream.close()
        if self.main_process:
            path = self.path / layout.METRICS_STREAM_FILE
            self.stream = MetricsStream(path, METRIC_COLUMNS, runs, rows)

    def load_checkpoint(self, template: TrainState, num_runs: int) -> TrainState:
        """The checkpoint's state of ``num_runs`` runs, in the structure of ``template``."""
        return load_checkpoint(self.checkpoint_path, template, num_runs=num_runs)

    def finished(self) -> bool:
        """Whether the run wrote its last output: its evaluation, or a sweep's ranking."""
        return any(
            files.refuse_link(self.path / name) is not None
            for name in (layout.EVALUATION_FILE, layout.SWEEP_FILE)
        )

    def mark_unfinished(self) -> None:
        """Removes a finished run's top-level outputs before it is trained further, so that
        until the extension finishes every reader says the run is unfinished (and reads its
        checkpoint) instead of presenting the old outputs as the run's."""
        for name in (layout.SWEEP_FILE, layout.EVALUATION_FILE, layout.PARAMS_FILE):
            (self.path / name).unlink(missing_ok=True)
        files.fsync_directory(self.path)

    def wave_file(self, wave: int) -> Path:
        return files.subdir(self.path, layout.WAVES_DIR) / layout.wave_file(".", wave).name

    def has_wave(self, wave: int) -> bool:
        """Whether wave ``wave`` finished (its block file is saved; a link is refused)."""
        return files.refuse_link(self.wave_file(wave)) is not None

    def save_wave(self, block: outputs.Block, wave: int) -> Path:
        """Keeps a finished wave's block until the outputs are written; returns its file."""
        files.subdir(self.path, layout.WAVES_DIR, create=True)
        path = self.wave_file(wave)
        block.save(path)
        return path

    def finished_wave(self, wave: int, runs: range, episodes: int, config: PPOConfig) -> Path:
        """The file of a wave finished before an interruption, checked (headers, digest,
        finite values) before the outputs are built from it."""
        path = self.wave_file(wave)
        reader.check_block(path, config, runs, episodes, float_dtype())  # as resume checked
        return path

    def write_metrics(self, batch_size: int) -> None:
        """``metrics.csv`` of a stopped run, from its stream's rows so far."""
        outputs.write_metrics_csv(self.path / layout.METRICS_FILE, self.stream.read(), batch_size)

    def write_outputs(
        self,
        combo: int | None,
        blocks: list,
        runs: range,
        episodes: int,
        timing: dict,
        batch_size: int,
        record: tuple[dict, PPOConfig] | None = None,
    ) -> None:
        """metrics.csv, params.npz and evaluation.json of ``runs`` from the blocks: in the run
        directory, or in combination ``combo``'s, with its own config.json ``record``."""
        directory = self.path  # never recreated: a deleted run directory fails the write
        if combo is not None:
            directory = files.subdir(self.path, layout.combo_dir(".", combo).name, create=True)
        if record is not None:
            self.write_config(*record, directory=directory)
        outputs.write_blocks_metrics_csv(directory / layout.METRICS_FILE, blocks, runs, batch_size)
        outputs.write_params(directory / layout.PARAMS_FILE, blocks, runs)
        path = directory / layout.EVALUATION_FILE
        outputs.write_evaluation(path, blocks, runs, episodes, timing)

    def write_ranking(self, data: dict) -> None:
        """``sweep.json``: a sweep's combinations, ranked."""
        files.write_json(self.path / layout.SWEEP_FILE, data)
