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

from jaxcart.rundir import files
from jaxcart.rundir import layout as rundir

ELAPSED_METRIC = "time/elapsed"


@dataclass(frozen=True)
class Run:
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


def unfinished(path: Path) -> bool:
    """A run (or sweep) that did not write its outputs but has a checkpoint to plot from."""
    from jaxcart.rundir.checkpoint import CHECKPOINT_FILE

    done = rundir.PARAMS_FILE if not rundir.is_sweep(path) else rundir.SWEEP_FILE
    return not (path / done).exists() and (path / CHECKPOINT_FILE).exists()


def load_run(run_dir: str | os.PathLike, label: str | None = None) -> Run:
    """Reads a run directory's config, metrics and evaluation; a run that did not finish,
    its metrics so far from its checkpoint (:attr:`Run.note` says so).

    Raises:
        rundir.RunDirError: ``run_dir`` is not a jaxcart run directory, or its
            ``metrics.csv`` is missing or unreadable.
    """
    path = Path(run_dir)
    info = rundir.read_run_config(path)
    if unfinished(path):
        return checkpoint_runs(path, info, [label] if label is not None else None)[0]
    if not (path / rundir.METRICS_FILE).exists():
        raise rundir.RunDirError(
            f"{path} has no {rundir.METRICS_FILE} and no checkpoint.npz: the run never "
            "started training"
        )
    metrics_path = files.inside(path, rundir.METRICS_FILE)
    max_rows = int(info.get("num_seeds", 1)) * info["config"].num_iterations
    metrics = rundir.read_metrics_csv(metrics_path, max_rows=max_rows)
    if "env_steps" not in metrics:
        raise rundir.RunDirError(f"{metrics_path} has no env_steps column")
    env_steps = _first_finite(metrics["env_steps"])
    if ELAPSED_METRIC in metrics:
        elapsed = _first_finite(metrics[ELAPSED_METRIC])
    elif "time/fps" in metrics:
        # Older runs: SB3's fps is env steps per seed / seconds since the start.
        elapsed = env_steps / _first_finite(metrics["time/fps"])
    else:
        elapsed = None
    evaluation = None
    if (path / rundir.EVALUATION_FILE).exists():
        evaluation = rundir.read_json(path, rundir.EVALUATION_FILE)
    num_seeds = next(iter(metrics.values())).shape[1]
    combination = info.get("combination") or None
    if label is None:
        label = combination_label(combination) if combination else default_label(path)
    return Run(
        path=path,
        label=label,
        metrics=metrics,
        env_steps=env_steps,
        elapsed=elapsed,
        num_seeds=int(info.get("num_seeds", num_seeds)),
        evaluation=evaluation,
        combination=combination,
    )


def checkpoint_runs(path: Path, info: dict, labels: Sequence[str] | None = None) -> list[Run]:
    """The curves so far of an unfinished run, or of each combination of an unfinished sweep
    (whose checkpoint holds every combination x seed), from ``checkpoint.npz``.

    Raises:
        rundir.RunDirError: no usable checkpoint, or no iteration finished yet.
    """
    from jaxcart.rundir.policy import checkpoint_runs as read_checkpoint
    from jaxcart.rundir.policy import combinations

    saved = read_checkpoint(path, info)
    if saved.iteration == 0:
        raise rundir.RunDirError(f"{path}: {saved.note} (no iteration finished yet: no curves)")
    config, num_seeds = info["config"], int(info.get("num_seeds", 1))
    env_steps = np.arange(1, saved.iteration + 1) * config.batch_size
    elapsed = saved.metrics.get(ELAPSED_METRIC)
    combos = combinations(info) or [None]
    runs = []
    for c, combination in enumerate(combos):
        metrics = {k: v[:, c * num_seeds : (c + 1) * num_seeds] for k, v in saved.metrics.items()}
        label = labels[c] if labels is not None else None
        if label is None:
            label = combination_label(combination) if combination else default_label(path)
        runs.append(
            Run(
                path=path,
                label=label,
                metrics=metrics,
                env_steps=env_steps,
                elapsed=None if elapsed is None else _first_finite(elapsed),
                num_seeds=num_seeds,
                evaluation=None,
                combination=combination,
                note=saved.note,
            )
        )
    return runs


def default_label(path: Path) -> str:
    """The run directory's name (``runs/sb3-x/`` and ``.`` resolve to a real name)."""
    return path.resolve().name or str(path)


def combination_label(combination: dict[str, float]) -> str:
    """``{"learning_rate": 0.001, "clip_coef": 0.2}`` -> ``learning_rate=0.001,clip_coef=0.2``."""
    return ",".join(f"{name}={value:g}" for name, value in combination.items())


def sweep_combinations(sweep_dir: Path) -> list[Path]:
    """The run directories of a sweep's combinations, in combination order.

    Raises:
        rundir.RunDirError: the sweep holds none.
    """
    combos = sorted(p for p in Path(sweep_dir).glob("combo-[0-9][0-9][0-9]*") if p.is_dir())
    if not combos:
        raise rundir.RunDirError(
            f"{sweep_dir} is a sweep without combination directories (combo-000/, ...)"
        )
    return combos


def load_runs(
    run_dirs: Sequence[str | os.PathLike], labels: Sequence[str] | None = None
) -> list[Run]:
    """Loads run directories, a sweep directory standing for its combinations.

    Args:
        run_dirs: run or sweep directories.
        labels: one per entry of ``run_dirs`` (default: directory names, and a combination's
            hyperparameter values); a sweep's label prefixes its combinations' labels.

    Raises:
        rundir.RunDirError: a path is not a usable run directory.
    """
    runs: list[Run] = []
    for i, path in enumerate(Path(p) for p in run_dirs):
        label = labels[i] if labels is not None else None
        if rundir.is_sweep(path):
            rundir.read_run_config(path)  # a clear error for a broken sweep
            for combo in sweep_combinations(path):
                run = load_run(combo)
                runs.append(run if label is None else _prefixed(run, label))
        elif (info := rundir.read_run_config(path)).get("combinations") and unfinished(path):
            combos = checkpoint_runs(path, info)  # an unfinished sweep: no combo-NNN/ yet
            runs += combos if label is None else [_prefixed(run, label) for run in combos]
        else:
            runs.append(load_run(path, label))
    if labels is None:
        _disambiguate(runs)
    return runs


def _prefixed(run: Run, prefix: str) -> Run:
    return dataclasses.replace(run, label=f"{prefix} {run.label}")


def _first_finite(values: np.ndarray) -> np.ndarray:
    """``[iterations, S] -> [iterations]``: the first finite value across seeds (these columns
    are the same for every seed)."""
    values = np.asarray(values, float)
    finite = np.isfinite(values)
    first = np.argmax(finite, axis=1)
    out = values[np.arange(values.shape[0]), first]
    return np.where(finite.any(axis=1), out, np.nan)


def _disambiguate(runs: list[Run]) -> None:
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
