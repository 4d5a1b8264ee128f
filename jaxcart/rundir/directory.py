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
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.engine.loop import METRIC_COLUMNS, TrainState
from jaxcart.rundir import checkpoint, files, layout, outputs, reader
from jaxcart.rundir.checkpoint import load_checkpoint, read_checkpoint_meta
from jaxcart.rundir.files import Manifest, RunDirError, RunLock
from jaxcart.rundir.stream import STREAM_DIGEST_KEY, MetricsStream, NoStream

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
    """Left by a start that failed before writing its ``config.json``: a temporary, the lock
    or the manifest that was to list it."""
    return layout.is_temporary(path) or path.name in (layout.LOCK_FILE, layout.MANIFEST_FILE)


def prepare_out_dir(out: Path) -> files.Dir:
    """Creates ``out`` and opens it (never through a link); refuses a non-empty or
    unwritable one with a clear message. A directory holding only what a failed start
    leaves (its ``.lock``, temporaries) is taken over (:meth:`RunDir.create` then takes its
    lock, so a live start is never taken over)."""
    if str(out) == "":
        raise ConfigError("--out is empty; name a directory for the run")
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a directory; choose another path")
    if out.is_dir() and any(not _leftover(p) for p in out.iterdir()):
        raise ConfigError(
            f"--out {out} is not empty; choose a new directory so no earlier run is "
            f"overwritten (or continue it: --resume {out} on the command line, "
            f"jaxcart.resume_run({str(out)!r}) from Python)"
        )
    try:
        out.mkdir(parents=True, exist_ok=True)
        directory = files.Dir.open(out)
    except OSError as exc:
        raise ConfigError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    try:  # the probe is written through the directory's descriptor: never through a link
        files.atomic_write_bytes(directory / layout.WRITE_PROBE, b"")
        directory.unlink(layout.WRITE_PROBE)
    except OSError as exc:
        directory.close()
        raise ConfigError(f"cannot write to --out {out}: {exc.strerror or exc}") from None
    return directory


STARTING_FILES = (
    layout.CONFIG_FILE,
    layout.MANIFEST_FILE,
    layout.CHECKPOINT_FILE,
    layout.METRICS_STREAM_FILE,
    layout.METRICS_FILE,
)
"""What a run directory holds before its first iteration has trained (besides its lock)."""


