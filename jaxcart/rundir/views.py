"""Typed reading of run directories for analysis: a run's curves (``metrics.csv``, or its
checkpoint while unfinished), its evaluation and its labels; a sweep stands for its
combinations."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxcart.core.config import RecordedNetwork
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.checkpoint import read_checkpoint_runs
from jaxcart.rundir.files import RunDirError

ELAPSED_METRIC = "time/elapsed"


@dataclass(frozen=True)
class RunCurves:
    """One run directory's curves: metric leaves ``[iterations, num_seeds]``."""

    path: Path
    label: str
    metrics: dict[str, np.ndarray]
    env_steps: np.ndarray  # [iterations], env steps per seed
    elapsed: np.ndarray | None  # [iterations] seconds of training, None if not recorded
    num_seeds: int
    evaluation: dict | None  # evaluation.json, None if missing
    combination: dict[str, float] | None = None  # a sweep's combination: its swept values
    note: str | None = None  # "from the checkpoint at iteration 12/40: ..." when unfinished
    custom_metrics: tuple[str, ...] = ()  # the run's own metrics (config.json's names)
    env: str = DEFAULT_ENV  # the env it trained on (config.json's env)


def unfinished(run_dir: files.Where) -> bool:
    """A run (or sweep) that did not write its outputs but has a checkpoint to plot from."""
    with files.opened(run_dir) as directory:
        done = layout.SWEEP_FILE if reader.is_sweep(directory) else layout.PARAMS_FILE
        return not files.present(directory / done) and files.present(
            directory / layout.CHECKPOINT_FILE
        )


def started(run_dir: Path) -> bool:
    """Whether a run has trained (or is training): it has outputs or a checkpoint."""
    names = (layout.METRICS_FILE, layout.SWEEP_FILE, layout.CHECKPOINT_FILE)
    return any(files.present(run_dir / name) for name in names)


def load_run(run_dir: str | os.PathLike, label: str | None = None) -> RunCurves:
    """Reads a run directory's config, metrics and evaluation; a run that did not finish,
    its metrics so far from its checkpoint (:attr:`RunCurves.note` says so); an evaluation
    (``python -m jaxcart.evaluate --out``), its evaluation alone (no curves). The directory
    is opened once and every file read through it (:func:`jaxcart.rundir.files.opened`).

    Raises:
        RunDirError: ``run_dir`` is not a jaxcart run directory, or its
            ``metrics.csv`` is missing or unreadable.
    """
    path = Path(run_dir)
    with files.opened(path) as directory:
        info = reader.read_run_config(directory)
        if unfinished(directory):
            labels = [label] if label is not None else None
            return checkpoint_curves(path, info, labels, directory)[0]
        trained = not reader.is_evaluation(info)
        if trained and not files.present(directory / layout.METRICS_FILE):
            raise RunDirError(
                f"{path} has no {layout.METRICS_FILE} and no {layout.CHECKPOINT_FILE}: the run "
                "never started training"
            )
        # an evaluation's curves are its run's: none here, as for a run that logged none
        metrics = reader.read_run_metrics(directory, info) if trained else {}
        evaluation = None
        if files.present(directory / layout.EVALUATION_FILE):
            evaluation = reader.read_evaluation(directory, int(info.get("num_seeds", 1)))
    if trained and "env_steps" not in metrics:
        raise RunDirError(f"{path / layout.METRICS_FILE} has no env_steps column")
    env_steps = _first_finite(metrics["env_steps"]) if trained else np.empty(0)
    elapsed = _first_finite(metrics[ELAPSED_METRIC]) if ELAPSED_METRIC in metrics else None
    num_seeds = next(iter(metrics.values())).shape[1] if trained else 1
    combination = info.get("combination") or None
    if label is None:
        label = combination_label(combination) if combination else default_label(path, info)
    return RunCurves(
        path=path,
        label=label,
        metrics=metrics,
        env_steps=env_steps,
        elapsed=elapsed,
        num_seeds=int(info.get("num_seeds", num_seeds)),
        evaluation=evaluation,
        combination=combination,
        custom_metrics=info["config"].metric_names,
        env=info["config"].env,
    )


def checkpoint_curves(
    path: Path,
    info: dict,
    labels: Sequence[str] | None = None,
    directory: files.Dir | None = None,
) -> list[RunCurves]:
    """The curves so far of an unfinished run, or of each combination of an unfinished sweep
    (whose checkpoint holds every combination x seed), from ``checkpoint.npz``.

    Raises:
        RunDirError: no usable checkpoint, or no iteration finished yet.
    """
    # a network recorded as data has no shapes to check its parameters against: curves only
    known = not isinstance(info["config"].network, RecordedNetwork)
    saved = read_checkpoint_runs(directory or path, info, params=known)
    if saved.iteration == 0:
        raise RunDirError(f"{path}: {saved.note} (no iteration finished yet: no curves)")
    config, num_seeds = info["config"], int(info.get("num_seeds", 1))
    env_steps = np.arange(1, saved.iteration + 1) * config.batch_size
    elapsed = saved.metrics.get(ELAPSED_METRIC)
    combos = reader.recorded_combinations(info) or [None]
    runs = []
    for c, combination in enumerate(combos):
        metrics = {k: v[:, c * num_seeds : (c + 1) * num_seeds] for k, v in saved.metrics.items()}
        label = labels[c] if labels is not None else None
        if label is None:
            label = combination_label(combination) if combination else default_label(path, info)
        runs.append(
            RunCurves(
                path=path,
                label=label,
                metrics=metrics,
                env_steps=env_steps,
                elapsed=None if elapsed is None else _first_finite(elapsed),
                num_seeds=num_seeds,
                evaluation=None,
                combination=combination,
                note=saved.note,
                custom_metrics=config.metric_names,
                env=config.env,
            )
        )
    return runs


