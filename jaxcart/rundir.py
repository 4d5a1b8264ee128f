"""Run directories: what ``python -m jaxcart.train`` writes and :func:`load_policy` reads.

Layout of ``RUN_DIR``:

- ``config.json``: the PPO config, preset, seeds, device count and package versions;
- ``metrics.csv``: one row per seed and iteration, SB3 metric names as columns;
- ``params.npz``: every seed's network parameters, arrays ``[num_seeds, ...]`` keyed by path
  (``params/actor/hidden_0/kernel``, ...);
- ``evaluation.json``: per-seed greedy evaluation in Gymnasium's CartPole-v1 (and in jaxcart).
"""

from __future__ import annotations

import csv
import json
import os
import tempfile
from importlib import metadata
from pathlib import Path

import numpy as np

from jaxcart.config import ConfigError, PPOConfig

FORMAT_VERSION = 1
CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.csv"
PARAMS_FILE = "params.npz"
EVALUATION_FILE = "evaluation.json"


class RunDirError(ValueError):
    """The directory is not a usable jaxcart run directory; the message says why."""


def package_versions() -> dict[str, str]:
    """Versions of the packages that determine a run's numbers."""
    versions = {}
    for name in ("jaxcart", "jax", "jaxlib", "flax", "optax", "distrax", "gymnasium", "numpy"):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Writes ``data`` to a temporary file beside ``path`` and renames it into place, so a
    crash mid-write never leaves a truncated ``path``."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: Path, data: dict) -> None:
    """Atomic, indented JSON."""
    atomic_write_bytes(path, (json.dumps(data, indent=2, sort_keys=False) + "\n").encode())


def flatten_params(tree: dict, prefix: str = "") -> dict[str, np.ndarray]:
    """``{"a": {"b": x}} -> {"a/b": x}``."""
    flat = {}
    for key, value in tree.items():
        name = f"{prefix}/{key}" if prefix else str(key)
        if isinstance(value, dict):
            flat.update(flatten_params(value, name))
        else:
            flat[name] = np.asarray(value)
    return flat


def unflatten_params(flat: dict[str, np.ndarray]) -> dict:
    """Inverse of :func:`flatten_params`."""
    tree: dict = {}
    for name, value in flat.items():
        node = tree
        *parents, leaf = name.split("/")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return tree


def save_params(path: Path, params: dict) -> None:
    """Saves a params tree (leaves ``[S, ...]``) to ``.npz`` atomically."""
    import io

    buf = io.BytesIO()
    np.savez(buf, **flatten_params(params))
    atomic_write_bytes(Path(path), buf.getvalue())


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
    import io

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


def load_params(run_dir: str | os.PathLike) -> dict:
    """Every seed's parameters, leaves ``[num_seeds, ...]``."""
    path = Path(run_dir) / PARAMS_FILE
    if not path.is_file() and (Path(run_dir) / "sweep.json").is_file():
        raise RunDirError(
            f"{run_dir} is a sweep: each combination is a run directory of its own, "
            f"e.g. {Path(run_dir) / 'combo-000'}"
        )
    if not path.is_file():
        raise RunDirError(
            f"{run_dir} has no {PARAMS_FILE}: the run did not finish saving parameters"
        )
    try:
        with np.load(path) as data:
            return unflatten_params({k: data[k] for k in data.files})
    except (OSError, ValueError) as exc:
        raise RunDirError(f"{path} is corrupted: {exc}") from None


def load_policy(run_dir: str | os.PathLike, seed_index: int = 0):
    """A greedy policy of one trained seed, usable in any Gymnasium loop.

    Returns:
        A callable mapping a float32 observation ``(4,)`` to an ``int`` action, or ``(N, 4)``
        to ``(N,)`` actions (plain NumPy; no JAX call per step).

    Example::

        policy = jaxcart.load_policy("runs/my-run")
        obs, _ = env.reset()
        obs, reward, terminated, truncated, _ = env.step(policy(obs))
    """
    from jaxcart.evaluate import NumpyPolicy, actor_layers

    info = read_run_config(run_dir)
    params = load_params(run_dir)
    num_seeds = int(info.get("num_seeds", 1))
    if (
        isinstance(seed_index, bool)
        or not isinstance(seed_index, (int, np.integer))
        or not 0 <= seed_index < num_seeds
    ):
        raise RunDirError(f"seed_index must be an integer in [0, {num_seeds}), got {seed_index!r}")
    kernels, biases = actor_layers(params)
    return NumpyPolicy(
        [k[seed_index] for k in kernels], [b[seed_index] for b in biases], info["config"].activation
    )
