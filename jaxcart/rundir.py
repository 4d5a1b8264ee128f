"""Run directories: what ``python -m jaxcart.train`` writes and the other commands read.

Layout of ``RUN_DIR``:

- ``config.json``: the PPO config, preset, seeds, device count and package versions;
- ``metrics.csv``: one row per seed and iteration, SB3 metric names as columns;
- ``params.npz``: every seed's network parameters, a tree file (:mod:`jaxcart.files`) with
  arrays ``[num_seeds, ...]`` keyed by path (``params/actor/hidden_0/kernel``, ...);
- ``evaluation.json``: per-seed greedy evaluation in Gymnasium's CartPole-v1 (and in jaxcart);
- ``checkpoint.npz``: the full training state while a run is unfinished
  (:mod:`jaxcart.checkpoint`);
- a sweep's directory holds ``config.json``, ``sweep.json`` and one run directory per
  combination, ``combo-000``, ``combo-001``, ...
"""

from __future__ import annotations

import csv
import io
import json
import os
from importlib import metadata
from pathlib import Path

import numpy as np

from jaxcart import files
from jaxcart.config import ConfigError, PPOConfig
from jaxcart.files import RunDirError, atomic_write_bytes, write_json

FORMAT_VERSION = 1
CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.csv"
PARAMS_FILE = "params.npz"
EVALUATION_FILE = "evaluation.json"
SWEEP_FILE = "sweep.json"


def combo_dir(sweep_dir: Path, combo: int) -> Path:
    """The run directory of one combination of a sweep."""
    return Path(sweep_dir) / f"combo-{combo:03d}"


def package_versions() -> dict[str, str]:
    """Versions of the packages that determine a run's numbers."""
    versions = {}
    for name in ("jaxcart", "jax", "jaxlib", "flax", "optax", "distrax", "gymnasium", "numpy"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def save_params(path: str | os.PathLike, params: dict) -> None:
    """Saves a params tree (leaves ``[S, ...]``) as a tree file, atomically."""
    files.save_tree(path, files.flatten(params))


def write_metrics_csv(path: Path, metrics: dict[str, np.ndarray], batch_size: int) -> None:
    """Rows ``seed_index, iteration, env_steps, <metrics...>`` from leaves ``[iterations, S]``."""
    names = list(metrics)
    iterations, num_seeds = next(iter(metrics.values())).shape[:2]
    lines = []
    for s in range(num_seeds):
        for i in range(iterations):
            row = [s, i + 1, (i + 1) * batch_size]
            row += [float(metrics[n][i, s]) for n in names]
            lines.append(row)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["seed_index", "iteration", "env_steps", *names])
    writer.writerows(lines)
    atomic_write_bytes(Path(path), out.getvalue().encode())


def read_metrics_csv(path: Path) -> dict[str, np.ndarray]:
    """Reads :func:`write_metrics_csv` output back into leaves ``[iterations, S]``."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise RunDirError(f"{path} has no rows")
    num_seeds = max(int(r["seed_index"]) for r in rows) + 1
    iterations = max(int(r["iteration"]) for r in rows)
    out: dict[str, np.ndarray] = {}
    for name in rows[0]:
        if name in ("seed_index", "iteration"):
            continue
        arr = np.full((iterations, num_seeds), np.nan)
        for r in rows:
            arr[int(r["iteration"]) - 1, int(r["seed_index"])] = float(r[name])
        out[name] = arr
    return out


def read_run_config(run_dir: str | os.PathLike) -> dict:
    """The run's ``config.json`` as a dict, with a clear error when it is not a run."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunDirError(
            f"{run_dir} is not a directory; pass the --out directory of a jaxcart run"
        )
    path = run_dir / CONFIG_FILE
    if not path.is_file():
        raise RunDirError(f"{run_dir} has no {CONFIG_FILE}: it is not a jaxcart run directory")
    try:
        data = json.loads(path.read_text())
        data["config"] = PPOConfig.from_dict(data["config"])
    except (json.JSONDecodeError, KeyError, TypeError, ConfigError) as exc:
        raise RunDirError(f"{path} is corrupted or from an incompatible version: {exc}") from None
    return data


def is_sweep(run_dir: str | os.PathLike) -> bool:
    """Whether ``run_dir`` is a sweep (its combinations are run directories of their own)."""
    return (Path(run_dir) / SWEEP_FILE).is_file() and not (Path(run_dir) / PARAMS_FILE).is_file()


def load_params(run_dir: str | os.PathLike) -> dict:
    """Every seed's parameters, leaves ``[num_seeds, ...]``."""
    path = Path(run_dir) / PARAMS_FILE
    if is_sweep(run_dir):
        raise RunDirError(
            f"{run_dir} is a sweep: each combination is a run directory of its own, "
            f"e.g. {combo_dir(Path(run_dir), 0)}"
        )
    if not path.is_file():
        raise RunDirError(
            f"{run_dir} has no {PARAMS_FILE}: the run did not finish saving parameters"
        )
    arrays, _ = files.load_tree(path)
    return files.unflatten(arrays)


__all__ = [
    "CONFIG_FILE",
    "EVALUATION_FILE",
    "METRICS_FILE",
    "PARAMS_FILE",
    "SWEEP_FILE",
    "RunDirError",
    "atomic_write_bytes",
    "combo_dir",
    "is_sweep",
    "load_params",
    "package_versions",
    "read_metrics_csv",
    "read_run_config",
    "save_params",
    "write_json",
    "write_metrics_csv",
]
