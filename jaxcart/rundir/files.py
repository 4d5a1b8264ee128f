"""The store: the one module that opens a file of a run directory, for reading or writing.

Every byte of a run directory goes through here, and each guarantee is given once, here, for
every reader and writer. Reading: :func:`open_regular` (no link followed, a regular file
only), :func:`read_bytes` (bounded by what such a file can hold), :func:`verified` and
:func:`read_json` (a file's digest is the one ``manifest.json`` records) and the tree files'
:func:`load_tree` (headers checked before anything large is read). Writing:
:func:`atomic_file` (a temporary beside the target, fsynced and renamed into place, so a crash
never leaves a torn file) and :class:`Manifest` (each finished file's ``sha256`` recorded).
The lock (:class:`RunLock`) and the metrics stream (:class:`MetricsStream`, the one file
appended to) are here too. Nothing read is ever imported or unpickled.

A tree file (parameters, checkpoints) is an uncompressed ``.npz``: every array leaf under its
tree path joined with ``/`` (``params/actor/hidden_0/kernel``, ``runners/opt_state/1/mu/...``)
and optionally a JSON metadata entry ``__meta__``.

The manifest: a run records each file's ``sha256:<hex>`` before the file is renamed into
place (the manifest then lists the old and the new digest, so a crash between the two renames
leaves a file the manifest accepts) and keeps only the new one once it is. Every reader checks
a file against it before trusting anything in it (:func:`verified`). The checkpoint counts too;
the metrics stream, appended chunk by chunk, is covered by the digest its checkpoint records,
and a finished wave's file by the digest it carries. A digest proves integrity, not
authorship. A directory whose ``config.json`` has no ``manifest`` flag was written before
manifests: it is read with a one-line :class:`UnverifiedRunWarning`; one whose
``config.json`` says it has a manifest and has none is refused.

The lock: one process at a time per run directory, an advisory ``flock`` on ``RUN_DIR/.lock``
held for the whole run and released by the operating system when its holder exits, however it
exits. The file keeps the holder's PID, so a refused process can say who holds it.

The metrics stream: ``RUN_DIR/metrics.stream`` holds float32 rows, one per iteration, no
header: each row is every metric column for every run of the wave being trained,
``[iteration, column, run]`` in C order. What the rows mean (their columns and runs) is
recorded in the checkpoint's metadata, and only as many rows as the checkpoint's iteration
count: rows written after the last checkpoint are cut when training continues, so a resumed
run's metrics are the uninterrupted run's, bit for bit. Rows are fsynced before every
checkpoint that counts them, so training holds one chunk of metrics in memory whatever the
run's length, and a checkpoint's size does not grow with it.
"""

from __future__ import annotations

import contextlib
import errno
import fnmatch
import hashlib
import json
import math
import os
import secrets
import stat
import warnings
import zipfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from jaxcart.rundir import layout

META_KEY = "__meta__"
MANIFEST_FORMAT = 1
MANIFEST_MAX_BYTES = 1 << 20
MAX_JSON_BYTES = 16 << 20
MAX_META_BYTES = 1 << 20
MANIFEST_FLAG = "manifest"
"""Of ``config.json``: true in a run that keeps ``manifest.json``."""
STREAM_DTYPE = np.dtype("<f4")
STREAM_DIGEST_KEY = "metrics_stream_digest"
"""Of a checkpoint's metadata: ``sha256:<hex>`` of the stream's rows it counts."""


class RunDirError(ValueError):
    """A file or directory is not a usable jaxcart run (directory); the message says why."""


class RunInUse(RunDirError):
    """Another process holds the run directory's lock."""


class UnverifiedRunWarning(UserWarning):
    """A run directory from before manifests: its files cannot be checked against one."""


LINK_REASON = "a symbolic link; jaxcart never follows links in a run directory"
WRITE_FAILURES = (errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM)
"""Errors of a disk or mount that refuses writes: reported as failed writes (exit 1), not as a
bad run directory."""