def default_label(path: Path, info: dict | None = None) -> str:
    """The run directory's name (``runs/sb3-x/`` and ``.`` resolve to a real name), with the
    physics its ``config.json`` records when they are not CartPole-v1's:
    ``short-pole (length=0.25)``, ``rand (length~U[0.5,1.5])``."""
    name = path.resolve().name or str(path)
    physics = physics_label(info or {})
    return f"{name} ({physics})" if physics else name


def physics_label(info: dict) -> str:
    """A run's physics from its ``config.json``: ``length=0.25,masspole~U[0.05,0.2]``
    (``""`` for CartPole-v1's)."""
    parts = [
        f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}"
        for k, v in (info.get("env_params") or {}).items()
    ]
    parts += [
        f"{k}~U[{r['low']:g},{r['high']:g}]" + ("/episode" if r.get("per") == "episode" else "")
        for k, r in (info.get("randomize") or {}).items()
    ]
    return ",".join(parts)


def combination_label(combination: dict[str, float]) -> str:
    """``{"learning_rate": 0.001, "clip_coef": 0.2}`` -> ``learning_rate=0.001,clip_coef=0.2``."""
    return ",".join(f"{name}={value:g}" for name, value in combination.items())


def load_runs(
    run_dirs: Sequence[str | os.PathLike], labels: Sequence[str] | None = None
) -> list[RunCurves]:
    """Loads run directories, a sweep directory standing for its combinations.

    Args:
        run_dirs: run or sweep directories.
        labels: one per entry of ``run_dirs`` (default: directory names, and a combination's
            hyperparameter values); a sweep's label prefixes its combinations' labels.

    Raises:
        RunDirError: a path is not a usable run directory.
    """
    runs: list[RunCurves] = []
    for i, path in enumerate(Path(p) for p in run_dirs):
        label = labels[i] if labels is not None else None
        if layout.is_groups(path):  # a structural sweep: every group's runs, labelled by it
            groups = [(name, group) for name, group in reader.read_groups(path) if started(group)]
            if not groups:
                raise RunDirError(
                    f"{path}: no shape group has trained yet; python -m jaxcart.train --resume "
                    f"{path} trains them"
                )
            for name, group in groups:
                prefix = name if label is None else f"{label} {name}"
                runs += load_runs([group], [prefix])
        elif layout.is_sweep(path):
            reader.read_run_config(path)  # a clear error for a broken sweep
            for combo in reader.combo_dirs(path):
                run = load_run(combo)
                runs.append(run if label is None else _prefixed(run, label))
        elif (info := reader.read_run_config(path)).get("combinations") and unfinished(path):
            combos = checkpoint_curves(path, info)  # an unfinished sweep: no combo-NNN/ yet
            runs += combos if label is None else [_prefixed(run, label) for run in combos]
        else:
            runs.append(load_run(path, label))
    if labels is None:
        _disambiguate(runs)
    return runs


def _prefixed(run: RunCurves, prefix: str) -> RunCurves:
    return dataclasses.replace(run, label=f"{prefix} {run.label}")


def _first_finite(values: np.ndarray) -> np.ndarray:
    """``[iterations, S] -> [iterations]``: the first finite value across seeds (these columns
    are the same for every seed)."""
    values = np.asarray(values, float)
    finite = np.isfinite(values)
    first = np.argmax(finite, axis=1)
    out = values[np.arange(values.shape[0]), first]
    return np.where(finite.any(axis=1), out, np.nan)


def _disambiguate(runs: list[RunCurves]) -> None:
    """Runs that share a label are labelled ``parent/label`` instead: ``parent/name`` for
    run directories, ``sweep/values`` for sweeps' combinations."""
    names = [r.label for r in runs]
    for i, run in enumerate(runs):
        if names.count(run.label) > 1:
            resolved = run.path.resolve()
            if run.combination:  # combo-NNN/ of a sweep, or an unfinished sweep itself
                sweep = resolved.parent if resolved.name.startswith("combo-") else resolved
                label = f"{sweep.name}/{run.label}"
            else:
                label = f"{resolved.parent.name}/{resolved.name}"
            runs[i] = dataclasses.replace(run, label=label)
