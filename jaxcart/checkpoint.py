"""Checkpoints of the full training state, written atomically.

A checkpoint is one ``.npz`` file: every array leaf of the state pytree under its tree path
(``runners/params/params/actor/hidden_0/kernel``, ...), plus a JSON metadata entry
(``__meta__``: iteration, config, seeds, package versions, chunk size, elapsed time). It is
written to a temporary file beside the target, flushed and fsynced, then renamed over the
previous checkpoint, so a crash or SIGKILL at any moment leaves either the old or the new
checkpoint, never a torn one. Loading restores leaves into a template pytree built from the
config, checking that every path, shape and dtype matches.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxcart.rundir import RunDirError, atomic_write_bytes

CHECKPOINT_FILE = "checkpoint.npz"
META_KEY = "__meta__"
CHECKPOINT_FORMAT = 1


def _leaf_items(tree: Any) -> list[tuple[str, Any]]:
    leaves, _ = jax.tree_util.tree_flatten_with_path(tree)
    return [(jax.tree_util.keystr(path), leaf) for path, leaf in leaves]


def save_checkpoint(
    path: str | os.PathLike, state: Any, meta: dict, extras: dict[str, np.ndarray] | None = None
) -> None:
    """Writes ``state`` (any pytree of arrays), ``meta`` (JSON-able) and ``extras`` (named
    arrays of any shape, e.g. the metrics so far) to ``path`` atomically."""
    arrays = {name: np.asarray(leaf) for name, leaf in _leaf_items(jax.device_get(state))}
    extras = {name: np.asarray(a) for name, a in (extras or {}).items()}
    meta = {
        **meta,
        "checkpoint_format": CHECKPOINT_FORMAT,
        "leaves": list(arrays),
        "extras": list(extras),
    }
    buf = io.BytesIO()
    np.savez(
        buf,
        **{f"leaf{i}": a for i, a in enumerate(arrays.values())},
        **{f"extra{i}": a for i, a in enumerate(extras.values())},
        **{META_KEY: np.frombuffer(json.dumps(meta).encode(), np.uint8)},
    )
    atomic_write_bytes(Path(path), buf.getvalue())
    # make the rename itself durable
    dir_fd = os.open(Path(path).parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def read_checkpoint_meta(path: str | os.PathLike) -> dict:
    """The metadata of a checkpoint, with a :class:`RunDirError` if it is unreadable."""
    try:
        with np.load(path) as data:
            return json.loads(bytes(data[META_KEY]).decode())
    except FileNotFoundError:
        raise RunDirError(f"no checkpoint at {path}") from None
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, json.JSONDecodeError) as exc:
        raise RunDirError(f"checkpoint {path} is corrupted: {exc}") from None


def load_checkpoint(path: str | os.PathLike, template: Any) -> tuple[Any, dict]:
    """Restores a checkpoint into the structure of ``template``.

    Returns:
        ``(state, meta)`` with ``state`` a pytree like ``template`` holding NumPy arrays.

    Raises:
        RunDirError: missing, corrupted, or saved from a different structure/shape.
    """
    meta = read_checkpoint_meta(path)
    if meta.get("checkpoint_format") != CHECKPOINT_FORMAT:
        raise RunDirError(
            f"checkpoint {path} has format {meta.get('checkpoint_format')}, expected {CHECKPOINT_FORMAT}"
        )
    items = _leaf_items(template)
    names = [name for name, _ in items]
    if meta["leaves"] != names:
        raise RunDirError(
            f"checkpoint {path} does not match this version's training state (different structure)"
        )
    try:
        with np.load(path) as data:
            arrays = [data[f"leaf{i}"] for i in range(len(names))]
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise RunDirError(f"checkpoint {path} is corrupted: {exc}") from None
    for (name, leaf), arr in zip(items, arrays):
        expected = (
            tuple(np.shape(leaf)),
            np.asarray(leaf).dtype if not hasattr(leaf, "dtype") else leaf.dtype,
        )
        if (arr.shape, arr.dtype) != expected:
            raise RunDirError(
                f"checkpoint {path}: {name} has shape/dtype {arr.shape}/{arr.dtype}, expected {expected[0]}/{expected[1]}"
            )
    treedef = jax.tree_util.tree_structure(template)
    return jax.tree_util.tree_unflatten(treedef, arrays), meta


def load_extras(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The named extra arrays saved with a checkpoint."""
    meta = read_checkpoint_meta(path)
    try:
        with np.load(path) as data:
            return {name: data[f"extra{i}"] for i, name in enumerate(meta.get("extras", []))}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        raise RunDirError(f"checkpoint {path} is corrupted: {exc}") from None