class Dir:
    """A directory opened once (``O_DIRECTORY | O_NOFOLLOW``) that every file inside it is
    opened, created, renamed and removed through (``dir_fd``, ``O_NOFOLLOW``): renaming the
    directory, or swapping one of its path's components for a link, while a run writes
    cannot send a write anywhere else, and no link inside it is ever followed."""

    def __init__(self, path: str | os.PathLike, fd: int) -> None:
        self.path, self.fd = Path(path), fd

    @classmethod
    def open(cls, path: str | os.PathLike, parent: Dir | None = None) -> Dir:
        """``path`` (a name inside ``parent`` when given) as a directory, never through a
        link as its last component.

        Raises:
            RunDirError: a link or not a directory.
            FileNotFoundError: it does not exist.
        """
        shown = parent.path / path if parent is not None else Path(path)
        flags = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
        try:
            fd = os.open(path, flags, dir_fd=parent.fd if parent is not None else None)
        except OSError as exc:
            if exc.errno in (errno.ELOOP, errno.ENOTDIR):  # Linux says ENOTDIR for a link
                refuse_link(parent / os.fspath(path) if parent else shown)  # a link: says so
                raise RunDirError(f"{shown} is not a directory; refusing it") from None
            raise
        return cls(shown, fd)

    def sub(self, name: str, create: bool = False) -> Dir:
        """The directory ``name`` inside this one, created first when ``create`` (this one
        is never recreated: a deleted run directory fails the write)."""
        if create:
            with contextlib.suppress(FileExistsError):
                os.mkdir(name, dir_fd=self.fd)
        return Dir.open(name, parent=self)

    def __truediv__(self, name: str) -> Entry:
        return Entry(self, name)

    def __str__(self) -> str:
        return str(self.path)

    def names(self) -> list[str]:
        """The names inside this directory (``os.listdir`` of its descriptor)."""
        return os.listdir(self.fd)

    def unlink(self, name: str) -> None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(name, dir_fd=self.fd)

    def fsync(self) -> None:
        """Makes the renames inside this directory durable."""
        os.fsync(self.fd)

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


class Entry:
    """A name inside an open :class:`Dir`: what the writers and readers take in place of a
    path (``str()`` of it is the path, for messages)."""

    def __init__(self, directory: Dir, name: str) -> None:
        self.dir, self.name = directory, name

    def __fspath__(self) -> str:
        return str(self.dir.path / self.name)

    __str__ = __fspath__


Target = str | os.PathLike | Entry
"""Where a file is: a path, or a name inside an open :class:`Dir`."""
Where = str | os.PathLike | Dir
"""A run directory as the readers take it: a path, or the :class:`Dir` a caller opened."""


@contextlib.contextmanager
def opened(run_dir: Where) -> Iterator[Dir]:
    """``run_dir`` opened once (:meth:`Dir.open`) for the block, so that every file a reader
    reads in it is opened through that descriptor: renaming the directory, or swapping a
    component of its path, while it is read cannot mix files of two directories. A
    :class:`Dir` is used as it is (and left open).

    Raises:
        RunDirError: missing, a link, or not a directory.
    """
    if isinstance(run_dir, Dir):
        yield run_dir
        return
    try:
        directory = Dir.open(run_dir)
    except FileNotFoundError:
        raise RunDirError(
            f"{run_dir} is not a directory; pass the --out directory of a jaxcart run"
        ) from None
    except OSError as exc:
        raise RunDirError(f"{run_dir} cannot be read: {exc.strerror or exc}") from None
    try:
        yield directory
    finally:
        directory.close()


def _located(target: Target) -> tuple[str, int | None]:
    """The name to pass to ``os.open`` and the directory descriptor it is relative to."""
    if isinstance(target, Entry):
        return target.name, target.dir.fd
    return os.fspath(target), None


def _lstat(target: Target) -> os.stat_result | None:
    """``target``'s own status (a link is not followed), None when it does not exist (nor
    does its parent, or its parent is a file).

    Raises:
        RunDirError: it cannot be read.
    """
    name, dir_fd = _located(target)
    try:
        return os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:
        raise RunDirError(f"{target} cannot be read: {exc.strerror or exc}") from None


def present(target: Target) -> bool:
    """Whether ``target`` exists, by ``lstat``: a link counts as present whatever it points
    to, so that what a directory is never depends on a link's target (its reader then refuses
    the link by name)."""
    try:
        return _lstat(target) is not None
    except RunDirError:
        return True  # there, but not readable: its reader says why


def refuse_link(path: Target) -> os.stat_result | None:
    """``lstat(path)``, refusing a symbolic link (a run directory someone else made may hold
    anything: a link would make jaxcart read or write outside the directory). None when
    ``path`` does not exist.

    Raises:
        RunDirError: ``path`` is a symbolic link.
    """
    st = _lstat(path)
    if st is not None and stat.S_ISLNK(st.st_mode):
        raise RunDirError(f"{path} is {LINK_REASON}")
    return st


def subdir(directory: str | os.PathLike, name: str, create: bool = False) -> Path:
    """``directory / name`` checked to be a real directory (not a link) when it exists
    (:meth:`Dir.sub`); created (its parent must exist: a deleted run directory is never
    recreated) when ``create``.

    Raises:
        RunDirError: a link or something other than a directory.
        OSError: it could not be created.
    """
    with opened(directory) as parent:
        try:
            parent.sub(name, create).close()
        except FileNotFoundError:
            if create:
                raise
    return Path(directory) / name


