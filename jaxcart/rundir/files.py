"""Writing files so that a crash never leaves a torn one, and the one ``.npz`` format for trees.

A tree file (parameters, checkpoints) is an uncompressed ``.npz``: every array leaf under its
tree path joined with ``/`` (``params/actor/hidden_0/kernel``, ``runners/opt_state/1/mu/...``)
and optionally a JSON metadata entry ``__meta__``. Nothing is ever unpickled.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import json
import math
import os
import secrets
import stat
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from jaxcart.rundir import layout

META_KEY = "__meta__"


class RunDirError(ValueError):
    """A file or directory is not a usable jaxcart run (directory); the message says why."""


def _read_umask() -> int:
    """The process's umask, read without changing it when the kernel reports it
    (``os.umask`` can only read it by setting it, and a file another thread creates meanwhile
    would get the wrong mode)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    umask = os.umask(0o022)
    os.umask(umask)
    return umask


@functools.cache
def file_mode() -> int:
    """The permissions ``open()`` would give a new file: ``0o666 & ~umask`` (0644 under the
    usual umask 022), read once. ``mkstemp`` creates 0600 files, which colleagues sharing a
    machine could not read."""
    return 0o666 & ~_read_umask()


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
                with contextlib.suppress(OSError):
                    st = os.stat(path, dir_fd=parent.fd if parent else None, follow_symlinks=False)
                    if stat.S_ISLNK(st.st_mode):
                        raise RunDirError(f"{shown} is {LINK_REASON}") from None
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

    @property
    def name(self) -> str:
        return self.path.name

    def names(self) -> list[str]:
        """The names inside this directory (``os.listdir`` of its descriptor)."""
        return os.listdir(self.fd)

    def lstat(self, name: str) -> os.stat_result | None:
        """``name``'s own status (a link is not followed), None when it does not exist."""
        try:
            return os.stat(name, dir_fd=self.fd, follow_symlinks=False)
        except FileNotFoundError:
            return None

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

    @property
    def path(self) -> Path:
        return self.dir.path / self.name

    def __fspath__(self) -> str:
        return str(self.path)

    def __str__(self) -> str:
        return str(self.path)


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


def present(target: Target) -> bool:
    """Whether ``target`` exists, by ``lstat`` (see :func:`jaxcart.rundir.layout.present`),
    relative to its directory's descriptor when it is an :class:`Entry`."""
    name, dir_fd = _located(target)
    try:
        os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
    except FileNotFoundError:
        return False
    except OSError:
        return True  # there, but not readable: its reader says why
    return True


LINK_REASON = "a symbolic link; jaxcart never follows links in a run directory"


def _located(target: Target) -> tuple[str, int | None]:
    """The name to pass to ``os.open`` and the directory descriptor it is relative to."""
    if isinstance(target, Entry):
        return target.name, target.dir.fd
    return os.fspath(target), None


@contextlib.contextmanager
def atomic_file(
    target: Target, mode: str = "w", on_digest: Callable[[str], None] | None = None
) -> Iterator[IO]:
    """A file to write ``target`` through: a temporary beside it (``.<name>.<random>.tmp``),
    fsynced and renamed into place when the block ends without an exception, so a crash
    mid-write leaves either the old file or the new one. The one writer of every file jaxcart
    writes. The temporary is created, renamed and removed through the directory's descriptor
    (``target`` a path: its parent, opened for the write), never through a link.

    Args:
        target: the file to (re)place.
        mode: ``"w"`` (UTF-8 text, ``newline=""``: what is written is what lands) or
            ``"wb"``.
        on_digest: called with the ``sha256:<hex>`` of the finished bytes before they are
            renamed into place (a manifest records it first: :mod:`jaxcart.rundir.manifest`).

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
        try:
            with atomic_file(parent / path.name, mode, on_digest) as f:
                yield f
        finally:
            parent.close()
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
    except BaseException as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp, dir_fd=directory.fd)
        if isinstance(exc, OSError):
            raise OSError(exc.errno, exc.strerror or str(exc), str(target)) from None
        raise


def fd_digest(fd: int) -> str:
    """``sha256:<hex>`` of an open file's bytes, read from its start (the offset is kept)."""
    h, offset = hashlib.sha256(), 0
    while chunk := os.pread(fd, 1 << 20, offset):
        h.update(chunk)
        offset += len(chunk)
    return "sha256:" + h.hexdigest()


