"""A run directory as the run that owns it sees it: created or opened under its lock, then
written as training goes (``config.json``, checkpoints, finished waves, outputs).

:class:`RunDir` is the run's persistence and nothing else: what to train and when to save
is decided by :mod:`jaxcart.run.lifecycle`. Every file goes through
:func:`jaxcart.rundir.files.atomic_file` and is read back through :mod:`jaxcart.rundir.reader`.

A checkpoint is one tree file (:mod:`jaxcart.rundir.files`): every array of the
:class:`~jaxcart.engine.loop.TrainState` under its tree path
(``state/runners/params/params/actor/hidden_0/kernel``, ``state/hyperparams/learning_rate``,
...) and a JSON ``__meta__`` entry (iteration, elapsed time, chunk size, config, package
versions, and the columns of the metrics so far). The metrics themselves are not in it but in
its companion ``metrics.stream`` (:class:`~jaxcart.rundir.files.MetricsStream`), so its size
does not grow with the run's length. It is written beside the target, fsynced and renamed over
the previous checkpoint, so a crash or SIGKILL at any moment leaves the old or the new one,
never a torn one.

The outputs are written from blocks of consecutive runs. A :class:`Block` holds what training
and evaluation produced for runs ``[start, stop)``: parameters, metrics, divergences and
evaluation returns. A run trained in one go is one block in memory; a run trained in waves
keeps one block file per finished wave (``waves/wave-00003.npz``) and the outputs are
streamed from them, so that no step holds more than one wave in memory: ``metrics.csv``,
``params.npz`` and ``evaluation.json``, for the whole run or for one combination of a sweep.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import json
import os
import zipfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

import numpy as np

from jaxcart.core.config import ConfigError, PPOConfig, float_dtype
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.solved import solved_definition
from jaxcart.engine.loop import METRIC_COLUMNS, TrainState, metric_columns
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.files import Manifest, RunDirError, RunLock
from jaxcart.rundir.layout import BLOCK_BEST_PARAMS, BLOCK_METRICS, BLOCK_PARAMS

VERSIONED_PACKAGES = ("jaxcart", "jax", "jaxlib", "flax", "optax", "distrax", "gymnasium", "numpy")
"""The packages that determine a run's numbers, recorded in config.json and checkpoints."""
RESUME_PACKAGES = ("jaxcart", "jax", "jaxlib")
"""Those a run must be continued with to continue bit-identically."""
Digest = Callable[[str], None] | None
"""Called with a finished file's digest before it is renamed into place (its manifest)."""


@functools.cache
def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "not installed"


def package_versions() -> dict[str, str]:
    """Versions of the packages that determine a run's numbers (each looked up once per
    process: every checkpoint records them)."""
    return {name: _version(name) for name in VERSIONED_PACKAGES}


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


