"""Run directories: what ``python -m jaxcart.train`` writes and the other commands read.

Layout of ``RUN_DIR``:

- ``config.json``: the PPO config, preset, seeds, device count and package versions;
- ``metrics.csv``: one row per seed and iteration, SB3 metric names as columns;
- ``params.npz``: every seed's network parameters, a tree file (:mod:`jaxcart.rundir.files`) with
  arrays ``[num_seeds, ...]`` keyed by path (``params/actor/hidden_0/kernel``, ...);
- ``evaluation.json``: per-seed greedy evaluation in Gymnasium's CartPole-v1 (and in jaxcart);
- ``checkpoint.npz``: the full training state while a run is unfinished
  (:mod:`jaxcart.rundir.checkpoint`);
- a sweep's directory holds ``config.json``, ``sweep.json`` and one run directory per
  combination, ``combo-000``, ``combo-001``, ...
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path

import numpy as np

from jaxcart.core.config import ConfigError, PPOConfig
from jaxcart.core.networks import ActorCritic
from jaxcart.rundir import files
from jaxcart.rundir.files import RunDirError, atomic_write_bytes, write_json

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


def metrics_csv_header(names: list[str]) -> list[str]:
    """The columns of ``metrics.csv``."""
    return ["seed_index", "iteration", "env_steps", *names]


def metrics_csv_rows(
    metrics: dict[str, np.ndarray], batch_size: int, first_seed: int = 0, runs: slice = slice(None)
) -> Iterator[list]:
    """The rows of ``metrics.csv`` for the runs ``runs`` of metrics ``[iterations, R]``,
    numbered from ``first_seed``: seed by seed, iteration by iteration."""
    names = list(metrics)
    columns = [np.asarray(metrics[n])[:, runs] for n in names]
    iterations, num_seeds = columns[0].shape
    for s in range(num_seeds):
        for i in range(iterations):
            row = [float(c[i, s]) for c in columns]
            yield [first_seed + s, i + 1, (i + 1) * batch_size, *row]


def write_metrics_csv(path: Path, metrics: dict[str, np.ndarray], batch_size: int) -> None:
    """Rows ``seed_index, iteration, env_steps, <metrics...>`` from leaves ``[iterations, S]``."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(metrics_csv_header(list(metrics)))
    writer.writerows(metrics_csv_rows(metrics, batch_size))
    atomic_write_bytes(Path(path), out.getvalue().encode())


MAX_JSON_BYTES = 16 << 20
MAX_CSV_BYTES_PER_ROW = 4096


def read_metrics_csv(path: Path, max_rows: int | None = None) -> dict[str, np.ndarray]:
    """Reads :func:`write_metrics_csv` output back into leaves ``[iterations, S]``.

    ``max_rows`` (seeds x iterations, from the run's config) bounds what is read.
    """
    path = Path(path)
    if max_rows is not None and path.stat().st_size > (max_rows + 1) * MAX_CSV_BYTES_PER_ROW:
        raise RunDirError(f"{path} is larger than {max_rows} rows can be")
    try:
        with open(path, newline="") as f:
            rows = list(csv.DictReader(f))
        if not rows:
            raise RunDirError(f"{path} has no rows")
        seeds = np.array([int(r["seed_index"]) for r in rows])
        iterations = np.array([int(r["iteration"]) for r in rows])
        if seeds.min() < 0 or iterations.min() < 1 or len(rows) > (max_rows or len(rows)):
            raise RunDirError(f"{path} has rows out of range")
        out: dict[str, np.ndarray] = {}
        for name in rows[0]:
            if name in ("seed_index", "iteration"):
                continue
            arr = np.full((iterations.max(), seeds.max() + 1), np.nan)
            arr[iterations - 1, seeds] = [float(r[name]) for r in rows]
            out[name] = arr
    except (KeyError, ValueError, TypeError, csv.Error, UnicodeDecodeError) as exc:
        raise RunDirError(f"{path} is corrupted: {exc}") from None
    return out