def atomic_write_bytes(
    target: Target, data: bytes, on_digest: Callable[[str], None] | None = None
) -> None:
    """Writes ``data`` to ``target`` through :func:`atomic_file`."""
    with atomic_file(target, "wb", on_digest) as f:
        f.write(data)


def fsync_directory(path: str | os.PathLike) -> None:
    """Makes the renames inside ``path`` durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_json(target: Target, data: dict, on_digest: Callable[[str], None] | None = None) -> None:
    """Atomic, indented JSON."""
    atomic_write_bytes(target, (json.dumps(data, indent=2) + "\n").encode(), on_digest)


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


def path_name(path: tuple) -> str:
    """A JAX key path as ``a/b/0/c`` (dict keys, attribute names and sequence indices)."""
    parts = []
    for key in path:
        for attr in ("key", "name", "idx"):
            if hasattr(key, attr):
                parts.append(str(getattr(key, attr)))
                break
        else:
            parts.append(str(key))
    return "/".join(parts)


def flatten(tree: Any, is_leaf: Any = None) -> dict[str, Any]:
    """``{"a": {"b": x}} -> {"a/b": x}`` for any pytree (array leaves as NumPy arrays)."""
    import jax

    leaves = jax.tree_util.tree_flatten_with_path(jax.device_get(tree), is_leaf=is_leaf)[0]
    return {
        path_name(path): leaf if is_leaf is not None else np.asarray(leaf) for path, leaf in leaves
    }


def unflatten(flat: dict[str, np.ndarray]) -> dict:
    """Inverse of :func:`flatten` for trees of nested dicts."""
    tree: dict = {}
    for name, value in flat.items():
        node = tree
        *parents, leaf = name.split("/")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return tree


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
def _reading(path: str | os.PathLike) -> Iterator[None]:
    """Turns every way reading a tree file can fail into one :class:`RunDirError`."""
    try:
        yield
    except FileNotFoundError:
        raise RunDirError(f"{path} does not exist") from None
    except RunDirError:
        raise
    except (
        OSError,
        ValueError,
        KeyError,
        EOFError,
        RecursionError,
        zipfile.BadZipFile,
        UnicodeDecodeError,
    ) as exc:
        raise RunDirError(f"{path} is corrupted: {str(exc)[:200]}") from None


Header = tuple[tuple[int, ...], np.dtype]
"""An array's shape and dtype, read from its ``.npy`` header."""
MAX_META_BYTES = 1 << 20


def refuse_link(path: Target) -> os.stat_result | None:
    """``lstat(path)``, refusing a symbolic link (a run directory someone else made may hold
    anything: a link would make jaxcart read or write outside the directory). None when
    ``path`` does not exist.

    Raises:
        RunDirError: ``path`` is a symbolic link.
    """
    name, dir_fd = _located(path)
    try:
        st = os.stat(name, dir_fd=dir_fd, follow_symlinks=False)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise RunDirError(f"{path} cannot be read: {exc.strerror or exc}") from None
    if stat.S_ISLNK(st.st_mode):
        raise RunDirError(f"{path} is {LINK_REASON}")
    return st


WRITE_FAILURES = (errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM)
"""Errors of a disk or mount that refuses writes: reported as failed writes (exit 1), not as a
bad run directory."""


def open_regular(
    path: Target, flags: int = os.O_RDONLY, mode: int = 0o666, in_place: bool = False
) -> int:
    """A descriptor of ``path`` opened without following a link, checked to be a regular
    file (never a FIFO, device or directory: ``O_NONBLOCK`` keeps a FIFO from blocking the
    open, and it is cleared once the file is known to be regular). ``in_place``: a file
    jaxcart changes where it lies (the lock, the metrics stream) must have one link, else
    truncating or appending to it would change a hard-linked file outside the run.

    Raises:
        RunDirError: ``path`` is a link, not a regular file, or (``in_place``) hard-linked.
        FileNotFoundError: it does not exist (and ``flags`` do not create it).
        OSError: the disk refuses an open for writing (:data:`WRITE_FAILURES`).
    """
    name, dir_fd = _located(path)
    try:
        fd = os.open(
            name, flags | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, mode, dir_fd=dir_fd
        )
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise RunDirError(f"{path} is {LINK_REASON}") from None
        writing = flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT)
        if isinstance(exc, FileNotFoundError) or (writing and exc.errno in WRITE_FAILURES):
            raise  # a missing file; or a disk that refuses writes: the caller's write failure
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


