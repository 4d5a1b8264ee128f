"""Checkpoints of the full training state, written atomically.

A checkpoint is one tree file (:mod:`jaxcart.rundir.files`): every array of the
:class:`~jaxcart.engine.loop.TrainState` under its tree path
(``state/runners/params/params/actor/hidden_0/kernel``, ``state/hyperparams/learning_rate``,
...) and a JSON ``__meta__`` entry (iteration, elapsed time, chunk size, config, package
versions, and the columns of the metrics so far). The metrics themselves are not in it but in
its companion ``metrics.stream``, one row per iteration (:mod:`jaxcart.rundir.stream`), so its
size does not grow with the run's length. It is written beside the target, fsynced and
renamed over the previous checkpoint, so a crash or SIGKILL at any moment leaves the old or
the new one, never a torn one. :func:`load_checkpoint` restores it into a template state
built from the run's config, checking that every name, shape and dtype matches.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from jaxcart.core.config import MAX_CUSTOM_METRICS, PPOConfig
from jaxcart.engine.loop import METRIC_COLUMNS, TrainState, metric_columns
from jaxcart.rundir import files, layout
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.layout import CHECKPOINT_FORMAT, CHECKPOINT_STATE
from jaxcart.rundir.reader import (
    MAX_RUNS,
    bounded_int,
    finite_number,
    no_best_policy,
    params_dtype,
    params_headers,
    read_run_config,
    recorded_combinations,
)
from jaxcart.rundir.stream import STREAM_DIGEST_KEY, read_stream


def state_arrays(state: TrainState) -> dict[str, np.ndarray]:
    """The checkpoint entries of a state's arrays: ``state/<tree path>`` -> ``[R, ...]`` (the
    config's traced fields under ``state/hyperparams/``)."""
    tree = {"runners": state.runners, "hyperparams": state.config}
    return {CHECKPOINT_STATE + name: a for name, a in files.flatten(tree).items()}


def save_checkpoint(
    path: files.Target,
    state: TrainState,
    meta: dict,
    on_digest: Callable[[str], None] | None = None,
) -> None:
    """Writes ``state``'s arrays and ``meta`` (JSON-able) to ``path``; the metrics so far
    are the stream's (made durable before this is called)."""
    meta = {
        **meta,
        "checkpoint_format": CHECKPOINT_FORMAT,
        "iteration": state.iteration,
        "elapsed": state.elapsed,
        "chunk_size": state.chunk_size,
        "metrics_columns": list(metric_columns(state.config)),
    }
    files.save_tree(path, state_arrays(state), meta, on_digest)  # the rename made durable


MAX_ELAPSED = 1e10
"""Seconds of training a checkpoint may declare (three centuries)."""
MAX_CHUNK = 1 << 20
"""The most iterations a checkpoint's chunk may declare: the compiled chunk scans an int32
iteration counter and builds ``[chunk_size, R]`` metrics, so a larger one could overflow or
exhaust memory in the compiled call (the trainer also caps it at the run's iterations)."""


def read_checkpoint_meta(path: files.Target) -> dict:
    """The metadata of a checkpoint, with a :class:`RunDirError` if it is unreadable, of
    another format, or holds fields of the wrong type or out of range."""
    meta = files.read_meta(path)
    if meta.get("checkpoint_format") != layout.CHECKPOINT_FORMAT:
        raise RunDirError(
            f"checkpoint {path} has format {meta.get('checkpoint_format')!r:.40}, this version "
            f"reads {layout.CHECKPOINT_FORMAT}"
        )
    checks = {
        "iteration": bounded_int(meta.get("iteration"), 0, 1 << 40),
        "chunk_size": bounded_int(meta.get("chunk_size"), 1, MAX_CHUNK),
        "elapsed": finite_number(meta.get("elapsed")) and 0 <= meta.get("elapsed") < MAX_ELAPSED,
        "wave": bounded_int(meta.get("wave", 0), 0, MAX_RUNS),
        "num_runs": bounded_int(meta.get("num_runs", 1), 1, MAX_RUNS),
        "versions": isinstance(meta.get("versions", {}), dict)
        and all(isinstance(v, str) for v in meta.get("versions", {}).values()),
        "metrics_columns": _known_columns(meta.get("metrics_columns")),
    }
    bad = [name for name, ok in checks.items() if not ok]
    if bad:
        raise RunDirError(f"checkpoint {path} is corrupted: {', '.join(bad)} out of range")
    return meta


def _known_columns(columns: object) -> bool:
    """The built-in columns, then at most :data:`MAX_CUSTOM_METRICS` names of a run's own."""
    n = len(METRIC_COLUMNS)
    return (
        isinstance(columns, list)
        and columns[:n] == list(METRIC_COLUMNS)
        and len(columns) <= n + MAX_CUSTOM_METRICS
        and all(isinstance(c, str) for c in columns)
    )


