"""Checkpoints of the full training state, written atomically.

A checkpoint is one tree file (:mod:`jaxcart.rundir.files`): every array of the
:class:`~jaxcart.engine.trainer.TrainState` under its tree path (``state/runners/params/params/actor/
hidden_0/kernel``, ``state/hyperparams/learning_rate``, ...), the metrics so far under
``metrics/<name>``, and a JSON ``__meta__`` entry (iteration, elapsed time, chunk size, config,
package versions). It is written beside the target, fsynced and renamed over the previous
checkpoint, so a crash or SIGKILL at any moment leaves the old or the new one, never a torn
one. :func:`jaxcart.rundir.reader.load_checkpoint` restores it into a template state built
from the run's config, checking that every name, shape and dtype matches.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from jaxcart.engine.trainer import TrainState
from jaxcart.rundir import files
from jaxcart.rundir.layout import CHECKPOINT_FORMAT, CHECKPOINT_METRICS, CHECKPOINT_STATE


def state_arrays(state: TrainState) -> dict[str, np.ndarray]:
    """The checkpoint entries of a state's arrays: ``state/<tree path>`` -> ``[R, ...]``."""
    tree = {"runners": state.runners, "hyperparams": state.hyperparams}
    return {CHECKPOINT_STATE + name: a for name, a in files.flatten(tree).items()}


def save_checkpoint(path: str | os.PathLike, state: TrainState, meta: dict) -> None:
    """Writes ``state`` (its arrays and metrics) and ``meta`` (JSON-able) to ``path``."""
    arrays = state_arrays(state)
    metrics = {CHECKPOINT_METRICS + name: np.asarray(a) for name, a in state.metrics.items()}
    meta = {
        **meta,
        "checkpoint_format": CHECKPOINT_FORMAT,
        "iteration": state.iteration,
        "elapsed": state.elapsed,
        "chunk_size": state.chunk_size,
    }
    files.save_tree(path, {**arrays, **metrics}, meta)
    files.fsync_directory(Path(path).parent)