def read_bytes(path: Target, max_bytes: int) -> bytes:
    """A regular file's bytes (no link followed), refusing one larger than ``max_bytes``.

    Raises:
        RunDirError: missing, a link, not a regular file, or too large.
    """
    try:
        fd = open_regular(path)
    except FileNotFoundError:
        raise RunDirError(f"{path} does not exist") from None
    with os.fdopen(fd, "rb") as f:
        if os.fstat(f.fileno()).st_size > max_bytes:
            raise RunDirError(f"{path} is larger than any such file jaxcart writes")
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise RunDirError(f"{path} is larger than any such file jaxcart writes")
    return data


def subdir(directory: str | os.PathLike, name: str, create: bool = False) -> Path:
    """``directory / name`` checked to be a real directory (not a link) when it exists;
    created (its parent must exist: a deleted run directory is never recreated) when
    ``create``.

    Raises:
        RunDirError: a link or something other than a directory.
        OSError: it could not be created.
    """
    path = Path(directory) / name
    st = refuse_link(path)
    if st is None and create:
        try:
            path.mkdir()
        except FileExistsError:
            pass
        st = refuse_link(path)
    if st is not None and not stat.S_ISDIR(st.st_mode):
        raise RunDirError(f"{path} is not a directory; refusing it")
    return path


def inside(directory: Where, name: str) -> Target:
    """``directory / name`` after checking that it is a regular file there, not a link (a
    run directory someone else made may hold anything).

    Raises:
        RunDirError: missing, a link, or not a regular file.
    """
    path = directory / name if isinstance(directory, Dir) else Path(directory) / name
    st = refuse_link(path)
    if st is None:
        raise RunDirError(f"{path} does not exist")
    if not stat.S_ISREG(st.st_mode):
        raise RunDirError(f"{path} is not a regular file; refusing it")
    return path


@contextlib.contextmanager
def open_tree(path: Target) -> Iterator[IO[bytes]]:
    """A tree file opened for reading without following a link (see :func:`open_regular`)."""
    try:
        fd = open_regular(path)
    except FileNotFoundError:
        raise RunDirError(f"{path} does not exist") from None
    with os.fdopen(fd, "rb") as f:
        yield f


def read_headers(path: Target, max_bytes: int) -> dict[str, Header]:
    """Each array's shape and dtype from its header alone, after checking that the file is
    a plain ``.npz`` whose declared sizes add up and stay under ``max_bytes``: a crafted
    file is refused before anything large is read.

    Raises:
        RunDirError: not a zip of ``.npy`` arrays, object arrays, sizes that do not match
            their headers, or more than ``max_bytes`` in all.
    """
    headers: dict[str, Header] = {}
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
            headers[info.filename[: -len(".npy")]] = (tuple(shape), dtype)
    return headers


def load_tree(path: Target, max_bytes: int = 1 << 34) -> tuple[dict[str, np.ndarray], dict | None]:
    """Every named array of a tree file and its metadata (None when it has none), reading
    at most ``max_bytes`` (checked against the headers before any array is read).

    Raises:
        RunDirError: the file is missing, not an ``.npz``, torn, too large or holds objects.
    """
    read_headers(path, max_bytes)
    with _reading(path), open_tree(path) as raw, np.load(raw, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != META_KEY}
        meta = _meta(data) if META_KEY in data.files else None
    return arrays, meta


def _meta(data: Any) -> dict:
    raw = data[META_KEY]
    if raw.dtype != np.uint8 or raw.size > MAX_META_BYTES:
        raise ValueError("metadata is not a JSON text of reasonable size")
    meta = json.loads(bytes(raw).decode())
    if not isinstance(meta, dict):
        raise ValueError("metadata is not a JSON object")
    return meta


def read_meta(path: Target) -> dict:
    """Only the JSON metadata of a tree file (the arrays are not read)."""
    headers = read_headers(path, max_bytes=1 << 40)  # sizes are checked, nothing large read
    if META_KEY not in headers:
        raise RunDirError(f"{path} has no metadata")
    with _reading(path), open_tree(path) as raw, np.load(raw, allow_pickle=False) as data:
        return _meta(data)


def check_finite(arrays: dict[str, np.ndarray], path: str | os.PathLike) -> None:
    """Refuses NaN or infinite values in floating-point arrays."""
    for name, a in arrays.items():
        if np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all():
            raise RunDirError(f"{path}: {name} holds NaN or infinite values; refusing it")