def prepare_out_dir(out: Path) -> files.Dir:
    """Creates ``out`` and opens it (never through a link); refuses a non-empty or
    unwritable one with a clear message. A directory holding only what a failed start
    leaves (its ``.lock``, temporaries, the manifest that was to list its ``config.json``) is
    taken over (:meth:`RunDir.create` then takes its lock, so a live start is never taken
    over)."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a directory; choose another path")
    leftover = lambda p: (
        layout.is_temporary(p) or p.name in (layout.LOCK_FILE, layout.MANIFEST_FILE)
    )
    if out.is_dir() and not all(leftover(p) for p in out.iterdir()):
        raise ConfigError(
            f"--out {out} is not empty; choose a new directory so no earlier run is "
            f"overwritten (or continue it: --resume {out} on the command line, "
            f"jaxcart.resume_run({str(out)!r}) from Python)"
        )
    directory = None
    try:
        out.mkdir(parents=True, exist_ok=True)
        directory = files.Dir.open(out)
        # the probe is written through the directory's descriptor: never through a link
        files.atomic_write_bytes(directory / layout.WRITE_PROBE, b"")
        directory.unlink(layout.WRITE_PROBE)
    except OSError as exc:
        if directory is not None:
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
        self.stream: files.MetricsStream | files.NoStream = files.NoStream()  # the wave's
        self._waves: files.Dir | None = None

    def _take(self, directory: files.Dir, verified: bool) -> None:
        """Locks the opened ``directory`` and keeps it (closed, and the lock released, when
        that or anything after it fails: a refused run is not left locked)."""
        self.dir = directory
        try:
            self.lock = RunLock(directory).acquire()
            # a run from before manifests keeps none: it stays a run that cannot be verified
            self.manifest = Manifest(directory, kept=verified)
            # only the lock's holder writes here: a temporary now is what a killed write left
            for opened in (directory, self._waves_dir(create=False)):  # waves/ a link: refused
                for name in opened.names() if opened is not None else ():
                    if layout.is_temporary(name):
                        opened.unlink(name)
        except BaseException:
            self.close()
            raise

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

    def _present(self, name: str) -> bool:
        """Whether ``name`` exists (a link is refused, never followed)."""
        return self.dir is not None and files.refuse_link(self.dir / name) is not None

    def read_checkpoint_meta(self) -> dict | None:
        """:attr:`checkpoint_meta` read from the checkpoint on disk (checked against the
        manifest); None when there is none (stopped while starting up: nothing was trained)."""
        self.checkpoint_meta = None
        if self._present(layout.CHECKPOINT_FILE):
            entry = self.manifest.verified(layout.CHECKPOINT_FILE)
            self.checkpoint_meta = reader.read_checkpoint_meta(entry)
        return self.checkpoint_meta

    def discard(self) -> None:
        """Removes what a start wrote before its first iteration trained (the files jaxcart
        writes at a start, never anything else), releases the directory, and removes it too
        when this start created it: a run that failed then (an XLA error while compiling, a
        full disk) leaves nothing behind, and the same command starts it afresh."""
        if self.dir is None:
            return
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

    def write_config(self, info: dict, config: PPOConfig) -> None:
        """``config.json``: ``info`` with ``config`` (:func:`~jaxcart.rundir.files.write_config`)."""
        files.write_config(self.manifest, {**info, "config": config.to_dict()})

    def save_checkpoint(self, state: TrainState, meta: dict) -> None:
        """Writes a (gathered) training state and its ``meta`` over the last checkpoint,
        once the metrics stream holds (durably) as many rows as the state has iterations;
        the checkpoint records the stream's digest, the manifest the checkpoint's."""
        digest = self.stream.sync(state.iteration)
        if digest is not None:
            meta = {**meta, files.STREAM_DIGEST_KEY: digest}
        self.manifest.write(layout.CHECKPOINT_FILE, save_checkpoint, state, meta)
        self.checkpoint_meta = {**meta, "iteration": state.iteration}

    def open_metrics(self, runs: int, rows: int, columns: tuple[str, ...] = METRIC_COLUMNS) -> None:
        """:attr:`stream` of ``columns`` (the run's :func:`~jaxcart.engine.loop.metric_columns`)
        for the wave about to train (``runs`` runs) cut to ``rows`` rows
        (the checkpoint's iterations; 0: a new wave), which must match the digest the
        checkpoint recorded. Only the main process keeps one."""
        self.stream.close()
        if self.main_process:
            meta = self.checkpoint_meta or {}
            expected = meta.get(files.STREAM_DIGEST_KEY) if rows else None
            entry = self.dir / layout.METRICS_STREAM_FILE
            self.stream = files.MetricsStream(entry, columns, runs, rows, expected)

    def load_checkpoint(self, template: TrainState, num_runs: int) -> TrainState:
        """The checkpoint's state of ``num_runs`` runs, in the structure of ``template``."""
        entry = self.manifest.verified(layout.CHECKPOINT_FILE)
        return reader.load_checkpoint(entry, template, num_runs=num_runs)

    def finished(self) -> bool:
        """Whether the run wrote its last output: its evaluation, or a sweep's ranking."""
        return any(self._present(name) for name in (layout.EVALUATION_FILE, layout.SWEEP_FILE))

    def mark_unfinished(self) -> None:
        """Removes a finished run's top-level outputs before it is trained further, so that
        until the extension finishes every reader says the run is unfinished (and reads its
        checkpoint) instead of presenting the old outputs as the run's."""
        names = (layout.SWEEP_FILE, layout.EVALUATION_FILE, *layout.POLICY_FILES.values())
        for name in names:
            self.dir.unlink(name)
        self.manifest.forget(*names)
        self.dir.fsync()

    def _waves_dir(self, create: bool) -> files.Dir | None:
        """``waves/``, opened once (created with ``create``; None when it does not exist
        and is not to be)."""
        if self._waves is None and (create or self._present(layout.WAVES_DIR)):
            self._waves = self.dir.sub(layout.WAVES_DIR, create=create)
        return self._waves

    def _wave_file(self, wave: int, create: bool = True) -> files.Entry | None:
        """Wave ``wave``'s block file in ``waves/`` (created with ``create``; None when it
        does not exist and is not to be)."""
        waves = self._waves_dir(create)
        return waves and waves / layout.wave_file(".", wave).name

    def has_wave(self, wave: int) -> bool:
        """Whether wave ``wave`` finished (its block file is saved; a link is refused)."""
        entry = self._wave_file(wave, create=False)
        return entry is not None and files.refuse_link(entry) is not None

    def save_wave(self, block: Block, wave: int) -> files.Entry:
        """Keeps a finished wave's block until the outputs are written; returns its file
        (its own digest inside: many waves would make the manifest a long file rewritten
        after every one)."""
        entry = self._wave_file(wave)
        block.save(entry)
        return entry

    def finished_wave(
        self, wave: int, runs: range, episodes: int, config: PPOConfig
    ) -> files.Entry:
        """The file of a wave finished before an interruption, checked (headers, digest,
        finite values) before the outputs are built from it."""
        entry = self._wave_file(wave)
        reader.check_block(entry, config, runs, episodes, float_dtype())  # as resume checked
        return entry

    def write_metrics(self, batch_size: int) -> None:
        """``metrics.csv`` of a stopped run, from its stream's rows so far."""
        self.manifest.write(layout.METRICS_FILE, write_metrics_csv, self.stream.read(), batch_size)

    def write_outputs(
        self,
        blocks: list,
        runs: range,
        config: PPOConfig,
        episodes: int,
        timing: dict,
        combo: tuple[int, dict] | None = None,
    ) -> None:
        """metrics.csv, params.npz (and params_best.npz when ``config`` keeps the best
        policies) and evaluation.json (solved as ``config.env`` defines it) of ``runs`` from
        the blocks: in the run directory, or with ``combo`` (its index and ``info``) in that
        combination's directory, beside its own config.json of ``info`` and ``config``."""
        directory, manifest = self.dir, self.manifest  # never recreated once deleted
        if combo is not None:
            directory = self.dir.sub(layout.combo_dir(".", combo[0]).name, create=True)
            manifest = Manifest(directory)
        parts = (
            (b.metrics, b.start + t.start - runs.start, t) for b, t in overlapping(blocks, runs)
        )
        try:
            if combo is not None:
                files.write_config(manifest, {**combo[1], "config": config.to_dict()})
            manifest.write(layout.METRICS_FILE, write_metrics_csv, parts, config.batch_size)
            manifest.write(layout.PARAMS_FILE, write_params, blocks, runs)
            if config.keep_best:
                manifest.write(layout.PARAMS_BEST_FILE, write_params, blocks, runs, best=True)
            manifest.write(
                layout.EVALUATION_FILE, write_evaluation, blocks, runs, episodes, timing, config.env
            )
        finally:
            if directory is not self.dir:
                directory.close()

    def write_ranking(self, data: dict) -> None:
        """``sweep.json``: a sweep's combinations, ranked."""
        self.manifest.write_json(layout.SWEEP_FILE, data)


def save_checkpoint(
    path: files.Target, state: TrainState, meta: dict, on_digest: Digest = None
) -> None:
    """Writes ``state``'s arrays (:func:`~jaxcart.rundir.reader.state_arrays`) and ``meta``
    (JSON-able) to ``path``; the metrics so far are the stream's (made durable before this
    is called). :func:`jaxcart.rundir.reader.load_checkpoint` restores it."""
    meta = {
        **meta,
        "checkpoint_format": layout.CHECKPOINT_FORMAT,
        "iteration": state.iteration,
        "elapsed": state.elapsed,
        "chunk_size": state.chunk_size,
        "metrics_columns": list(metric_columns(state.config)),
    }
    files.save_tree(path, reader.state_arrays(state), meta, on_digest)  # the rename made durable


# ---- outputs, from blocks of runs ----


RUN_ARRAYS = ("diverged_at", "gym_returns", "jax_returns")
"""What a block holds of each run besides its parameters and metrics: the iteration it
diverged at (or -1) ``[n]``, its Gymnasium and JAX greedy returns ``[n, episodes]``."""
BEST_ARRAYS = ("best_gym_returns", "best_iteration", "best_score")
"""What a block of a run that keeps its best policies holds of them: their Gymnasium returns
``[n, episodes]``, the (1-based) iteration each was evaluated at and its eval/mean_return
``[n]``."""


@dataclass
class Block:
    """Results of runs ``[start, stop)``: arrays with a leading (or, for metrics, second)
    axis of ``stop - start`` runs."""

    start: int
    stop: int
    params: dict[str, np.ndarray]  # flattened names -> [n, ...]
    metrics: dict[str, np.ndarray]  # name -> [iterations, n]
    diverged_at: np.ndarray  # [n]
    gym_returns: np.ndarray  # [n, episodes]
    jax_returns: np.ndarray  # [n, episodes]
    timing: dict[str, float]
    best_params: dict[str, np.ndarray] | None = None  # keep_best's, flattened -> [n, ...]
    best: dict[str, np.ndarray] | None = None  # keep_best's BEST_ARRAYS

    def save(self, path: files.Target) -> None:
        arrays = {BLOCK_PARAMS + k: v for k, v in self.params.items()}
        arrays |= {BLOCK_BEST_PARAMS + k: v for k, v in (self.best_params or {}).items()}
        arrays |= self.best or {}
        arrays |= {BLOCK_METRICS + k: np.asarray(v) for k, v in self.metrics.items()}
        arrays |= {name: getattr(self, name) for name in RUN_ARRAYS}
        meta = {"start": self.start, "stop": self.stop, **self.timing}
        files.save_tree(path, arrays, {**meta, layout.DIGEST_KEY: files.arrays_digest(arrays)})

    @classmethod
    def load(cls, path: files.Target) -> Block:
        arrays, meta = files.load_tree(path)
        take = lambda prefix: {
            k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)
        }
        timing = {k: v for k, v in meta.items() if k not in ("start", "stop", layout.DIGEST_KEY)}
        best = {k: arrays[k] for k in BEST_ARRAYS if k in arrays} or None
        return cls(
            **{name: arrays[name] for name in RUN_ARRAYS},
            start=int(meta["start"]),
            stop=int(meta["stop"]),
            params=take(BLOCK_PARAMS),
            metrics=take(BLOCK_METRICS),
            timing=timing,
            best_params=take(BLOCK_BEST_PARAMS) or None,
            best=best,
        )


def _spans(blocks: list, runs: range) -> Iterator[tuple[Block | files.Target, slice]]:
    """Each block (or block file, whose span is read from its metadata alone) that holds some
    of ``runs``, with the slice of its axis that does."""
    for item in blocks:
        # a block in memory: its own fields; a file: its metadata, no array read
        meta = vars(item) if isinstance(item, Block) else files.read_meta(item)
        start, stop = int(meta["start"]), int(meta["stop"])
        lo, hi = max(start, runs.start), min(stop, runs.stop)
        if lo < hi:
            yield item, slice(lo - start, hi - start)


def overlapping(blocks: list, runs: range) -> Iterator[tuple[Block, slice]]:
    """Each block that holds some of ``runs`` (loaded when it is a path), with the slice of
    its axis that does."""
    for item, take in _spans(blocks, runs):
        yield (item if isinstance(item, Block) else Block.load(item)), take


def _param_slices(blocks: list, runs: range, name: str, best: bool = False) -> Iterator[np.ndarray]:
    """One parameter array of each block that holds some of ``runs``, sliced to them (the
    best policies' with ``best``); a block file is read for that array alone."""
    for item, take in _spans(blocks, runs):
        if isinstance(item, Block):
            yield (item.best_params if best else item.params)[name][take]
        else:
            with files.open_tree(item) as raw, np.load(raw, allow_pickle=False) as data:
                yield data[(BLOCK_BEST_PARAMS if best else BLOCK_PARAMS) + name][take]


def write_metrics_csv(
    path: files.Target,
    metrics: dict[str, np.ndarray] | Iterable[tuple[dict, int, slice]],
    batch_size: int,
    on_digest: Digest = None,
) -> None:
    """``metrics.csv``: rows ``seed_index, iteration, env_steps, <metrics...>``, seed by seed,
    iteration by iteration, from leaves ``[iterations, S]`` (a run's metrics in memory: a
    stopped run's so far, or another library's log) or, streamed part by part, from
    ``(metrics [iterations, R], first seed index, runs)`` parts (blocks of a run's waves)."""
    parts = [(metrics, 0, slice(None))] if isinstance(metrics, dict) else metrics
    with files.atomic_file(path, "w", on_digest) as f:
        writer, header = csv.writer(f, lineterminator="\n"), None
        for part, first, take in parts:
            if header is None:
                header = [*layout.METRICS_INDEX_COLUMNS, *part]
                writer.writerow(header)
            columns = [np.asarray(part[n])[:, take] for n in part]
            iterations, num_seeds = columns[0].shape
            for s in range(num_seeds):
                for i in range(iterations):
                    row = [float(c[i, s]) for c in columns]
                    writer.writerow([first + s, i + 1, (i + 1) * batch_size, *row])


def write_params(
    path: files.Target, blocks: list, runs: range, on_digest: Digest = None, best: bool = False
) -> None:
    """``params.npz`` for ``runs`` (``params_best.npz`` of the best policies with ``best``):
    each array's header for the whole run, then its blocks' bytes in order (a leading-axis
    concatenation), streamed into place."""
    first, _ = next(overlapping(blocks, runs))
    with (
        files.atomic_file(path, "wb", on_digest) as out,
        zipfile.ZipFile(out, "w", allowZip64=True) as zf,
    ):
        for name, a in first.params.items():
            shape = (len(runs), *a.shape[1:])
            with zf.open(name + ".npy", "w", force_zip64=True) as f:
                header = {
                    "descr": np.lib.format.dtype_to_descr(a.dtype),
                    "fortran_order": False,
                    "shape": shape,
                }
                np.lib.format.write_array_header_1_0(f, header)
                for part in _param_slices(blocks, runs, name, best):
                    f.write(np.ascontiguousarray(part).tobytes())


def write_evaluation(
    path: files.Target,
    blocks: list,
    runs: range,
    episodes: int,
    extra: dict,
    env_id: str = DEFAULT_ENV,
    on_digest: Digest = None,
) -> None:
    """``evaluation.json`` for ``runs``: per-seed returns and solved flags (solved as
    ``env_id`` defines it), streamed."""
    counts = {"solved_seeds": 0}  # and best_solved_seeds, when the runs kept their best
    with files.atomic_file(path, "w", on_digest) as f:
        definition = json.dumps(solved_definition(env_id).format(episodes=episodes))
        head = f'{{\n  "episodes": {episodes},\n  "solved_definition": {definition},\n'
        f.write(head + '  "seeds": [')
        sep = "\n"
        for block, take in overlapping(blocks, runs):
            final = block.metrics["rollout/ep_rew_mean"][-1, take]
            g, j, d = block.gym_returns[take], block.jax_returns[take], block.diverged_at[take]
            first = block.start + take.start - runs.start
            for s in range(len(g)):
                seed = {
                    "seed_index": first + s,
                    **reader.gymnasium_entry(g[s], env_id),
                    "jaxcart_returns": j[s].tolist(),
                    "jaxcart_mean": float(j[s].mean()),
                    "final_ep_rew_mean": float(final[s]),
                    "diverged_at_iteration": int(d[s]) if d[s] >= 0 else None,
                }
                counts["solved_seeds"] += int(seed["solved"])
                if block.best is not None:  # the seed's best policy: its verdict and where
                    iteration = int(block.best["best_iteration"][take][s])
                    seed["best"] = {
                        "iteration": iteration if iteration > 0 else None,
                        "eval_mean_return": (
                            float(block.best["best_score"][take][s]) if iteration > 0 else None
                        ),
                        **reader.gymnasium_entry(block.best["best_gym_returns"][take][s], env_id),
                    }
                    best = counts.get("best_solved_seeds", 0) + int(seed["best"]["solved"])
                    counts["best_solved_seeds"] = best
                f.write(sep + "    " + json.dumps(seed))
                sep = ",\n"
        f.write("\n  ],\n" + json.dumps({**counts, **extra}, indent=2)[2:] + "\n")


def evaluation_record(returns: np.ndarray, env_id: str = DEFAULT_ENV) -> dict:
    """``evaluation.json`` of greedy Gymnasium returns ``[num_seeds, episodes]``: per seed
    its returns, their mean and least, and whether they solve ``env_id``."""
    returns = np.asarray(returns)
    seeds = [{"seed_index": s, **reader.gymnasium_entry(g, env_id)} for s, g in enumerate(returns)]
    return {
        "episodes": returns.shape[1],
        "solved_definition": solved_definition(env_id).format(episodes=returns.shape[1]),
        "seeds": seeds,
        "solved_seeds": sum(seed["solved"] for seed in seeds),
    }


def write_evaluation_dir(
    directory: files.Dir,
    info: dict,
    returns: np.ndarray | None = None,
    others: dict[str, dict] | None = None,
) -> None:
    """An evaluation written in one go (``python -m jaxcart.evaluate --out``, laid out as
    :mod:`jaxcart.rundir.layout` says): ``config.json`` (``info``), ``evaluation.json`` of
    ``returns`` ``[num_seeds, episodes]`` (a sweep's own directory has none: its
    ``combo-NNN/`` do) and ``others`` (name -> JSON object: a sweep's ``sweep.json``), each
    recorded in the directory's manifest as a run's files are, so that the readers check it
    as they check a run."""
    listing = Manifest(directory)
    files.write_config(listing, info)
    if returns is not None:
        env_id = info["config"].get("env", DEFAULT_ENV)
        listing.write_json(layout.EVALUATION_FILE, evaluation_record(returns, env_id))
    for name, data in (others or {}).items():
        listing.write_json(name, data)