# ---- reading: the one opener ----


def open_regular(
    path: Target, flags: int = os.O_RDONLY, mode: int = 0o666, in_place: bool = False
) -> int:
    """A descriptor of ``path`` opened without following a link, checked to be a regular
    file (never a FIFO, device or directory: ``O_NONBLOCK`` keeps a FIFO from blocking the
    open, and it is cleared once the file is known to be regular). ``in_place``: a file
    jaxcart changes where it lies (the lock, the metrics stream) must have one link, else
    truncating or appending to it would change a hard-linked file outside the run.

    Raises:
        RunDirError: ``path`` is missing (opened for reading), a link, not a regular file,
            or (``in_place``) hard-linked.
        OSError: the disk refuses an open for writing (:data:`WRITE_FAILURES`).
    """
    name, dir_fd = _located(path)
    writing = flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT)
    try:
        fd = os.open(
            name, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, mode, dir_fd=dir_fd
        )
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise RunDirError(f"{path} is {LINK_REASON}") from None
        if isinstance(exc, FileNotFoundError) and not writing:
            raise RunDirError(f"{path} does not exist") from None
        if isinstance(exc, FileNotFoundError) or (writing and exc.errno in WRITE_FAILURES):
            raise  # a disk that refuses writes: the caller's write failure
        raise RunDirError(f"{path} cannot be opened: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise RunDirError(f"{path} is not a regular file; refusing it")
        if in_place and st.st_nlink != 1:
            raise RunDirError(
                f"{path} has {st.st_nlink} hard links; jaxcart changes it in place and "
                "refuses a file that is also elsewhere (remove it and resume)"
            )
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def open_tree(path: Target) -> IO[bytes]:
    """``path`` opened for reading in binary through :func:`open_regular`."""
    return os.fdopen(open_regular(path), "rb")


def read_bytes(path: Target, max_bytes: int) -> bytes:
    """A regular file's bytes (no link followed), refusing one larger than ``max_bytes``.

    Raises:
        RunDirError: missing, a link, not a regular file, or too large.
    """
    with open_tree(path) as f:
        if (
            os.fstat(f.fileno()).st_size > max_bytes
            or len(data := f.read(max_bytes + 1)) > max_bytes
        ):
            raise RunDirError(f"{path} is larger than any such file jaxcart writes")
    return data


def hash_fd(fd: int, size: int | None = None) -> Any:
    """sha256 of the first ``size`` bytes (all, when None) of ``fd`` from its start (the
    offset is kept): the hash object, for a caller that appends more."""
    h, offset = hashlib.sha256(), 0
    while size is None or offset < size:
        chunk = os.pread(fd, 1 << 20 if size is None else min(1 << 20, size - offset), offset)
        if not chunk:
            break
        h.update(chunk)
        offset += len(chunk)
    return h


def fd_digest(fd: int) -> str:
    """``sha256:<hex>`` of an open file's bytes, read from its start (the offset is kept)."""
    return "sha256:" + hash_fd(fd).hexdigest()


def _check_listed(run_dir: Dir, name: str, digest: str, info: dict | None) -> None:
    """Refuses ``RUN_DIR/name`` unless ``digest`` (of its bytes) is one its manifest lists;
    ``info`` (the run's ``config.json``) says whether the run keeps a manifest: a run from
    before manifests gets an :class:`UnverifiedRunWarning` instead."""
    manifest = run_dir / layout.MANIFEST_FILE
    if info is not None and not info.get(MANIFEST_FLAG) and not present(manifest):
        warnings.warn(
            f"{run_dir} was written before jaxcart kept a manifest: its files cannot be "
            "verified, only checked for sense",
            UnverifiedRunWarning,
            stacklevel=4,
        )
        return
    if not present(manifest):
        raise RunDirError(f"{manifest} is missing: the run's files cannot be verified")
    _check_digest(run_dir / name, digest, read_manifest(run_dir).get(name))


def _check_digest(entry: Entry, digest: str, listed: list[str] | None) -> None:
    """Refuses the file ``entry`` unless its ``digest`` is one of ``listed``."""
    if digest not in (listed or []):
        raise RunDirError(
            f"{entry} is not the file the run wrote: its digest is not the one "
            f"{layout.MANIFEST_FILE} records"
        )


def verified(run_dir: Dir, name: str, info: dict | None, missing: str = "") -> Entry:
    """``RUN_DIR/name`` after refusing it unless it is a regular file (no link followed)
    whose bytes are those its manifest records; ``info`` (the run's ``config.json``) says
    whether the run keeps a manifest. A run from before manifests gets an
    :class:`UnverifiedRunWarning`. The check every reader of a large file makes.

    Raises:
        RunDirError: missing (``missing`` says why, when given), the manifest is missing or
            broken, or the file is not listed or differs.
    """
    entry = run_dir / name
    if missing and refuse_link(entry) is None:
        raise RunDirError(missing)
    with open_tree(entry) as f:
        _check_listed(run_dir, name, fd_digest(f.fileno()), info)
    return entry


def read_json(
    run_dir: Where,
    name: str,
    max_bytes: int = MAX_JSON_BYTES,
    verify: bool = False,
    info: dict | None = None,
) -> dict:
    """A JSON object from a run directory, refusing links, non-regular files, files over
    ``max_bytes`` and anything but an object. With ``verify``, the bytes read must be those
    the directory's manifest records (:func:`verified`; ``info``, the run's ``config.json``,
    says whether it keeps one: the object itself when None, for ``config.json``).

    Raises:
        RunDirError: missing, a link, not a regular file, too large, not a JSON object, or
            (``verify``) not the file the run wrote.
    """
    with opened(run_dir) as directory:
        path = directory / name
        text = read_bytes(path, max_bytes)
        try:
            data = json.loads(text.decode())
        except (ValueError, RecursionError) as exc:  # bad UTF-8 and 5,000-digit ints too
            raise RunDirError(
                f"{path} is corrupted or from an incompatible version: {exc}"
            ) from None
        if not isinstance(data, dict):
            raise RunDirError(f"{path} is corrupted: not a JSON object")
        if verify:
            digest = "sha256:" + hashlib.sha256(text).hexdigest()
            _check_listed(directory, name, digest, data if info is None else info)
    return data


def read_manifest(run_dir: Where) -> dict[str, list[str]]:
    """The digests ``RUN_DIR/manifest.json`` lists, file name -> accepted digests.

    Raises:
        RunDirError: missing, a link, or not a manifest.
    """
    data = read_json(run_dir, layout.MANIFEST_FILE, MANIFEST_MAX_BYTES)
    listed = data.get("files")
    if (
        not isinstance(listed, dict)
        or data.get("format") != MANIFEST_FORMAT
        or not all(
            isinstance(v, list) and all(isinstance(d, str) for d in v) for v in listed.values()
        )
    ):
        raise RunDirError(f"{run_dir}/{layout.MANIFEST_FILE} is corrupted: not a jaxcart manifest")
    return listed


CLASSIFYING_FILES = (layout.SWEEP_FILE, layout.PARAMS_FILE, layout.CHECKPOINT_FILE)
"""Whether these exist says whether a directory is a sweep, a finished or an unfinished run
(:func:`~jaxcart.rundir.reader.is_sweep`): :func:`read_config` refuses each as a link."""


def read_config(run_dir: Where, verify: bool = False) -> dict:
    """A run's ``config.json`` as written (:func:`write_config`): a JSON object, nothing in it
    interpreted, imported or called. The one reader of that file, for every reader of runs
    (:func:`jaxcart.rundir.reader.read_run_config` checks what it holds), for ``--resume``
    and for ``--config RUN_DIR``. Its bytes must be those the manifest records; with
    ``verify`` (a resume), its own digest must match its contents too (hand edits and
    corruption are refused: a run continues only with the settings it started with).

    Raises:
        RunDirError: not a run directory (with a hint for what a failed start or an
            interrupted ``python -m jaxcart.sb3`` run leaves), a link, unreadable, too large,
            not a JSON object, or edited.
    """
    with opened(run_dir) as directory:
        path = directory / layout.CONFIG_FILE
        if refuse_link(path) is None:
            raise RunDirError(_not_a_run(directory))
        for name in CLASSIFYING_FILES:  # what the directory is: never decided through a link
            refuse_link(directory / name)
        data = read_json(directory, layout.CONFIG_FILE, verify=True)
    if verify and layout.DIGEST_KEY not in data:
        raise RunDirError(
            f"{path} has no digest: it was not written by this version of jaxcart, or was "
            "rewritten by hand; a run continues only with the settings it started with"
        )
    body = {k: v for k, v in data.items() if k != layout.DIGEST_KEY}
    if verify and data[layout.DIGEST_KEY] != json_digest(body):
        raise RunDirError(
            f"{path} does not match its digest: it was edited or corrupted after the run "
            "wrote it; restore it (a run continues only with the settings it started with)"
        )
    return data


def _not_a_run(directory: Dir) -> str:
    """Why ``directory``, which has no ``config.json``, is not a run, and what to do."""
    names, hint = directory.names(), ""
    if names == [layout.LOCK_FILE]:
        hint = (
            f" (only the {layout.LOCK_FILE} of a start that failed: start it again with "
            f"--out {directory}, which takes it over)"
        )
    if present(directory / layout.SB3_PLAN_FILE):
        # SB3's seeds are kept one by one; the run directory is written once all finish
        kept = 0
        if layout.SB3_SEEDS_DIR in names:
            with contextlib.closing(directory.sub(layout.SB3_SEEDS_DIR)) as seeds:
                kept = len(fnmatch.filter(seeds.names(), "seed-*.npz"))
        hint = (
            f" yet: it is an interrupted python -m jaxcart.sb3 run ({kept} seed(s) kept); "
            f"train the others, then plot or evaluate it: python -m jaxcart.sb3 --resume "
            f"{directory}"
        )
    return f"{directory} has no {layout.CONFIG_FILE}: it is not a jaxcart run directory{hint}"


# ---- writing: the one writer, and the manifest that records what it wrote ----


@contextlib.contextmanager
def atomic_file(
    target: Target, mode: str = "w", on_digest: Callable[[str], None] | None = None
) -> Iterator[IO]:
    """A file to write ``target`` through: a temporary beside it (``.<name>.<random>.tmp``),
    fsynced and renamed into place (the rename made durable) when the block ends without an
    exception, so a crash mid-write leaves either the old file or the new one. The one writer
    of every file jaxcart writes. The temporary is created, renamed and removed through the
    directory's descriptor (``target`` a path: its parent, opened for the write), never
    through a link; it gets ``0o666`` less the umask, the mode ``open()`` gives.

    Args:
        target: the file to (re)place.
        mode: ``"w"`` (UTF-8 text, ``newline=""``: what is written is what lands) or
            ``"wb"``.
        on_digest: called with the ``sha256:<hex>`` of the finished bytes before they are
            renamed into place (a :class:`Manifest` records it first).

    Raises:
        OSError: the write failed (a full or read-only disk, no permission); ``filename`` is
            the target and the previous file, if any, is untouched.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_file writes with mode 'w' or 'wb', got {mode!r}")
    if not isinstance(target, Entry):
        path = Path(target)
        try:
            parent = Dir.open(path.parent)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        with contextlib.closing(parent), atomic_file(parent / path.name, mode, on_digest) as f:
            yield f
        return
    directory, name = target.dir, target.name
    tmp = None
    try:
        tmp = f"{layout.temporary_prefix(name)}{secrets.token_hex(6)}{layout.TEMPORARY_SUFFIX}"
        flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        fd = os.open(tmp, flags, 0o666, dir_fd=directory.fd)  # 0o666 less the umask
        try:
            text = {"encoding": "utf-8", "newline": ""} if mode == "w" else {}
            f = os.fdopen(fd, mode, **text)
        except BaseException:
            os.close(fd)
            raise
        with f:
            yield f
            f.flush()
            os.fsync(f.fileno())
            if on_digest is not None:
                on_digest(fd_digest(f.fileno()))
        os.replace(tmp, name, src_dir_fd=directory.fd, dst_dir_fd=directory.fd)
        directory.fsync()
    except BaseException as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp, dir_fd=directory.fd)
        if isinstance(exc, OSError):
            raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from None
        raise


def atomic_write_bytes(
    target: Target, data: bytes, on_digest: Callable[[str], None] | None = None
) -> None:
    """Writes ``data`` to ``target`` through :func:`atomic_file`."""
    with atomic_file(target, "wb", on_digest) as f:
        f.write(data)


def write_json(target: Target, data: dict, on_digest: Callable[[str], None] | None = None) -> None:
    """Atomic, indented JSON."""
    atomic_write_bytes(target, (json.dumps(data, indent=2) + "\n").encode(), on_digest)


Writer = Callable[..., None]
"""Writes one file: ``writer(entry, *args, on_digest=...)``, through :func:`atomic_file`."""


class Manifest:
    """The manifest a run writes in one of its directories (opened :class:`Dir`); ``kept``
    False: a run from before manifests (or a process that writes nothing), whose files are
    written alone and never checked."""

    def __init__(self, directory: Dir | None, kept: bool = True) -> None:
        self.dir, self.kept = directory, kept
        self.digests: dict[str, list[str]] = {}
        if kept:
            with contextlib.suppress(RunDirError):  # a resumed run keeps what it recorded
                self.digests = read_manifest(directory)

    def write(self, name: str, writer: Writer, *args: Any, **kwargs: Any) -> None:
        """Writes ``name`` with ``writer(entry, *args, on_digest=..., **kwargs)`` and records
        it: its new digest beside the old before it is renamed into place, only the new one
        after."""
        if not self.kept:
            return writer(self.dir / name, *args, on_digest=None, **kwargs)

        def stage(digest: str) -> None:
            self.digests[name] = [*self.digests.get(name, [])[-1:], digest]
            self._write()

        writer(self.dir / name, *args, on_digest=stage, **kwargs)
        self.digests[name] = self.digests[name][-1:]
        self._write()

    def write_json(self, name: str, data: dict) -> None:
        """``name`` as indented JSON (:func:`write_json`), recorded."""
        self.write(name, write_json, data)

    def forget(self, *names: str) -> None:
        if self.kept:
            for name in names:
                self.digests.pop(name, None)
            self._write()

    def verified(self, name: str) -> Entry:
        """``name``, refused unless its bytes are those recorded for it (a run from before
        manifests: unchecked)."""
        if self.kept:
            with open_tree(self.dir / name) as f:
                _check_digest(self.dir / name, fd_digest(f.fileno()), self.digests.get(name))
        return self.dir / name

    def _write(self) -> None:
        data = {"format": MANIFEST_FORMAT, "files": dict(sorted(self.digests.items()))}
        write_json(self.dir / layout.MANIFEST_FILE, data)


def write_config(manifest: Manifest, info: dict) -> None:
    """``config.json`` of a run, a sweep's combination, an SB3 run or an evaluation, recorded
    in ``manifest``: ``info`` (a JSON object, its PPO config already a dict), flagged as a run
    that keeps a manifest when it does, and its own digest over the rest, which
    :func:`read_config` checks on resume. The one writer of ``config.json``. A sweep's
    combinations are left to the reader to derive from its ``sweep``
    (:func:`~jaxcart.rundir.reader.sweep_combinations`): a million would be 70 MB of JSON."""
    data = {k: v for k, v in info.items() if k != layout.DIGEST_KEY}
    if data.get("sweep"):
        data.pop("combinations", None)
    if manifest.kept:
        data[MANIFEST_FLAG] = True
    manifest.write_json(layout.CONFIG_FILE, {**data, layout.DIGEST_KEY: json_digest(data)})


def record_json(run_dir: Where, named: dict[str, dict]) -> None:
    """Writes each ``name -> JSON object`` into ``run_dir`` and records it in the
    directory's ``manifest.json`` (created when it has none), as a run's files are: an
    evaluation's ``config.json``, a structural sweep's ``groups.json``."""
    with opened(run_dir) as directory:
        listing = Manifest(directory)
        for name, data in named.items():
            listing.write_json(name, data)


class RunLock:
    """An exclusive lock on a run directory; :meth:`acquire` fails at once if it is held."""

    def __init__(self, run_dir: str | os.PathLike | Dir) -> None:
        self.target = (run_dir if isinstance(run_dir, Dir) else Path(run_dir)) / layout.LOCK_FILE
        self._fd: int | None = None

    def acquire(self) -> RunLock:
        """Takes the lock, or raises :class:`RunInUse` naming the holder's PID."""
        import fcntl

        if self._fd is not None:
            return self
        # 0o666 less the umask, as every file of a run directory; a link (symbolic or hard)
        # is refused, not followed: truncating it would truncate whatever it points to
        fd = open_regular(self.target, os.O_RDWR | os.O_CREAT, 0o666, in_place=True)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            raise RunInUse(
                f"{Path(self.target).parent} is in use by another jaxcart process (PID "
                f"{holder}); wait for it to finish or stop it first"
            ) from None
        except BaseException:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor releases the flock
            self._fd = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


# ---- the metrics stream: the one file appended to ----


class MetricsStream:
    """The stream of one wave (``runs`` runs, ``columns``), opened with ``rows`` rows kept:
    longer files are cut to them (rows past the checkpoint), shorter ones are refused, and
    with ``digest`` (the checkpoint's record of them) rows whose bytes differ are refused."""

    def __init__(
        self, path: Target, columns: Sequence[str], runs: int, rows: int, digest: str | None = None
    ) -> None:
        self.path, self.columns, self.runs = path, tuple(columns), int(runs)
        self.row_bytes = len(self.columns) * self.runs * STREAM_DTYPE.itemsize
        # appended where it lies (0o666 less the umask): a hard link elsewhere is refused
        self.fd = self._call(open_regular, path, os.O_RDWR | os.O_CREAT, 0o666, True)
        try:
            self.hash = _check_rows(self.fd, path, rows, self.row_bytes, digest)
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
        rows = np.stack([np.asarray(metrics[c], STREAM_DTYPE) for c in self.columns], axis=1)
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


def _check_rows(fd: int, path: Target, rows: int, row_bytes: int, digest: str | None) -> Any:
    """The sha256 of the first ``rows`` rows of the stream ``fd`` (kept open for the rows
    appended next), refusing a shorter file or (``digest``: the checkpoint's record) other
    bytes."""
    if os.fstat(fd).st_size < rows * row_bytes:
        raise RunDirError(
            f"{path} holds {os.fstat(fd).st_size // row_bytes} iterations of metrics, fewer "
            f"than the {rows} iterations its checkpoint counts; refusing it"
        )
    h = hash_fd(fd, rows * row_bytes)
    if digest is not None and "sha256:" + h.hexdigest() != digest:
        raise RunDirError(
            f"{path} is not the file the run wrote: its rows differ from the digest its "
            "checkpoint records"
        )
    return h


def read_stream(
    path: Target, columns: Sequence[str], runs: int, rows: int, digest: str | None = None
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
    with open_tree(path) as f:
        _check_rows(f.fileno(), path, rows, len(columns) * runs * STREAM_DTYPE.itemsize, digest)
        return _mapped(f, rows, columns, runs)


def _mapped(f, rows: int, columns: Sequence[str], runs: int) -> dict[str, np.ndarray]:
    """The first ``rows`` rows of the open stream ``f``, memory-mapped (zeros when there are
    none: an empty file cannot be mapped), as column -> ``[rows, runs]`` views."""
    shape = (rows, len(columns), runs)
    block = (
        np.memmap(f, STREAM_DTYPE, mode="r", shape=shape) if rows else np.zeros(shape, STREAM_DTYPE)
    )
    return {name: block[:, c, :] for c, name in enumerate(columns)}


# ---- tree files (.npz) ----


def json_digest(data: dict) -> str:
    """``sha256:<hex>`` of a JSON object's canonical text (sorted keys, no spaces), so
    that any change to a value shows while formatting does not matter."""
    text = json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=True)
    return "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def arrays_digest(arrays: dict[str, np.ndarray]) -> str:
    """``sha256:<hex>`` of named arrays: each name, dtype, shape and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.asarray(arrays[name])
        h.update(f"{name}|{a.dtype.str}|{a.shape}|".encode())
        # a long (e.g. memory-mapped) array is hashed a slab of rows at a time: the same
        # bytes as its C-order whole, without a copy of all of it
        rows = max(1, (64 << 20) // max(1, a[:1].nbytes)) if a.ndim else 1
        for start in range(0, len(a) if a.ndim else 1, rows):
            h.update(np.ascontiguousarray(a[start : start + rows] if a.ndim else a).tobytes())
    return "sha256:" + h.hexdigest()


def flatten(tree: Any, is_leaf: Any = None) -> dict[str, Any]:
    """``{"a": {"b": x}} -> {"a/b": x}`` for any pytree (array leaves as NumPy arrays): each
    leaf under its key path, dict keys, attribute names and sequence indices joined by ``/``."""
    import jax

    leaves = jax.tree_util.tree_flatten_with_path(jax.device_get(tree), is_leaf=is_leaf)[0]
    return {
        jax.tree_util.keystr(path, simple=True, separator="/"): (
            leaf if is_leaf is not None else np.asarray(leaf)
        )
        for path, leaf in leaves
    }


def unflatten(flat: dict[str, np.ndarray]) -> dict:
    """Inverse of :func:`flatten` for trees of nested dicts."""
    from flax.traverse_util import unflatten_dict

    return unflatten_dict(flat, sep="/")


def save_tree(
    target: Target,
    arrays: dict[str, np.ndarray],
    meta: dict | None = None,
    on_digest: Callable[[str], None] | None = None,
) -> None:
    """Writes named arrays (see :func:`flatten`) and optional JSON ``meta`` atomically."""
    entries = dict(arrays)
    if meta is not None:
        entries[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    with atomic_file(target, "wb", on_digest) as f:  # written as it goes: no copy of the whole file
        np.savez(f, **entries)


@contextlib.contextmanager
def _reading(path: Target) -> Iterator[None]:
    """Turns every way reading a tree file can fail into one :class:`RunDirError`."""
    try:
        yield
    except RunDirError:
        raise
    except (OSError, ValueError, KeyError, EOFError, RecursionError, zipfile.BadZipFile) as exc:
        raise RunDirError(f"{path} is corrupted: {str(exc)[:200]}") from None


Header = tuple[tuple[int, ...], np.dtype]
"""An array's shape and dtype, read from its ``.npy`` header."""


def nbytes(headers: dict[str, Header]) -> int:
    """The bytes of the arrays these headers describe."""
    return sum(math.prod(shape) * np.dtype(dtype).itemsize for shape, dtype in headers.values())


def read_headers(path: Target, max_bytes: int) -> tuple[dict[str, Header], dict | None]:
    """Each array's shape and dtype from its header alone, and the JSON metadata (None when
    there is none), after checking that the file is a plain ``.npz`` whose declared sizes add
    up and stay under ``max_bytes``: a crafted file is refused before anything large is read.

    Raises:
        RunDirError: not a zip of ``.npy`` arrays, object arrays, sizes that do not match
            their headers, more than ``max_bytes`` in all, or metadata that is not a JSON
            object of reasonable size.
    """
    headers: dict[str, Header] = {}
    meta = None
    with _reading(path), open_tree(path) as raw, zipfile.ZipFile(raw) as zf:
        infos = zf.infolist()
        names = [i.filename for i in infos]
        if len(set(names)) != len(names):  # np.load would read the last, unchecked, copy
            twice = next(n for n in names if names.count(n) > 1)
            raise RunDirError(f"{path} holds the entry {twice!r} twice; refusing it")
        total = sum(i.file_size for i in infos)
        if total > max_bytes:
            raise RunDirError(
                f"{path} declares {total:,} bytes, more than the {max_bytes:,} expected"
            )
        for info in infos:
            if info.compress_type != zipfile.ZIP_STORED:  # jaxcart never compresses: no bombs
                raise RunDirError(f"{path}: {info.filename} is compressed; refusing it")
            if not info.filename.endswith(".npy"):
                raise RunDirError(f"{path}: unexpected entry {info.filename!r}")
            with zf.open(info) as f:
                version = np.lib.format.read_magic(f)
                read_header = {
                    (1, 0): np.lib.format.read_array_header_1_0,
                    (2, 0): np.lib.format.read_array_header_2_0,
                }.get(version)
                if read_header is None:
                    raise RunDirError(f"{path}: {info.filename} has .npy version {version}")
                shape, _, dtype = read_header(f)
                if dtype.hasobject:
                    raise RunDirError(f"{path}: {info.filename} holds objects; refusing it")
                data_bytes = math.prod(shape) * dtype.itemsize
                if f.tell() + data_bytes != info.file_size:
                    raise RunDirError(f"{path}: {info.filename}'s size does not match its header")
                if info.filename == META_KEY + ".npy":
                    if dtype != np.uint8 or data_bytes > MAX_META_BYTES:
                        raise ValueError("metadata is not a JSON text of reasonable size")
                    meta = json.loads(f.read(data_bytes).decode())
                    if not isinstance(meta, dict):
                        raise ValueError("metadata is not a JSON object")
                    continue
            headers[info.filename[: -len(".npy")]] = (tuple(shape), dtype)
    return headers, meta


def load_tree(
    path: Target,
    max_bytes: int = 1 << 34,
    expected: dict[str, Header] | None = None,
    what: str = "this run's network",
    exact: bool = True,
) -> tuple[dict[str, np.ndarray], dict | None]:
    """Every named array of a tree file and its metadata (None when it has none), reading
    at most ``max_bytes`` (checked against the headers before any array is read). With
    ``expected`` (name -> shape and dtype; a dtype None takes any), the headers must hold
    exactly those arrays (at least those, unless ``exact``; ``what`` says what they are, in
    the error) and those of a given dtype must be finite.

    Raises:
        RunDirError: the file is missing, not an ``.npz``, torn, too large, holds objects,
            or not the ``expected`` arrays.
    """
    found, meta = read_headers(path, max_bytes)
    if expected is not None:
        missing = sorted(set(expected) - set(found))
        extra = sorted(set(found) - set(expected)) if exact else []
        if missing or extra:
            raise RunDirError(
                f"{path} does not hold {what} (different structure): missing {missing[:3]}, "
                f"unexpected {extra[:3]}"
            )
        for name, (shape, dtype) in expected.items():
            if found[name][0] != shape or (dtype is not None and found[name][1] != dtype):
                raise RunDirError(
                    f"{path} does not hold {what}: {name} has another shape/dtype "
                    f"{found[name][0]}/{found[name][1]}, expected {shape}/{dtype}"
                )
    with _reading(path), open_tree(path) as raw, np.load(raw, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != META_KEY}
    for name, (_, dtype) in (expected or {}).items():
        a = arrays[name]
        if dtype is not None and np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all():
            raise RunDirError(f"{path}: {name} holds NaN or infinite values; refusing it")
    return arrays, meta


def read_meta(path: Target) -> dict:
    """Only the JSON metadata of a tree file (the arrays are not read)."""
    meta = read_headers(path, max_bytes=1 << 40)[1]  # sizes are checked, nothing large read
    if meta is None:
        raise RunDirError(f"{path} has no metadata")
    return meta