class RunDir:
    """One run directory, locked by the main process from :meth:`create`/:meth:`open` to
    :meth:`close`. Only the main process writes; the others hold no lock.

    The main process opens the directory once (:class:`~jaxcart.rundir.files.Dir`) and
    opens, creates, renames and removes every file through that descriptor: renaming the
    directory or a component of its path while the run writes changes nothing it writes.
    """

    def __init__(self, path: str | os.PathLike, main_process: bool = True) -> None:
        self.path, self.main_process = Path(path), main_process
        self.dir: files.Dir | None = None
        self.lock = RunLock(self.path)
        self.manifest = Manifest(None, kept=False)
        self.checkpoint_meta: dict | None = None  # of the checkpoint on disk, when there is one
        self.created = False  # by this process's create(): discard() may remove it
        self.stream: MetricsStream | NoStream = NoStream()  # the metrics of the wave training
        self._waves: files.Dir | None = None

    def _take(self, directory: files.Dir, verified: bool) -> None:
        """Locks the opened ``directory`` (closed when that fails) and keeps it."""
        try:
            self.lock = RunLock(directory).acquire()
        except BaseException:
            directory.close()
            raise
        self.dir = directory
        # a run from before manifests keeps none: it stays a run that cannot be verified
        self.manifest = Manifest(directory, kept=verified)

    @classmethod
    def create(
        cls, path: str | os.PathLike, info: dict, config: PPOConfig, main_process: bool = True
    ) -> RunDir:
        """A new run directory (refusing a non-empty one), locked, with its ``config.json``
        (``info`` and ``config``)."""
        directory = cls(path, main_process)
        if main_process:
            directory.created = not directory.path.exists()
            directory._take(prepare_out_dir(directory.path), verified=True)
            try:
                directory.write_config(info, config)
            except BaseException:
                directory.discard()  # while holding the lock; the directory too if created here
                raise
        return directory

    @classmethod
    def open(cls, path: str | os.PathLike, main_process: bool = True) -> RunDir:
        """An existing run directory, locked before its checkpoint is read (another process
        may be writing it); :class:`RunInUse` when another process holds it."""
        directory = cls(path, main_process)
        if main_process:
            opened = files.Dir.open(directory.path)
            directory._take(opened, files.present(opened / layout.MANIFEST_FILE))
        return directory

    def _present(self, name: str, directory: files.Dir | None = None) -> bool:
        """Whether ``name`` exists (a link is refused, never followed)."""
        directory = directory or self.dir
        return directory is not None and files.refuse_link(directory / name) is not None

    def _verified(self, name: str) -> files.Entry:
        """``name`` checked against the manifest (a run from before manifests: unchecked)."""
        self.manifest.verify(name)
        return self.dir / name

    def read_checkpoint_meta(self) -> dict | None:
        """:attr:`checkpoint_meta` read from the checkpoint on disk; None when there is none
        (stopped while starting up: nothing was trained)."""
        if not self._present(layout.CHECKPOINT_FILE):
            self.checkpoint_meta = None
        else:
            self.checkpoint_meta = read_checkpoint_meta(self._verified(layout.CHECKPOINT_FILE))
        return self.checkpoint_meta

    def discard(self) -> None:
        """Removes what a start wrote before its first iteration trained (the files jaxcart
        writes at a start, never anything else), releases the directory, and removes it too
        when this start created it: a run that failed then (an XLA error while compiling, a
        full disk) leaves nothing behind, and the same command starts it afresh."""
        if self.dir is None:
            return
        self.stream.close()
        for name in STARTING_FILES:
            with contextlib.suppress(OSError, RunDirError):
                if self._present(name):
                    self.dir.unlink(name)
        with contextlib.suppress(OSError):
            self.dir.unlink(layout.LOCK_FILE)  # while holding it: no one else took it
        empty = False
        with contextlib.suppress(OSError):
            empty = not os.listdir(self.dir.fd)
        self.close()
        if empty and self.created:
            with contextlib.suppress(OSError):
                self.path.rmdir()

    def close(self) -> None:
        """Releases the run directory for other processes."""
        self.stream.close()
        self.lock.release()
        for opened in (self._waves, self.dir):
            if opened is not None:
                opened.close()

    def write_config(self, info: dict, config: PPOConfig, manifest: Manifest | None = None) -> None:
        """``config.json``: ``info`` with ``config`` as a dict (in a combination's
        directory, through its ``manifest``, when given); a sweep's combinations are left to the reader to derive
        from its ``sweep`` (:func:`~jaxcart.rundir.reader.sweep_combinations`)."""
        data = {k: v for k, v in info.items() if k != layout.DIGEST_KEY}
        if data.get("sweep"):  # the reader derives them: a million would be 70 MB of JSON
            data.pop("combinations", None)
        data["config"] = config.to_dict()
        manifest = manifest or self.manifest
        if manifest.kept:
            data[files.MANIFEST_FLAG] = True
        manifest.write_json(
            layout.CONFIG_FILE, {**data, layout.DIGEST_KEY: files.json_digest(data)}
        )

    @property
    def checkpoint_path(self) -> Path:
        return self.path / layout.CHECKPOINT_FILE

    def save_checkpoint(self, state: TrainState, meta: dict) -> None:
        """Writes a (gathered) training state and its ``meta`` over the last checkpoint,
        once the metrics stream holds (durably) as many rows as the state has iterations;
        the checkpoint records the stream's digest, the manifest the checkpoint's."""
        digest = self.stream.sync(state.iteration)
        if digest is not None:
            meta = {**meta, STREAM_DIGEST_KEY: digest}
        self.manifest.write(
            layout.CHECKPOINT_FILE,
            lambda entry, d: checkpoint.save_checkpoint(entry, state, meta, d),
        )
        self.checkpoint_meta = {**meta, "iteration": state.iteration}

    def open_metrics(self, runs: int, rows: int, columns: tuple[str, ...] = METRIC_COLUMNS) -> None:
        """:attr:`stream` of ``columns`` (the run's :func:`~jaxcart.engine.loop.metric_columns`)
        for the wave about to train (``runs`` runs) cut to ``rows`` rows
        (the checkpoint's iterations; 0: a new wave), which must match the digest the
        checkpoint recorded. Only the main process keeps one."""
        self.stream.close()
        if self.main_process:
            expected = (self.checkpoint_meta or {}).get(STREAM_DIGEST_KEY) if rows else None
            entry = self.dir / layout.METRICS_STREAM_FILE
            self.stream = MetricsStream(entry, columns, runs, rows, expected)

    def load_checkpoint(self, template: TrainState, num_runs: int) -> TrainState:
        """The checkpoint's state of ``num_runs`` runs, in the structure of ``template``."""
        entry = self._verified(layout.CHECKPOINT_FILE)
        return load_checkpoint(entry, template, num_runs=num_runs)

    def finished(self) -> bool:
        """Whether the run wrote its last output: its evaluation, or a sweep's ranking."""
        return any(self._present(name) for name in (layout.EVALUATION_FILE, layout.SWEEP_FILE))

    def mark_unfinished(self) -> None:
        """Removes a finished run's top-level outputs before it is trained further, so that
        until the extension finishes every reader says the run is unfinished (and reads its
        checkpoint) instead of presenting the old outputs as the run's."""
        names = (
            layout.SWEEP_FILE,
            layout.EVALUATION_FILE,
            layout.PARAMS_FILE,
            layout.PARAMS_BEST_FILE,
        )
        for name in names:
            self.dir.unlink(name)
        self.manifest.forget(*names)
        self.dir.fsync()

    def _waves_dir(self, create: bool = False) -> files.Dir | None:
        if self._waves is None and (create or self._present(layout.WAVES_DIR)):
            self._waves = self.dir.sub(layout.WAVES_DIR, create=create)
        return self._waves

    def wave_file(self, wave: int) -> files.Entry:
        return self._waves_dir(create=True) / layout.wave_file(".", wave).name

    def has_wave(self, wave: int) -> bool:
        """Whether wave ``wave`` finished (its block file is saved; a link is refused)."""
        waves = self._waves_dir()
        return waves is not None and self._present(layout.wave_file(".", wave).name, waves)

    def save_wave(self, block: outputs.Block, wave: int) -> files.Entry:
        """Keeps a finished wave's block until the outputs are written; returns its file
        (its own digest inside: many waves would make the manifest a long file rewritten
        after every one)."""
        entry = self.wave_file(wave)
        block.save(entry)
        return entry

    def finished_wave(
        self, wave: int, runs: range, episodes: int, config: PPOConfig
    ) -> files.Entry:
        """The file of a wave finished before an interruption, checked (headers, digest,
        finite values) before the outputs are built from it."""
        entry = self.wave_file(wave)
        reader.check_block(entry, config, runs, episodes, float_dtype())  # as resume checked
        return entry

    def write_metrics(self, batch_size: int) -> None:
        """``metrics.csv`` of a stopped run, from its stream's rows so far."""
        rows = self.stream.read()
        self.manifest.write(
            layout.METRICS_FILE,
            lambda entry, d: outputs.write_metrics_csv(entry, rows, batch_size, d),
        )

    def write_outputs(
        self,
        combo: int | None,
        blocks: list,
        runs: range,
        episodes: int,
        timing: dict,
        batch_size: int,
        record: tuple[dict, PPOConfig] | None = None,
        best: bool = False,
        env_id: str = DEFAULT_ENV,
    ) -> None:
        """metrics.csv, params.npz and evaluation.json of ``runs`` from the blocks: in the run
        directory, or in combination ``combo``'s, with its own config.json ``record``
        (``env_id``: the env whose notion of solved the evaluation records); with ``best``,
        params_best.npz too."""
        directory, manifest = self.dir, self.manifest  # never recreated once deleted
        if combo is not None:
            directory = self.dir.sub(layout.combo_dir(".", combo).name, create=True)
            manifest = Manifest(directory)
        try:
            if record is not None:
                self.write_config(*record, manifest=manifest)
            manifest.write(
                layout.METRICS_FILE,
                lambda e, d: outputs.write_blocks_metrics_csv(e, blocks, runs, batch_size, d),
            )
            manifest.write(
                layout.PARAMS_FILE, lambda e, d: outputs.write_params(e, blocks, runs, d)
            )
            if best:
                manifest.write(
                    layout.PARAMS_BEST_FILE,
                    lambda e, d: outputs.write_params(e, blocks, runs, d, best=True),
                )
            manifest.write(
                layout.EVALUATION_FILE,
                lambda e, d: outputs.write_evaluation(e, blocks, runs, episodes, timing, d, env_id),
            )
        finally:
            if directory is not self.dir:
                directory.close()

    def write_ranking(self, data: dict) -> None:
        """``sweep.json``: a sweep's combinations, ranked."""
        self.manifest.write_json(layout.SWEEP_FILE, data)