def load_checkpoint(
    path: str | os.PathLike, template: TrainState, num_runs: int | None = None
) -> TrainState:
    """Restores a checkpoint (:mod:`jaxcart.rundir.checkpoint`) into the structure of
    ``template`` (NumPy leaves), to resume training.

    ``template`` gives the names, dtypes and per-run shapes; its leading run axis may be
    shorter than the checkpoint's ``num_runs`` (a one-run template is enough). Every header
    is checked before anything is read, and the state must be finite.

    Raises:
        RunDirError: missing, corrupted, crafted, or saved from a different structure/shape.
    """
    import jax

    from jaxcart.engine.loop import TrainState

    meta = read_checkpoint_meta(path)
    if meta["metrics_columns"] != list(metric_columns(template.config)):
        raise RunDirError(f"checkpoint {path} records other metrics than this run's config.json")
    expected = _expected_headers(template, num_runs)
    limit = files.nbytes(expected)
    what = "this version's training state"
    arrays, _ = files.load_tree(path, limit + (1 << 20), expected, what)
    tree = {"runners": template.runners, "hyperparams": template.config}
    restored = jax.tree.unflatten(jax.tree.structure(tree), [arrays[n] for n in expected])
    return TrainState(
        runners=restored["runners"],
        config=restored["hyperparams"],
        iteration=int(meta["iteration"]),
        elapsed=float(meta["elapsed"]),
        metrics={},  # in the stream (jaxcart.rundir.stream)
        chunk_size=int(meta["chunk_size"]),
    )


def _expected_headers(template: TrainState, num_runs: int | None) -> dict:
    """Names, shapes and dtypes a checkpoint of ``num_runs`` runs holds."""
    runs = num_runs if num_runs is not None else len(template.runners.diverged_at)
    return {name: ((runs, *a.shape[1:]), a.dtype) for name, a in state_arrays(template).items()}


@dataclass(frozen=True)
class CheckpointRuns:
    """What a run's checkpoint holds for reading: every run's parameters and metrics so far.

    A sweep's checkpoint (in the sweep directory) holds all combinations x seeds: run ``r``
    is combination ``r // num_seeds``, seed index ``r % num_seeds``.
    """

    params: dict  # leaves [R, ...]
    metrics: dict[str, np.ndarray]  # name -> [iteration, R]
    iteration: int
    num_iterations: int

    @property
    def note(self) -> str:
        where = f"from the checkpoint at iteration {self.iteration}/{self.num_iterations}"
        if self.iteration >= self.num_iterations:
            return f"{where}: training finished but the run stopped before writing its outputs"
        return f"{where}: the run did not finish"


def read_checkpoint_runs(
    run_dir: files.Where, info: dict | None = None, policy: str = "final", params: bool = True
) -> CheckpointRuns:
    """Reads the parameters and metrics of every run from ``RUN_DIR/checkpoint.npz`` (no
    optimizer or env state is restored), refusing crafted files: the metadata must match the
    run's ``config.json``, every array header is checked before anything is read, the whole
    file is bounded by what this config's checkpoint can hold, and parameters must be finite.
    With ``params=False`` (curves only) the parameters are neither read nor checked, so a run
    whose network's code is not imported here (:class:`~jaxcart.core.config.RecordedNetwork`)
    still plots.

    Raises:
        RunDirError: no usable checkpoint.
    """
    with files.opened(run_dir) as directory:
        info = info or read_run_config(directory)
        return _read_checkpoint_runs(directory, info, policy, params)


def _read_checkpoint_runs(
    directory: files.Dir, info: dict, policy: str, with_params: bool = True
) -> CheckpointRuns:
    config = info["config"]
    missing = f"{directory} has no {layout.PARAMS_FILE} and no {layout.CHECKPOINT_FILE}"
    path = files.verified(directory, layout.CHECKPOINT_FILE, info, missing)
    meta = read_checkpoint_meta(path)
    runs = int(info.get("num_seeds", 1)) * max(1, len(recorded_combinations(info)))
    iteration = meta.get("iteration")
    if (
        meta.get("num_runs") != runs
        or not isinstance(iteration, int)
        or not 0 <= iteration <= config.num_iterations
    ):
        raise RunDirError(f"{path} does not belong to this run's config.json")
    params_prefix = layout.CHECKPOINT_PARAMS
    if policy == "best":  # the best policies so far (keep_best)
        if not config.keep_best:
            raise RunDirError(no_best_policy(directory))
        params_prefix = layout.CHECKPOINT_BEST_PARAMS
    params = {}
    if with_params:
        headers = params_headers(config, runs, params_dtype(info))
        expected = {params_prefix + name: header for name, header in headers.items()}
        limit = 2 * _checkpoint_bytes(config, runs)  # float64 under x64
        arrays, _ = files.load_tree(path, limit, expected, exact=False)
        params = {name[len(params_prefix) :]: arrays[name] for name in expected}
    stream_path = directory / layout.METRICS_STREAM_FILE
    digest = meta.get(STREAM_DIGEST_KEY)
    streamed = read_stream(stream_path, metric_columns(config), runs, iteration, digest)
    metrics = {name: a.astype(float) for name, a in streamed.items()}
    return CheckpointRuns(files.unflatten(params), metrics, iteration, config.num_iterations)


def _checkpoint_bytes(config: PPOConfig, runs: int) -> int:
    """A generous bound on the bytes of a checkpoint of ``runs`` runs: parameters and Adam's
    two moments, per-env state and episode statistics (whatever the run's length)."""
    params = files.nbytes(params_headers(config, runs))
    per_run = config.num_envs * 256 + (1 << 14)
    return 4 * params + runs * per_run + (1 << 20)
