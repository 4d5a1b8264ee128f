"""The one reader of run directories' contents: every command and the library read a run's
files through here (plot, compare, evaluate, ``load_policy`` and resume), so that what is
checked before anything is trusted is checked in one place.

A run directory may come from anyone. What the store (:mod:`jaxcart.rundir.files`)
guarantees for every file (no link followed, regular files only, bounded reads, the digest
the manifest records) is not checked again here; what is checked here is the sense of what
the files hold: ``config.json``'s fields, metrics within what training can produce,
evaluation returns within the env's, arrays of the shapes this run's network has, a
checkpoint that belongs to this run. Every way a file can be wrong is one
:class:`~jaxcart.rundir.files.RunDirError` that says which file and why.

The curves of a run (:func:`load_run`, :func:`load_runs`: ``metrics.csv``, or its checkpoint
while unfinished, with its evaluation and labels; a sweep standing for its combinations) are
what plot and compare read.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import itertools
import math
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxcart.core import envs, physics, pytree
from jaxcart.core.config import (
    MAX_CUSTOM_METRICS,
    ConfigError,
    PPOConfig,
    RecordedNetwork,
    recorded_code,
    untrusted_code,
)
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.networks import ActorCritic, param_shapes
from jaxcart.core.solved import EPISODE_LIMITS, is_solved, return_bounds
from jaxcart.engine.loop import METRIC_COLUMNS, TrainState, metric_columns
from jaxcart.rundir import files, layout
from jaxcart.rundir.files import MAX_JSON_BYTES, RunDirError, read_json

EVAL_JSON_BYTES_PER_EPISODE = 64  # two returns per episode, as JSON, with room to spare
EVAL_JSON_BYTES_PER_SEED = 1024  # a seed's entry besides its returns
MAX_CSV_BYTES_PER_ROW = 4096
FLOAT32_MAX = float(np.finfo(np.float32).max)
X64_KEY = "x64"
"""Of ``config.json``: true when the run trained in float64 (``JAX_ENABLE_X64=1``)."""
MAX_RUNS = 1 << 20
"""The most runs (seeds x combinations) a ``config.json`` may declare."""
MAX_EVAL_EPISODES = 100_000
"""The most evaluation episodes per seed a run directory may declare."""
RUN_INTS = {
    "num_seeds": (1, MAX_RUNS),
    "seed": (0, 2**32 - 1),
    "wave_size": (1, MAX_RUNS),
    "eval_episodes": (1, MAX_EVAL_EPISODES),
    "device_count": (1, 1 << 16),
}
"""The integers of ``config.json`` and their bounds (``wave_size`` and ``eval_episodes`` may
be null)."""
MAX_ELAPSED = 1e10
"""Seconds of training a checkpoint may declare (three centuries)."""
MAX_CHUNK = 1 << 20
"""The most iterations a checkpoint's chunk may declare: the compiled chunk scans an int32
iteration counter and builds ``[chunk_size, R]`` metrics, so a larger one could overflow or
exhaust memory in the compiled call (the trainer also caps it at the run's iterations)."""
ELAPSED_METRIC = "time/elapsed"


# ---- config.json ----


def read_run_config(run_dir: files.Where, verify: bool = False) -> dict:
    """The run's ``config.json`` (:func:`~jaxcart.rundir.files.read_config`) as a dict
    (``config`` a :class:`PPOConfig`), with a clear error when it does not hold what a run's
    config holds; with ``verify`` (a resume), its digest must match its contents."""
    data = files.read_config(run_dir, verify)
    try:
        data["config"] = PPOConfig.from_dict(data["config"])
        _check_run_fields(data)
    except (KeyError, TypeError, ValueError, OverflowError, ConfigError) as exc:
        raise RunDirError(
            f"{Path(str(run_dir)) / layout.CONFIG_FILE} is corrupted or from an incompatible "
            f"version: {exc}"
        ) from None
    return data


def bounded_int(value: object, low: int, high: int) -> bool:
    """Whether ``value`` is an integer (not a bool; a NumPy one too) in ``[low, high]``."""
    integer = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    return integer and low <= value <= high


def finite_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _mapping(value: object, check: Callable[[object], bool] = finite_number) -> bool:
    """Whether ``value`` is a ``{name: value}`` object whose every value passes ``check``
    (a finite number by default)."""
    return isinstance(value, dict) and all(
        isinstance(k, str) and check(v) for k, v in value.items()
    )


def _string(value: object) -> bool:
    return isinstance(value, str)


def _failed(checks: dict[str, bool]) -> str:
    """The names of the ``checks`` that failed, comma-separated (``""``: none did)."""
    return ", ".join(name for name, ok in checks.items() if not ok)


def check_num_runs(num_seeds: int, num_combos: int) -> None:
    """Raises :class:`ConfigError` (a ValueError) when ``num_seeds`` x ``num_combos`` (0 or 1:
    no sweep) runs are more than :data:`MAX_RUNS`: the one bound of a run directory, for a new
    run as for one read back, checked before any list of runs is built."""
    if num_seeds * max(1, num_combos) > MAX_RUNS:
        what = f" x {num_combos:,} combinations" if num_combos > 1 else ""
        raise ConfigError(
            f"num_seeds: {num_seeds:,} seeds{what} is over the {MAX_RUNS:,} runs a run "
            "directory holds; train fewer",
            option="num_seeds",
        )


def _check_run_fields(data: dict) -> None:
    defaults = {"num_seeds": 1, "seed": 0, "device_count": 1}
    for name, (low, high) in RUN_INTS.items():
        value = data.get(name, defaults.get(name))
        if not (bounded_int(value, low, high) or (value is None and name not in defaults)):
            raise ValueError(f"{name} {value!r:.40} (in [{low:,}, {high:,}])")
    preset, versions = data.get("preset", ""), data.get("versions", {})
    sweep, combination = data.get("sweep", {}), data.get("combination") or {}
    source = data.get(layout.EVALUATION_OF_KEY)
    checks = {
        "preset": isinstance(preset, str) and len(preset) <= 256,
        X64_KEY: isinstance(data.get(X64_KEY, False), bool),
        "versions": _mapping(versions, _string),
        "sweep": _mapping(sweep, lambda v: isinstance(v, list) and all(map(finite_number, v))),
        "combination": _mapping(combination),
        layout.EVALUATION_OF_KEY: source is None
        or (isinstance(source, dict) and isinstance(source.get("run"), str)),
    }
    if bad := _failed(checks):
        raise ValueError(f"{bad} not what a run records")
    num_seeds = data.get("num_seeds", 1)
    check_num_runs(num_seeds, math.prod(len(v) for v in sweep.values()) if sweep else 0)
    _check_physics_fields(data)
    if not sweep and data.get("combinations"):  # explicit points (a search's trials)
        check_num_runs(num_seeds, len(recorded_combinations(data)))
        return
    derived = sweep_combinations(sweep)
    if "combinations" in data and recorded_combinations(data) != derived:  # older runs
        raise ValueError("combinations do not match the sweep")
    data["combinations"] = derived


def _check_physics_fields(data: dict) -> None:
    """``env_params`` (a {field: value} object the env's params accept), ``randomize`` and
    the physics entries of a sweep or combination, checked as a new run's are."""
    env = data.get("env_params") or {}
    if not isinstance(env, dict):
        raise ValueError("env_params is not a {field: value} object")
    dtype = params_dtype(data)  # what the run trained in
    params = physics.make_env_params(env, dtype)
    randomize = data.get("randomize") or {}
    if not isinstance(randomize, dict) or not all(
        isinstance(r, dict)
        and finite_number(r.get("low"))
        and finite_number(r.get("high"))
        and r.get("per") in ("run", "episode")
        and r["low"] <= r["high"]
        and name in physics.CONTINUOUS
        for name, r in randomize.items()
    ):
        raise ValueError("randomize is not a {field: {low, high, per}} object")
    combination = env_values(data.get("combination") or {})
    for name in (*env_values(data.get("sweep", {})), *combination):
        physics.check_continuous(name, "config.json: sweep")
    physics.check_physics(pytree.with_values(params, combination), dtype)


def is_evaluation(info: dict) -> bool:
    """Whether a ``config.json`` (read by :func:`read_run_config`) is an evaluation's
    (``python -m jaxcart.evaluate --out``): per-seed returns on other physics, no training."""
    return layout.EVALUATION_OF_KEY in info


def env_values(combination: dict) -> dict:
    """The physics entries of a combination (or of a sweep's values), without their ``env.``
    prefix: ``{"env.length": 0.25, "learning_rate": 0.001}`` -> ``{"length": 0.25}``."""
    prefix = physics.PREFIX
    return {k[len(prefix) :]: v for k, v in combination.items() if k.startswith(prefix)}


def combo_config(config: PPOConfig, combination: dict) -> PPOConfig:
    """The config of one combination of a sweep: ``config`` with the combination's values
    but its physics entries (``env.NAME``), which are not config fields."""
    fields = {k: v for k, v in combination.items() if not k.startswith(physics.PREFIX)}
    return dataclasses.replace(config, **fields)


def run_env_params(info: dict, combination: int | None = None):
    """The physics a run (or one combination of a sweep) trained on, from its ``config.json``
    (read by :func:`read_run_config`): the env's defaults, with ``env_params`` and the
    combination's ``env.NAME`` values over them. A randomised field keeps its nominal value
    (``env_params``'), which is what a randomised run is evaluated on."""
    values = dict(info.get("env_params") or {})
    values.update(env_values(info.get("combination") or {}))
    if combination is not None:
        combos = recorded_combinations(info)
        if 0 <= combination < len(combos):
            values.update(env_values(combos[combination]))
    return physics.make_env_params(values)


def sweep_combinations(sweep: dict[str, list], limit: int | None = None) -> list[dict]:
    """Every combination of a sweep's values (the first ``limit``), in ``itertools.product``
    order: the one run order of a float sweep (``config.json`` records the sweep, not its
    million combinations) and of a structural sweep's or a search space's shape groups; none
    without axes."""
    if not sweep:
        return []
    combinations = itertools.islice(itertools.product(*sweep.values()), limit)
    return [dict(zip(sweep, values)) for values in combinations]


def recorded_combinations(info: dict) -> list[dict[str, float]]:
    """A run's ``config.json`` ``combinations`` (``[]`` without a sweep), checked: a list of
    ``{name: number}``."""
    combos = info.get("combinations") or []
    if not isinstance(combos, list) or not all(map(_mapping, combos)):
        raise RunDirError("config.json is corrupted: combinations is not a list of {name: value}")
    return combos


def params_dtype(info: dict) -> np.dtype:
    """The float type a run trained in: float64 when its ``config.json`` records ``x64``."""
    return np.dtype(np.float64 if info.get(X64_KEY) else np.float32)


SHAPE_FIELDS = ("num_envs", "num_steps", "minibatch_size", "update_epochs", "hidden_sizes")
"""Settings a structural sweep groups by: each value changes the program's shapes."""
AXES_KEY = "shape_axes"
"""Of a structural sweep group's ``config.json``: the names of the sweep's shape axes."""


def group_label(values: dict) -> str:
    """Settings as a label, of a shape group, a sweep's combination or a run's physics:
    ``{"num_envs": 4, "hidden_sizes": (64, 64)}`` -> ``num_envs=4,hidden_sizes=64x64``,
    ``{"learning_rate": 0.001, "clip_coef": 0.2}`` -> ``learning_rate=0.001,clip_coef=0.2``."""

    def show(value: object) -> str:
        if isinstance(value, (tuple, list)):
            return "x".join(map(str, value))
        return f"{value:g}" if isinstance(value, float) else str(value)

    return ",".join(f"{name}={show(value)}" for name, value in values.items())


def group_values(info: dict) -> dict:
    """A shape group's values of the sweep's shape axes, from its own config (``info``, its
    ``config.json`` as read): ``{"num_envs": 4}``."""
    axes = info.get(AXES_KEY) or []
    return {name: getattr(info["config"], name) for name in SHAPE_FIELDS if name in axes}


def _run_dirs(sweep_dir: str | os.PathLike, glob: str, none: str) -> list[Path]:
    """The run directories of a sweep matching ``glob`` (``combo-NNN``, ``group-NNN``) in
    order, each refused if a link or not a directory; ``none`` says what is wrong without."""
    names = sorted(p.name for p in Path(sweep_dir).glob(glob))
    if not names or len(names) > MAX_RUNS:
        raise RunDirError(none)
    return [files.subdir(sweep_dir, name) for name in names]


def read_groups(sweep_dir: str | os.PathLike) -> list[tuple[str, Path]]:
    """A structural sweep's shape groups (its ``group-NNN/`` run directories) as ``(label,
    run directory)`` in group order, each labelled from its own ``config.json``
    (``num_envs=4,hidden_sizes=64x64``, ``SWEEP/group-000``).

    Raises:
        RunDirError: a group directory that is a link or not a run directory.
    """
    none = f"{sweep_dir} is not a structural sweep: no group-000/"
    paths = _run_dirs(sweep_dir, layout.GROUP_GLOB, none)
    return [(group_label(group_values(read_run_config(p))) or p.name, p) for p in paths]


def combo_dirs(sweep_dir: str | os.PathLike) -> list[Path]:
    """The run directories of a sweep's combinations, in combination order.

    Raises:
        RunDirError: the sweep holds none.
    """
    none = f"{sweep_dir} is a sweep without combination directories (combo-000/, ...)"
    return _run_dirs(sweep_dir, layout.COMBO_GLOB, none)


def is_sweep(run_dir: files.Where) -> bool:
    """Whether ``run_dir`` (a path, or a directory opened once) is a sweep: its combinations
    are run directories of their own."""
    directory = run_dir if isinstance(run_dir, files.Dir) else Path(run_dir)
    sweep = files.present(directory / layout.SWEEP_FILE)
    return sweep and not files.present(directory / layout.PARAMS_FILE)


def is_groups(run_dir: str | os.PathLike) -> bool:
    """Whether ``run_dir`` is a structural sweep: shape groups, each a run directory."""
    return files.present(layout.group_dir(run_dir, 0))


# ---- metrics.csv and evaluation.json ----


def read_metrics_csv(
    path: files.Target, max_rows: int | None = None, shape: tuple[int, int] | None = None
) -> dict[str, np.ndarray]:
    """Reads ``metrics.csv`` (:mod:`jaxcart.rundir.directory`) back into leaves
    ``[iterations, S]``.

    ``max_rows`` (seeds x iterations, from the run's config) bounds what is read, and
    ``shape`` (iterations, seeds) the indices of its rows: nothing is allocated from a
    number in the file itself.
    """
    limit = MAX_JSON_BYTES * 64 if max_rows is None else (max_rows + 1) * MAX_CSV_BYTES_PER_ROW
    text = files.read_bytes(path, limit)
    seed_column, iteration_column, _ = layout.METRICS_INDEX_COLUMNS
    try:
        rows = list(csv.DictReader(io.StringIO(text.decode(), newline="")))
        if not rows:
            raise RunDirError(f"{path} has no rows")
        seeds = np.array([int(r[seed_column]) for r in rows])
        iterations = np.array([int(r[iteration_column]) for r in rows])
        max_iterations, num_seeds = shape or (iterations.max(), seeds.max() + 1)
        if (
            seeds.min() < 0
            or iterations.min() < 1
            or seeds.max() >= num_seeds
            or iterations.max() > max_iterations
            or len(rows) > (max_rows or len(rows))
        ):
            raise RunDirError(
                f"{path} has rows out of range (seed_index in [0, {num_seeds}), "
                f"iteration in [1, {max_iterations}])"
            )
        out: dict[str, np.ndarray] = {}
        for name in rows[0]:
            if name in (seed_column, iteration_column):
                continue
            arr = np.full((iterations.max(), seeds.max() + 1), np.nan)
            arr[iterations - 1, seeds] = [float(r[name]) for r in rows]
            out[name] = arr
    except (KeyError, ValueError, TypeError, csv.Error, UnicodeDecodeError) as exc:
        raise RunDirError(f"{path} is corrupted: {exc}") from None
    return out


def read_run_metrics(run_dir: files.Where, info: dict) -> dict[str, np.ndarray]:
    """A run's ``metrics.csv``, bounded by the seeds x iterations its ``info`` (its
    ``config.json``) trains; leaves ``[iterations, S]``."""
    num_seeds, iterations = int(info.get("num_seeds", 1)), info["config"].num_iterations
    with files.opened(run_dir) as directory:
        missing = (
            f"{directory} has no {layout.METRICS_FILE} and no {layout.CHECKPOINT_FILE}: the run "
            "never started training"
        )
        path = files.verified(directory, layout.METRICS_FILE, info, missing)
        metrics = read_metrics_csv(path, num_seeds * iterations, (iterations, num_seeds))
    check_metrics(metrics, path, info["config"].env)
    return metrics


METRIC_BOUNDS = {
    "train/approx_kl": (-FLOAT32_MAX, FLOAT32_MAX),
    "train/clip_fraction": (0.0, 1.0),
    "train/value_loss": (0.0, FLOAT32_MAX),
    "train/learning_rate": (0.0, FLOAT32_MAX),
    "train/explained_variance": (-FLOAT32_MAX, 1.0),
    "time/fps": (0.0, FLOAT32_MAX),
    "time/elapsed": (0.0, FLOAT32_MAX),
}
"""What each metric can hold besides the episode statistics (:func:`check_metrics`): fractions
in [0, 1], losses and rates within float32 (the stream stores float32). NaN is allowed (a
diverged run's iterations, and no finished episode yet); infinities never."""


def check_metrics(
    metrics: dict[str, np.ndarray], path: files.Target, env_id: str = DEFAULT_ENV
) -> None:
    """Refuses metrics outside what training on ``env_id`` can produce: :data:`METRIC_BOUNDS`,
    the episode statistics within ``env_id``'s returns and lengths, any other column within
    float32."""
    returns, limit = return_bounds(env_id), float(EPISODE_LIMITS[env_id])
    episodes = {"rollout/ep_rew_mean": returns, "rollout/ep_rew_max": returns}
    bounds = {**METRIC_BOUNDS, **episodes, "rollout/ep_len_mean": (0.0, limit)}
    for name, values in metrics.items():
        low, high = bounds.get(name, (-FLOAT32_MAX, FLOAT32_MAX))
        a = np.asarray(values, float)
        bad = np.isinf(a) | (a < low) | (a > high)
        if bad.any():
            raise RunDirError(
                f"{path}: {name} holds {a[bad].flat[0]!r}, outside [{low:g}, {high:g}]; refusing it"
            )


def read_evaluation(
    run_dir: files.Where, num_seeds: int | None = None, info: dict | None = None
) -> dict:
    """A run's ``evaluation.json`` (per-seed returns and solved flags), checked: one entry
    per seed (``num_seeds``, from its ``config.json``, when given), each with a finite
    ``gymnasium_mean`` and a boolean ``solved``. Its size is bounded by the seeds x episodes
    the run's ``config.json`` declares (a 100,000-seed run writes ~24 MB); ``info``: that
    config as :func:`read_run_config` read it (default: read here).
    """
    with files.opened(run_dir) as directory:
        info = read_run_config(directory) if info is None else info
        name, limit = layout.EVALUATION_FILE, _evaluation_bytes(info)
        data = read_json(directory, name, limit, verify=True, info=info)
        path = directory / name
    env_id = info["config"].env
    seeds = data.get("seeds")
    if not isinstance(seeds, list) or not all(
        isinstance(s, dict)
        and finite_number(s.get("gymnasium_mean"))
        and isinstance(s.get("solved"), bool)
        for s in seeds
    ):
        raise RunDirError(
            f"{path} is corrupted: seeds is not a list of {{gymnasium_mean, solved, ...}}"
        )
    if num_seeds is not None and len(seeds) != num_seeds:
        raise RunDirError(f"{path} holds {len(seeds)} seeds, its config.json trains {num_seeds}")
    episodes = data.get("episodes")
    if episodes is not None and not bounded_int(episodes, 1, MAX_EVAL_EPISODES):
        raise RunDirError(f"{path} is corrupted: episodes {episodes!r}")
    for s in seeds:
        problem = _seed_problem(s, episodes, env_id)
        if problem:
            raise RunDirError(
                f"{path}: seed {s.get('seed_index', '?')!r:.20} {problem}; refusing it"
            )
    solved = data.get("solved_seeds")
    if solved is not None and solved != sum(s["solved"] for s in seeds):
        raise RunDirError(f"{path}: solved_seeds {solved!r:.20} does not count the solved seeds")
    return data


def _seed_problem(seed: dict, episodes: int | None, env_id: str) -> str | None:
    """What is wrong with one seed's entry of ``evaluation.json`` (None: nothing): returns
    outside the env's [least, greatest episode return], means and minima that are not theirs,
    and a ``solved`` that is not what the returns say."""
    low, high = return_bounds(env_id)
    span = f"[{low:g}, {high:g}]"
    within = lambda values: (
        len(values) and all(finite_number(v) and low <= v <= high for v in values)
    )
    best = seed.get("best")  # the best policy's own evaluation, when the run kept one
    if isinstance(best, dict) and not finite_number(best.get("gymnasium_mean")):
        return "has a best policy without a finite gymnasium_mean"
    mean = seed["gymnasium_mean"]
    if not within([mean]):
        return f"has gymnasium_mean {mean!r:.20}, outside {span}"
    if "gymnasium_returns" not in seed:  # another library's entry: the mean and flag alone
        if seed["solved"] and not is_solved(np.array([mean]), env_id):
            return "says solved with a mean that does not solve it"
        return None
    returns = seed["gymnasium_returns"]
    if not (
        isinstance(returns, list)
        and len(returns) == (episodes or len(returns)) > 0
        and all(finite_number(v) for v in returns)
    ):
        return "has gymnasium_returns that are not a list of one number per episode"
    if not within(returns):
        return f"has returns outside {span}"
    expected = gymnasium_entry(np.asarray(returns, float), env_id)  # what its returns say
    if not math.isclose(mean, expected["gymnasium_mean"], rel_tol=1e-9, abs_tol=1e-9):
        return "has a gymnasium_mean that is not the mean of its returns"
    for name in ("gymnasium_min", "solved"):
        if seed.get(name, expected[name]) != expected[name]:
            return f"says {name}={seed[name]!r:.20} where its returns say {expected[name]}"
    jax_returns = seed.get("jaxcart_returns")
    if jax_returns is not None and not (isinstance(jax_returns, list) and within(jax_returns)):
        return f"has jaxcart_returns outside {span}"
    final = seed.get("final_ep_rew_mean")
    nan = isinstance(final, float) and math.isnan(final)
    if final is not None and not nan and not within([final]):
        return f"has final_ep_rew_mean {final!r:.20}, outside {span}"
    return None


def gymnasium_entry(returns: np.ndarray, env_id: str = DEFAULT_ENV) -> dict:
    """One seed's greedy Gymnasium episodes as ``evaluation.json`` records them: the returns
    ``[episodes]``, their mean and least, and whether they solve ``env_id`` (what every writer
    of the file records, and what its reader checks a seed's entry against)."""
    return {
        "gymnasium_returns": returns.tolist(),
        "gymnasium_mean": float(returns.mean()),
        "gymnasium_min": float(returns.min()),
        "solved": bool(is_solved(returns, env_id)),
    }


def _evaluation_bytes(info: dict) -> int:
    """The largest ``evaluation.json`` the run's ``config.json`` (``info``, read by
    :func:`read_run_config`: its numbers within the reader's bounds) allows: its declared
    seeds x episodes."""
    seeds, episodes = info.get("num_seeds", 1), info.get("eval_episodes") or 20
    per_seed = EVAL_JSON_BYTES_PER_SEED + episodes * EVAL_JSON_BYTES_PER_EPISODE
    return MAX_JSON_BYTES + seeds * per_seed


# ---- parameters, wave files and checkpoints ----


def params_headers(
    config: PPOConfig, num_seeds: int, dtype: np.dtype | type = np.float32, prefix: str = ""
) -> dict[str, files.Header]:
    """The arrays ``params.npz`` holds for this config (each name after ``prefix``):
    ``[num_seeds, ...]`` shapes; the built-in network's of ``dtype`` (float64 for a run
    trained under x64: :func:`params_dtype`), another network's as its own initialisation
    gives them."""
    obs_dim = envs.make(config.env).obs_dim
    if isinstance(config.network, RecordedNetwork):  # its shapes need its code
        raise untrusted_code(recorded_code(config))
    is_shape = lambda x: isinstance(x, tuple)
    if config.network is None:
        network = ActorCritic.from_config(config)
        shapes = files.flatten(network.shapes(obs_dim), is_leaf=is_shape)
        leaves = {name: (shape, np.dtype(dtype)) for name, shape in shapes.items()}
    else:
        leaves = files.flatten(param_shapes(config.network, obs_dim), is_leaf=is_shape)
    return {prefix + name: ((num_seeds, *shape), dt) for name, (shape, dt) in leaves.items()}


def load_params(run_dir: files.Where, policy: str = "final", info: dict | None = None) -> dict:
    """Every seed's parameters from ``params.npz`` (``policy="best"``: the best policies of
    the periodic evaluation, ``params_best.npz``), leaves ``[num_seeds, ...]``. ``info`` is
    the run's config as already read (its network resolved: :func:`resolve_code`)."""
    name = policy_file(policy)
    with files.opened(run_dir) as directory:
        info = info or read_run_config(directory)
        missing = f"{directory} has no {name}: the run did not finish saving parameters"
        if policy == "best" and not info["config"].keep_best:
            missing = no_best_policy(directory)
        path = files.verified(directory, name, info, missing)
        expected = params_headers(info["config"], int(info.get("num_seeds", 1)), params_dtype(info))
        arrays, _ = files.load_tree(path, 4 * files.nbytes(expected) + (1 << 16), expected)
    return files.unflatten(arrays)


def no_best_policy(run_dir: files.Where) -> str:
    """What to say of a run asked for a best policy it never kept."""
    return (
        f"{run_dir}: no best policy was kept (train with --eval-every N --keep-best); "
        "use its final policy (--policy final)"
    )


def policy_file(policy: str) -> str:
    """The file of ``policy``: ``final`` (params.npz) or ``best`` (params_best.npz).

    Raises:
        RunDirError: another name.
    """
    if policy not in layout.POLICY_FILES:
        raise RunDirError(f"policy must be 'final' or 'best', got {policy!r}")
    return layout.POLICY_FILES[policy]


def check_block(
    path: Path, config: PPOConfig, runs: range, episodes: int, dtype: np.dtype | type = np.float32
) -> None:
    """Refuses a wave file (:class:`~jaxcart.rundir.directory.Block`) that is not the one
    this run wrote for ``runs``: its headers (parameters of this network, metrics
    ``[iterations, n]``, returns ``[n, episodes]``) are checked before anything is read, then
    its digest and finite parameters.

    Raises:
        RunDirError: a link, torn, crafted, edited or of another shape.
    """
    n = len(runs)
    expected = params_headers(config, n, dtype, layout.BLOCK_PARAMS)
    fixed = {"diverged_at": (n,), "gym_returns": (n, episodes), "jax_returns": (n, episodes)}
    if config.keep_best:
        expected |= params_headers(config, n, dtype, layout.BLOCK_BEST_PARAMS)
        fixed |= {"best_gym_returns": (n, episodes), "best_iteration": (n,), "best_score": (n,)}
    expected |= {name: (shape, None) for name, shape in fixed.items()}
    params = files.nbytes(params_headers(config, n)) * (2 if config.keep_best else 1)
    metrics = (64 + len(config.extra_metric_names)) * config.num_iterations * n * 8
    limit = 2 * (params + metrics + n * (2 * episodes + 1) * 8 + (1 << 20))  # generous
    arrays, meta = files.load_tree(path, limit, expected, "this wave's results", exact=False)
    shapes = {name: a.shape for name, a in arrays.items() if name.startswith(layout.BLOCK_METRICS)}
    if any(shape != (config.num_iterations, n) for shape in shapes.values()):
        raise RunDirError(f"{path} does not hold this wave's results: metrics of another shape")
    if meta is None or (meta.get("start"), meta.get("stop")) != (runs.start, runs.stop):
        raise RunDirError(f"{path} is not the file of runs [{runs.start}, {runs.stop})")
    if meta.get(layout.DIGEST_KEY) != files.arrays_digest(arrays):
        raise RunDirError(
            f"{path} does not match its digest: edited or corrupted; delete it to "
            "train that wave again"
        )


def state_arrays(state: TrainState) -> dict[str, np.ndarray]:
    """The checkpoint entries of a state's arrays: ``state/<tree path>`` -> ``[R, ...]`` (the
    config's traced fields under ``state/hyperparams/``)."""
    tree = {"runners": state.runners, "hyperparams": state.config}
    return {layout.CHECKPOINT_STATE + k: a for k, a in files.flatten(tree).items()}


def read_checkpoint_meta(path: files.Target) -> dict:
    """The metadata of a checkpoint, with a :class:`RunDirError` if it is unreadable, of
    another format, or holds fields of the wrong type or out of range."""
    meta = files.read_meta(path)
    if meta.get("checkpoint_format") != layout.CHECKPOINT_FORMAT:
        raise RunDirError(
            f"checkpoint {path} has format {meta.get('checkpoint_format')!r:.40}, this version "
            f"reads {layout.CHECKPOINT_FORMAT}"
        )
    columns, versions = meta.get("metrics_columns"), meta.get("versions", {})
    checks = {
        "iteration": bounded_int(meta.get("iteration"), 0, 1 << 40),
        "chunk_size": bounded_int(meta.get("chunk_size"), 1, MAX_CHUNK),
        "elapsed": finite_number(meta.get("elapsed")) and 0 <= meta.get("elapsed") < MAX_ELAPSED,
        "wave": bounded_int(meta.get("wave", 0), 0, MAX_RUNS),
        "num_runs": bounded_int(meta.get("num_runs", 1), 1, MAX_RUNS),
        "versions": _mapping(versions, _string),
        # the built-in columns, then at most MAX_CUSTOM_METRICS names of a run's own
        "metrics_columns": isinstance(columns, list)
        and columns[: len(METRIC_COLUMNS)] == list(METRIC_COLUMNS)
        and len(columns) <= len(METRIC_COLUMNS) + MAX_CUSTOM_METRICS
        and all(isinstance(c, str) for c in columns),
    }
    if bad := _failed(checks):
        raise RunDirError(f"checkpoint {path} is corrupted: {bad} out of range")
    return meta


def load_checkpoint(
    path: str | os.PathLike, template: TrainState, num_runs: int | None = None
) -> TrainState:
    """Restores a checkpoint into the structure of ``template`` (NumPy leaves), to resume
    training.

    ``template`` gives the names, dtypes and per-run shapes; its leading run axis may be
    shorter than the checkpoint's ``num_runs`` (a one-run template is enough). Every header
    is checked before anything is read, and the state must be finite.

    Raises:
        RunDirError: missing, corrupted, crafted, or saved from a different structure/shape.
    """
    import jax

    meta = read_checkpoint_meta(path)
    if meta["metrics_columns"] != list(metric_columns(template.config)):
        raise RunDirError(f"checkpoint {path} records other metrics than this run's config.json")
    runs = num_runs if num_runs is not None else len(template.runners.diverged_at)
    expected = {k: ((runs, *a.shape[1:]), a.dtype) for k, a in state_arrays(template).items()}
    what = "this version's training state"
    arrays, _ = files.load_tree(path, files.nbytes(expected) + (1 << 20), expected, what)
    tree = {"runners": template.runners, "hyperparams": template.config}
    restored = jax.tree.unflatten(jax.tree.structure(tree), [arrays[n] for n in expected])
    return TrainState(
        runners=restored["runners"],
        config=restored["hyperparams"],
        iteration=int(meta["iteration"]),
        elapsed=float(meta["elapsed"]),
        metrics={},  # in the stream (jaxcart.rundir.files.MetricsStream)
        chunk_size=int(meta["chunk_size"]),
    )


@dataclass(frozen=True)
class CheckpointRuns:
    """What a run's checkpoint holds for reading: every run's parameters and metrics so far.

    A sweep's checkpoint (in the sweep directory) holds all combinations x seeds: run ``r``
    is combination ``r // num_seeds``, seed index ``r % num_seeds``.
    """

    params: dict  # leaves [R, ...]
    metrics: dict[str, np.ndarray]  # name -> [iteration, R]
    iteration: int
    note: str  # "from the checkpoint at iteration 12/40: the run did not finish"


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
        RunDirError: no usable checkpoint, or ``policy`` is neither ``final`` nor ``best``.
    """
    best = policy_file(policy) == layout.PARAMS_BEST_FILE
    with files.opened(run_dir) as directory:
        info = info or read_run_config(directory)
        config = info["config"]
        missing = f"{directory} has no {layout.PARAMS_FILE} and no {layout.CHECKPOINT_FILE}"
        path = files.verified(directory, layout.CHECKPOINT_FILE, info, missing)
        meta = read_checkpoint_meta(path)
        runs = int(info.get("num_seeds", 1)) * max(1, len(recorded_combinations(info)))
        iteration = meta["iteration"]
        if meta.get("num_runs") != runs or iteration > config.num_iterations:
            raise RunDirError(f"{path} does not belong to this run's config.json")
        if best and not config.keep_best:
            raise RunDirError(no_best_policy(directory))
        # the best policies so far (keep_best), or the latest
        prefix = layout.CHECKPOINT_BEST_PARAMS if best else layout.CHECKPOINT_PARAMS
        arrays = {}
        if params:
            expected = params_headers(config, runs, params_dtype(info), prefix)
            # parameters and Adam's two moments, per-env state and episode statistics
            state = 4 * files.nbytes(params_headers(config, runs))
            limit = 2 * (state + runs * (config.num_envs * 256 + (1 << 14)) + (1 << 20))
            arrays, _ = files.load_tree(path, limit, expected, exact=False)
            arrays = {name[len(prefix) :]: arrays[name] for name in expected}
        stream = directory / layout.METRICS_STREAM_FILE
        digest = meta.get(files.STREAM_DIGEST_KEY)
        streamed = files.read_stream(stream, metric_columns(config), runs, iteration, digest)
    metrics = {name: a.astype(float) for name, a in streamed.items()}
    note = f"from the checkpoint at iteration {iteration}/{config.num_iterations}: " + (
        "training finished but the run stopped before writing its outputs"
        if iteration >= config.num_iterations
        else "the run did not finish"
    )
    return CheckpointRuns(files.unflatten(arrays), metrics, iteration, note)


# ---- curves: what plot and compare read ----


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
        done = (layout.SWEEP_FILE, layout.PARAMS_FILE)  # a finished sweep's, a finished run's
        finished = any(files.present(directory / name) for name in done)
        return not finished and files.present(directory / layout.CHECKPOINT_FILE)


def started(run_dir: Path) -> bool:
    """Whether a run has trained (or is training): it has outputs or a checkpoint."""
    names = (layout.METRICS_FILE, layout.SWEEP_FILE, layout.CHECKPOINT_FILE)
    return any(files.present(run_dir / name) for name in names)


def _curves(
    path: Path, info: dict, label: str | None, metrics: dict, **fields: object
) -> RunCurves:
    """A :class:`RunCurves` of ``metrics`` (its own ``combination`` by default), labelled
    ``label`` or by its combination's values or its directory."""
    combination = fields.setdefault("combination", info.get("combination") or None)
    if label is None:
        label = group_label(combination) if combination else default_label(path, info)
    elapsed = metrics.get(ELAPSED_METRIC)
    shape = next(iter(metrics.values())).shape[1] if metrics else 1
    return RunCurves(
        path=path,
        label=label,
        metrics=metrics,
        elapsed=None if elapsed is None else _first_finite(elapsed),
        num_seeds=int(info.get("num_seeds", shape)),
        custom_metrics=info["config"].metric_names,
        env=info["config"].env,
        **fields,
    )


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
        info = read_run_config(directory)
        if unfinished(directory):
            return checkpoint_curves(path, info, label, directory)[0]
        trained = not is_evaluation(info)
        # an evaluation's curves are its run's: none here, as for a run that logged none
        metrics = read_run_metrics(directory, info) if trained else {}
        evaluation = None
        if files.present(directory / layout.EVALUATION_FILE):
            evaluation = read_evaluation(directory, int(info.get("num_seeds", 1)), info)
    if trained and "env_steps" not in metrics:
        raise RunDirError(f"{path / layout.METRICS_FILE} has no env_steps column")
    env_steps = _first_finite(metrics["env_steps"]) if trained else np.empty(0)
    return _curves(path, info, label, metrics, env_steps=env_steps, evaluation=evaluation)


def checkpoint_curves(
    path: Path,
    info: dict,
    label: str | None = None,
    directory: files.Dir | None = None,
) -> list[RunCurves]:
    """The curves so far of an unfinished run, or of each combination of an unfinished sweep
    (whose checkpoint holds every combination x seed), from ``checkpoint.npz``; labelled
    ``label`` when given (else by :func:`_curves`).

    Raises:
        RunDirError: no usable checkpoint, or no iteration finished yet.
    """
    # a network recorded as data has no shapes to check its parameters against: curves only
    known = not isinstance(info["config"].network, RecordedNetwork)
    saved = read_checkpoint_runs(directory or path, info, params=known)
    if saved.iteration == 0:
        raise RunDirError(f"{path}: {saved.note} (no iteration finished yet: no curves)")
    num_seeds = int(info.get("num_seeds", 1))
    env_steps = np.arange(1, saved.iteration + 1) * info["config"].batch_size
    return [
        _curves(
            path,
            info,
            label,
            {k: v[:, c * num_seeds : (c + 1) * num_seeds] for k, v in saved.metrics.items()},
            env_steps=env_steps,
            evaluation=None,
            combination=combination,
            note=saved.note,
        )
        for c, combination in enumerate(recorded_combinations(info) or [None])
    ]


def default_label(path: Path, info: dict | None = None) -> str:
    """The run directory's name (``runs/sb3-x/`` and ``.`` resolve to a real name), with the
    physics its ``config.json`` records when they are not the env's defaults:
    ``short-pole (length=0.25)``, ``rand (length~U[0.5,1.5])``."""
    name = path.resolve().name or str(path)
    physics = physics_label(info or {})
    return f"{name} ({physics})" if physics else name


def physics_label(info: dict) -> str:
    """A run's physics from its ``config.json``: ``length=0.25,masspole~U[0.05,0.2]``
    (``""`` for the env's defaults)."""
    parts = [group_label(info.get("env_params") or {})]
    parts += [
        f"{k}~U[{r['low']:g},{r['high']:g}]" + ("/episode" if r.get("per") == "episode" else "")
        for k, r in (info.get("randomize") or {}).items()
    ]
    return ",".join(filter(None, parts))


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
        if is_groups(path):  # a structural sweep: every group's runs, labelled by it
            groups = [(name, group) for name, group in read_groups(path) if started(group)]
            if not groups:
                raise RunDirError(
                    f"{path}: no shape group has trained yet; python -m jaxcart.train --resume "
                    f"{path} trains them"
                )
            for name, group in groups:
                runs += load_runs([group], [name if label is None else f"{label} {name}"])
        elif is_sweep(path):
            read_run_config(path)  # a clear error for a broken sweep
            runs += _prefixed((load_run(combo) for combo in combo_dirs(path)), label)
        elif (info := read_run_config(path)).get("combinations") and unfinished(path):
            runs += _prefixed(checkpoint_curves(path, info), label)  # an unfinished sweep
        else:
            runs.append(load_run(path, label))
    if labels is None:
        _disambiguate(runs)
    return runs


def _prefixed(runs: Iterable[RunCurves], prefix: str | None) -> list[RunCurves]:
    """``runs`` with ``prefix`` (when given) before each label."""
    return [
        r if prefix is None else dataclasses.replace(r, label=f"{prefix} {r.label}") for r in runs
    ]


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
