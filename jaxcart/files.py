"""Writing files so that a crash never leaves a torn one, and the one ``.npz`` format for trees.

A tree file (parameters, checkpoints) is an uncompressed ``.npz``: every array leaf under its
tree path joined with ``/`` (``params/actor/hidden_0/kernel``, ``runners/opt_state/1/mu/...``)
and optionally a JSON metadata entry ``__meta__``. Nothing is ever unpickled.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

META_KEY = "__meta__"


class RunDirError(ValueError):
    """A file or directory is not a usable jaxcart run (directory); the message says why."""


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    """Writes ``data`` to a temporary file beside ``path``, fsyncs it and renames it into
    place, so a crash mid-write leaves either the old file or the new one.

    Raises:
        OSError: the write failed (a full or read-only disk, no permission); ``filename`` is
            ``path`` and the previous file, if any, is untouched.
    """
    path = Path(path)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        raise


def fsync_directory(path: str | os.PathLike) -> None:
    """Makes the renames inside ``path`` durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_json(path: str | os.PathLike, data: dict) -> None:
    """Atomic, indented JSON."""
    atomic_write_bytes(path, (json.dumps(data, indent=2) + "\n").encode())


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


def flatten(tree: Any) -> dict[str, np.ndarray]:
    """``{"a": {"b": x}} -> {"a/b": x}`` for any pytree (leaves as NumPy arrays)."""
    import jax

    leaves = jax.tree_util.tree_flatten_with_path(jax.device_get(tree))[0]
    return {path_name(path): np.asarray(leaf) for path, leaf in leaves}


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
    path: str | os.PathLike, arrays: dict[str, np.ndarray], meta: dict | None = None
) -> None:
    """Writes named arrays (see :func:`flatten`) and optional JSON ``meta`` atomically."""
    entries = dict(arrays)
    if meta is not None:
        entries[META_KEY] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
    buf = io.BytesIO()
    np.savez(buf, **entries)
    atomic_write_bytes(path, buf.getvalue())


@contextlib.contextmanager
def _reading(path: str | os.PathLike) -> Iterator[None]:
    """Turns every way reading a tree file can fail into one :class:`RunDirError`."""
    try:
        yield
    except FileNotFoundError:
        raise RunDirError(f"{path} does not exist") from None
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise RunDirError(f"{path} is corrupted: {exc}") from None


def load_tree(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict | None]:
    """Every named array of a tree file and its metadata (None when it has none).

    Raises:
        RunDirError: the file is missing, not an ``.npz``, torn or holds objects.
    """
    with _reading(path), np.load(path, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files if k != META_KEY}
        meta = json.loads(bytes(data[META_KEY]).decode()) if META_KEY in data.files else None
    return arrays, meta


def read_meta(path: str | os.PathLike) -> dict:
    """Only the JSON metadata of a tree file (the arrays are not read)."""
    with _reading(path), np.load(path, allow_pickle=False) as data:
        return json.loads(bytes(data[META_KEY]).decode())
