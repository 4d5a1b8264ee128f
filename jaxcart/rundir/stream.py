"""The metrics of the wave being trained, appended to disk chunk by chunk.

``RUN_DIR/metrics.stream`` holds float32 rows, one per iteration, no header: each row is
every column of :data:`~jaxcart.engine.loop.METRIC_COLUMNS` for every run of the wave,
``[iteration, column, run]`` in C order. What the rows mean (their columns and runs) is
recorded in the checkpoint's metadata, and only as many rows as the checkpoint's iteration
count: rows written after the last checkpoint are cut when training continues, so a resumed
run's metrics are the uninterrupted run's, bit for bit. Rows are fsynced before every
checkpoint that counts them.

Training therefore holds one chunk of metrics in memory whatever the run's length, and a
checkpoint's size does not grow with it. At the end of a wave the rows are read back
memory-mapped (a finished wave's block file copies them; one wave's outputs are written
from them). The checkpoint and this file are each other's companions: a finished one-wave
run keeps both, so that ``--resume RUN --total-timesteps N`` can extend it.

This is the one file jaxcart appends to; :mod:`jaxcart.rundir.files` writes every other.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxcart.rundir import files
from jaxcart.rundir.files import RunDirError

DTYPE = np.dtype("<f4")


STREAM_DIGEST_KEY = "metrics_stream_digest"
"""Of a checkpoint's metadata: ``sha256:<hex>`` of the stream's rows it counts."""


class MetricsStream:
    """The stream of one wave (``runs`` runs, ``columns``), opened with ``rows`` rows kept:
    longer files are cut to them (rows past the checkpoint), shorter ones are refused, and
    with ``digest`` (the checkpoint's record of them) rows whose bytes differ are refused."""

    def __init__(
        self,
        path: files.Target,
        columns: Sequence[str],
        runs: int,
        rows: int,
        digest: str | None = None,
    ) -> None:
        self.path, self.columns, self.runs = path, tuple(columns), int(runs)
        self.row_bytes = len(self.columns) * self.runs * DTYPE.itemsize
        # appended where it lies (0o666 less the umask): a hard link elsewhere is refused
        flags = os.O_RDWR | os.O_CREAT
        self.fd = self._call(files.open_regular, self.path, flags, 0o666, True)
        try:
            self.hash = _check_rows(self.fd, self.path, rows, self.row_bytes, digest)
            self._call(os.ftruncate, self.fd, rows * self.row_bytes)
            os.lseek(self.fd, 0, os.SEEK_END)
        except BaseException:
            os.close(self.fd)
            raise
        self.rows = rows

    def _call(self, fn, *args):
        """``fn(*args)``, an OSError (a full or read-only disk) naming the stream's file."""
        try:
            return fn(*args)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), str(self.path)) from None

    def append(self, metrics: dict[str, np.ndarray]) -> None:
        """Appends one chunk: leaves ``[iterations_in_chunk, runs]`` for every column."""
        rows = np.stack([np.asarray(metrics[c], DTYPE) for c in self.columns], axis=1)
        if rows.shape[1:] != (len(self.columns), self.runs):
            raise ValueError(f"metrics of shape {rows.shape[1:]}, expected {self.runs} runs")
        view = memoryview(np.ascontiguousarray(rows)).cast("B")
        self.hash.update(view)
        while view:
            view = view[self._call(os.write, self.fd, view) :]
        self.rows += len(rows)

    def sync(self, rows: int) -> str:
        """Makes the rows durable before a checkpoint of ``rows`` iterations counts them;
        returns their digest, for the checkpoint to record."""
        if rows != self.rows:
            raise RuntimeError(f"{self.path} holds {self.rows} iterations, the checkpoint {rows}")
        self._call(os.fsync, self.fd)
        return "sha256:" + self.hash.hexdigest()

    def read(self) -> dict[str, np.ndarray]:
        """Every row so far, memory-mapped from the open file (what this process wrote, even
        if the path was removed meanwhile): column -> ``[rows, runs]``."""
        with os.fdopen(os.dup(self.fd), "rb") as f:
            return _mapped(f, self.rows, self.columns, self.runs)

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


class NoStream:
    """The stream of a process that writes none (not the main one, or no wave open yet)."""

    def append(self, metrics: dict[str, np.ndarray]) -> None:
        pass

    def sync(self, rows: int) -> None:
        pass

    def read(self) -> dict[str, np.ndarray]:
        return {}

    def close(self) -> None:
        pass


def _check_rows(fd: int, path: files.Target, rows: int, row_bytes: int, digest: str | None) -> Any:
    """The sha256 of the first ``rows`` rows of the stream ``fd`` (kept open for the rows
    appended next), refusing a shorter file or (``digest``: the checkpoint's record) other
    bytes."""
    size = rows * row_bytes
    if os.fstat(fd).st_size < size:
        raise RunDirError(
            f"{path} holds {os.fstat(fd).st_size // row_bytes} iterations of metrics, fewer "
            f"than the {rows} iterations its checkpoint counts; refusing it"
        )
    h = files.hash_fd(fd, size)
    if digest is not None and "sha256:" + h.hexdigest() != digest:
        raise RunDirError(
            f"{path} is not the file the run wrote: its rows differ from the digest its "
            "checkpoint records"
        )
    return h


def read_stream(
    path: files.Target,
    columns: Sequence[str],
    runs: int,
    rows: int,
    digest: str | None = None,
) -> dict[str, np.ndarray]:
    """The first ``rows`` rows of a metrics stream, memory-mapped read-only: column ->
    ``[rows, runs]`` float32 (a view; nothing is read until it is used). With ``digest``
    (the checkpoint's record), rows whose bytes differ are refused.

    Raises:
        RunDirError: missing, a link, not a regular file, shorter than ``rows`` rows, or
            not the rows the checkpoint recorded.
    """
    if rows == 0:
        return _mapped(None, 0, columns, runs)
    with files.open_tree(path) as f:
        _check_rows(f.fileno(), path, rows, len(columns) * runs * DTYPE.itemsize, digest)
        return _mapped(f, rows, columns, runs)


def _mapped(f, rows: int, columns: Sequence[str], runs: int) -> dict[str, np.ndarray]:
    """The first ``rows`` rows of the open stream ``f``, memory-mapped (zeros when there are
    none: an empty file cannot be mapped), as column -> ``[rows, runs]`` views."""
    shape = (rows, len(columns), runs)
    block = np.memmap(f, DTYPE, mode="r", shape=shape) if rows else np.zeros(shape, DTYPE)
    return {name: block[:, c, :] for c, name in enumerate(columns)}