def read_json(run_dir: str | os.PathLike, name: str) -> dict:
    """A JSON object from a run directory, refusing links out of it, oversized files and
    anything but an object."""
    path = files.inside(run_dir, name)
    if path.stat().st_size > MAX_JSON_BYTES:
        raise RunDirError(f"{path} is larger than any {name} jaxcart writes")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as exc:
        raise RunDirError(f"{path} is corrupted or from an incompatible version: {exc}") from None
    if not isinstance(data, dict):
        raise RunDirError(f"{path} is corrupted: not a JSON object")
    return data


def read_run_config(run_dir: str | os.PathLike) -> dict:
    """The run's ``config.json`` as a dict (``config`` a :class:`PPOConfig`), with a clear
    error when it is not a run or does not hold what a run's config holds."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise RunDirError(
            f"{run_dir} is not a directory; pass the --out directory of a jaxcart run"
        )
    if not (run_dir / CONFIG_FILE).exists():
        raise RunDirError(f"{run_dir} has no {CONFIG_FILE}: it is not a jaxcart run directory")
    data = read_json(run_dir, CONFIG_FILE)
    path = run_dir / CONFIG_FILE
    try:
        data["config"] = PPOConfig.from_dict(data["config"])
        _check_run_fields(data)
    except (KeyError, TypeError, ValueError, ConfigError) as exc:
        raise RunDirError(f"{path} is corrupted or from an incompatible version: {exc}") from None
    return data


def _check_run_fields(data: dict) -> None:
    num_seeds, seed = data.get("num_seeds", 1), data.get("seed", 0)
    if not isinstance(num_seeds, int) or isinstance(num_seeds, bool) or num_seeds < 1:
        raise ValueError(f"num_seeds {num_seeds!r}")
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**32:
        raise ValueError(f"seed {seed!r}")
    wave_size = data.get("wave_size", num_seeds)
    if not isinstance(wave_size, int) or isinstance(wave_size, bool) or wave_size < 1:
        raise ValueError(f"wave_size {wave_size!r}")
    sweep = data.get("sweep", {})
    if not isinstance(sweep, dict) or not all(
        isinstance(v, list) and all(isinstance(x, (int, float)) for x in v) for v in sweep.values()
    ):
        raise ValueError(f"sweep {sweep!r}")


def params_headers(config: PPOConfig, num_seeds: int) -> dict[str, files.Header]:
    """The arrays ``params.npz`` holds for this config: names, ``[num_seeds, ...]`` shapes."""
    network = ActorCritic.from_config(config)
    shapes = files.flatten(network.shapes(), is_leaf=lambda x: isinstance(x, tuple))
    return {name: ((num_seeds, *shape), np.dtype(np.float32)) for name, shape in shapes.items()}


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
    if not path.exists():
        raise RunDirError(
            f"{run_dir} has no {PARAMS_FILE}: the run did not finish saving parameters"
        )
    info = read_run_config(run_dir)
    expected = params_headers(info["config"], int(info.get("num_seeds", 1)))
    path = files.inside(run_dir, PARAMS_FILE)
    found = files.read_headers(path, max_bytes=4 * _bytes(expected) + (1 << 16))
    if found != expected:
        raise RunDirError(
            f"{path} does not hold this run's network: {_difference(found, expected)}"
        )
    arrays, _ = files.load_tree(path)
    files.check_finite(arrays, path)
    return files.unflatten(arrays)


def _difference(found: dict[str, files.Header], expected: dict[str, files.Header]) -> str:
    missing, extra = sorted(set(expected) - set(found)), sorted(set(found) - set(expected))
    if missing or extra:
        return f"missing {missing[:3]}, unexpected {extra[:3]}"
    name = next(n for n in expected if found[n] != expected[n])
    (shape, dtype), (want_shape, want_dtype) = found[name], expected[name]
    return f"{name} is {shape} {dtype}, expected {want_shape} {want_dtype}"


def _bytes(headers: dict[str, files.Header]) -> int:
    return sum(int(np.prod(shape)) * dtype.itemsize for shape, dtype in headers.values())


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
