"""Checkpoints of the full training state, written atomically.

A checkpoint is one tree file (:mod:`jaxcart.rundir.files`): every array of the
:class:`~jaxcart.engine.trainer.TrainState` under its tree path (``state/runners/params/params/actor/
hidden_0/kernel``, ``state/hyperparams/learning_rate``, ...), the metrics so far under
``metrics/<name>``, and a JSON ``__meta__`` entry (iteration, elapsed time, chunk size, config,
package versions). It is written beside the target, fsynced and renamed over the previous
checkpoint, so a crash or SIGKILL at any moment leaves the old or the new one, never a torn
one. Loading restores the arrays into a template state built from the run's config, checking
that every name, shape and dtype matches.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np

from jaxcart.engine.trainer import TrainState
from jaxcart.rundir import files
from jaxcart.rundir.files import RunDirError

CHECKPOINT_FILE = "checkpoint.npz"
CHECKPOINT_FORMAT = 2
STATE = "state/"
METRICS = "metrics/"


def _state_arrays(state: TrainState) -> dict[str, np.ndarray]:
    tree = {"runners": state.runners, "hyperparams": state.hyperparams}
    return {STATE + name: a for name, a in files.flatten(tree).items()}


def save_checkpoint(path: str | os.PathLike, state: TrainState, meta: dict) -> None:
    """Writes ``state`` (its arrays and metrics) and ``meta`` (JSON-able) to ``path``."""
    arrays = _state_arrays(state)
    metrics = {METRICS + name: np.asarray(a) for name, a in state.metrics.items()}
    meta = {
        **meta,
        "checkpoint_format": CHECKPOINT_FORMAT,
        "iteration": state.iteration,
        "elapsed": state.elapsed,
        "chunk_size": state.chunk_size,
    }
    files.save_tree(path, {**arrays, **metrics}, meta)
    files.fsync_directory(Path(path).parent)


def read_checkpoint_meta(path: str | os.PathLike) -> dict:
    """The metadata of a checkpoint, with a :class:`RunDirError` if it is unreadable."""
    meta = files.read_meta(path)
    if not isinstance(meta, dict) or meta.get("checkpoint_format") != CHECKPOINT_FORMAT:
        found = meta.get("checkpoint_format") if isinstance(meta, dict) else None
        raise RunDirError(
            f"checkpoint {path} has format {found}, this version reads {CHECKPOINT_FORMAT}"
        )
    return meta


def load_checkpoint(
    path: str | os.PathLike, template: TrainState, num_runs: int | None = None
) -> TrainState:
    """Restores a checkpoint into the structure of ``template`` (NumPy leaves).

    ``template`` gives the names, dtypes and per-run shapes; its leading run axis may be
    shorter than the checkpoint's ``num_runs`` (a one-run template is enough). Every header
    is checked before anything is read, and the state must be finite.

    Raises:
        RunDirError: missing, corrupted, crafted, or saved from a different structure/shape.
    """
    meta = read_checkpoint_meta(path)
    expected = _expected_headers(template, num_runs, int(meta["iteration"]))
    limit = sum(int(np.prod(shape)) * dtype.itemsize for shape, dtype in expected.values())
    found = files.read_headers(path, max_bytes=limit + (1 << 20))
    found.pop(files.META_KEY, None)
    if set(found) != set(expected):
        raise RunDirError(
            f"checkpoint {path} does not match this version's training state (different structure)"
        )
    for name, (shape, dtype) in expected.items():
        if found[name] != (shape, dtype):
            raise RunDirError(
                f"checkpoint {path}: {name} has shape/dtype {found[name][0]}/{found[name][1]}, "
                f"expected {shape}/{dtype}"
            )
    arrays, _ = files.load_tree(path, max_bytes=limit + (1 << 20))
    state_names = [n for n in expected if n.startswith(STATE)]
    files.check_finite({n: arrays[n] for n in state_names}, path)
    tree = {"runners": template.runners, "hyperparams": template.hyperparams}
    restored = jax.tree.unflatten(jax.tree.structure(tree), [arrays[n] for n in state_names])
    metrics = {n[len(METRICS) :]: a for n, a in arrays.items() if n.startswith(METRICS)}
    return TrainState(
        runners=restored["runners"],
        hyperparams=restored["hyperparams"],
        iteration=int(meta["iteration"]),
        elapsed=float(meta["elapsed"]),
        metrics=metrics,
        chunk_size=int(meta["chunk_size"]),
    )


def _expected_headers(template: TrainState, num_runs: int | None, iterations: int) -> dict:
    """Names, shapes and dtypes a checkpoint of ``num_runs`` runs at ``iterations`` holds."""
    runs = num_runs if num_runs is not None else len(template.runners.diverged_at)
    expected = {
        name: ((runs, *a.shape[1:]), a.dtype) for name, a in _state_arrays(template).items()
    }
    for name, a in template.metrics.items():
        expected[METRICS + name] = ((iterations, runs), np.asarray(a).dtype)
    return expected
