"""The one reader of run directories: every command and the library read a run's files
through here (plot, compare, evaluate, ``load_policy`` and resume), so that what is checked
before anything is trusted is checked in one place.

A run directory may come from anyone: every reader refuses links out of the directory,
bounds what it reads by what the run's ``config.json`` says it can hold, checks headers
before reading arrays, and turns every way a file can be broken into one
:class:`~jaxcart.rundir.files.RunDirError` that says which file and why.
"""

from __future__ import annotations

import csv
import fnmatch
import io
import itertools
import math
import os
from pathlib import Path

import numpy as np

from jaxcart.core import envs, physics
from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import (
    ConfigError,
    PPOConfig,
    RecordedNetwork,
    recorded_code,
    untrusted_code,
)
from jaxcart.core.envs import DEFAULT_ENV
from jaxcart.core.networks import ActorCritic, param_shapes
from jaxcart.core.solved import EPISODE_LIMITS, is_solved, return_bounds
from jaxcart.rundir import files, layout
from jaxcart.rundir.files import MAX_JSON_BYTES, RunDirError, read_json

EVAL_JSON_BYTES_PER_EPISODE = 64  # two returns per episode, as JSON, with room to spare
EVAL_JSON_BYTES_PER_SEED = 1024  # a seed's entry besides its returns
MAX_CSV_BYTES_PER_ROW = 4096


MAX_RETURN = EnvParams().max_episode_steps
"""The largest episode return (and length) of CartPole-v1: one point per step, 500 steps."""
FLOAT32_MAX = float(np.finfo(np.float32).max)
X64_KEY = "x64"
"""Of ``config.json``: true when the run trained in float64 (``JAX_ENABLE_X64=1``)."""
MAX_RUNS = 1 << 20
"""The most runs (seeds x combinations) a ``config.json`` may declare."""
MAX_EVAL_EPISODES = 100_000
"""The most evaluation episodes per seed a run directory may declare."""


CLASSIFYING_FILES = (layout.SWEEP_FILE, layout.PARAMS_FILE, layout.CHECKPOINT_FILE)
"""Whether these exist says whether a directory is a sweep, a finished or an unfinished run
(:func:`~jaxcart.rundir.layout.is_sweep`): :func:`read_run_config` refuses each as a link."""


def read_run_config(run_dir: files.Where, verify: bool = False) -> dict:
    """The run's ``config.json`` as a dict (``config`` a :class:`PPOConfig`), with a clear
    error when it is not a run or does not hold what a run's config holds; with ``verify``
    (a resume), its digest must match its contents (hand edits and corruption are refused).
    """
    with files.opened(run_dir) as directory:
        return _read_run_config(directory, verify)


def _read_run_config(directory: files.Dir, verify: bool) -> dict:
    path = directory / layout.CONFIG_FILE
    if files.refuse_link(path) is None:
        names = directory.names()
        only_lock = names == [layout.LOCK_FILE]
        hint = (
            f" (only the {layout.LOCK_FILE} of a start that failed: start it again with "
            f"--out {directory}, which takes it over)"
            if only_lock
            else ""
        )
        if files.present(directory / layout.SB3_PLAN_FILE):
            # SB3's seeds are kept one by one; the run directory is written once all finish
            kept = 0
            if layout.SB3_SEEDS_DIR in names:
                seeds = directory.sub(layout.SB3_SEEDS_DIR)
                try:
                    kept = len(fnmatch.filter(seeds.names(), "seed-*.npz"))
                finally:
                    seeds.close()
            hint = (
                f" yet: it is an interrupted python -m jaxcart.sb3 run ({kept} seed(s) kept); "
                f"train the others, then plot or evaluate it: python -m jaxcart.sb3 --resume "
                f"{directory}"
            )
        raise RunDirError(
            f"{directory} has no {layout.CONFIG_FILE}: it is not a jaxcart run directory{hint}"
        )
    for name in CLASSIFYING_FILES:  # what the directory is: never decided through a link
        files.refuse_link(directory / name)
    data = read_json(directory, layout.CONFIG_FILE)
    files.verified(directory, layout.CONFIG_FILE, data)
    if verify:
        _check_digest(path, data)
    try:
        data["config"] = PPOConfig.from_dict(data["config"])
        _check_run_fields(data)
    except (KeyError, TypeError, ValueError, OverflowError, ConfigError) as exc:
        raise RunDirError(f"{path} is corrupted or from an incompatible version: {exc}") from None
    return data


def _check_digest(path: files.Target, data: dict) -> None:
    """Refuses a ``config.json`` whose digest is missing or does not match its contents."""
    if layout.DIGEST_KEY not in data:
        raise RunDirError(
            f"{path} has no digest: it was not written by this version of jaxcart, or was "
            "rewritten by hand; a run continues only with the settings it started with"
        )
    body = {k: v for k, v in data.items() if k != layout.DIGEST_KEY}
    if data[layout.DIGEST_KEY] != files.json_digest(body):
        raise RunDirError(
            f"{path} does not match its digest: it was edited or corrupted after the run "
            "wrote it; restore it (a run continues only with the settings it started with)"
        )


def bounded_int(value: object, low: int, high: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


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
    num_seeds, seed = data.get("num_seeds", 1), data.get("seed", 0)
    if not bounded_int(num_seeds, 1, MAX_RUNS):
        raise ValueError(f"num_seeds {num_seeds!r}")
    if not bounded_int(seed, 0, 2**32 - 1):
        raise ValueError(f"seed {seed!r}")
    wave_size = data.get("wave_size", num_seeds)
    if wave_size is not None and not bounded_int(wave_size, 1, MAX_RUNS):
        raise ValueError(f"wave_size {wave_size!r}")
    episodes = data.get("eval_episodes")
    if episodes is not None and not bounded_int(episodes, 1, MAX_EVAL_EPISODES):
        raise ValueError(f"eval_episodes {episodes!r} (at most {MAX_EVAL_EPISODES:,})")
    device_count = data.get("device_count", 1)
    if not bounded_int(device_count, 1, 1 << 16):
        raise ValueError(f"device_count {device_count!r}")
    preset = data.get("preset", "")
    if not isinstance(preset, str) or len(preset) > 256:
        raise ValueError(f"preset {preset!r}")
    if not isinstance(data.get(X64_KEY, False), bool):
        raise ValueError(f"{X64_KEY} {data.get(X64_KEY)!r}")
    versions = data.get("versions", {})
    if not isinstance(versions, dict) or not all(isinstance(v, str) for v in versions.values()):
        raise ValueError("versions is not a {package: version} object")
    sweep = data.get("sweep", {})
    if not isinstance(sweep, dict) or not all(
        isinstance(v, list) and all(finite_number(x) for x in v) for v in sweep.values()
    ):
        raise ValueError(f"sweep {sweep!r}")
    combination = data.get("combination") or {}
    if not isinstance(combination, dict) or not all(finite_number(v) for v in combination.values()):
        raise ValueError("combination is not a {name: value} object")
    check_num_runs(num_seeds, math.prod(len(v) for v in sweep.values()) if sweep else 0)
    _check_physics_fields(data)
    source = data.get(layout.EVALUATION_OF_KEY)
    if source is not None and not (isinstance(source, dict) and isinstance(source.get("run"), str)):
        raise ValueError(f"{layout.EVALUATION_OF_KEY} is not a {{run, ...}} object")
    if not sweep and data.get("combinations"):  # explicit points (a search's trials)
        check_num_runs(num_seeds, len(recorded_combinations(data)))
        return
    derived = sweep_combinations(sweep)
    if "combinations" in data and recorded_combinations(data) != derived:  # older runs
        raise ValueError("combinations do not match the sweep")
    data["combinations"] = derived


def _check_physics_fields(data: dict) -> None:
    """``env_params`` (a {field: value} object CartPole's params accept), ``randomize`` and the
    physics entries of a sweep or combination, checked as a new run's are."""
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
    for name in (*data.get("sweep", {}), *(data.get("combination") or {})):
        if name.startswith(physics.PREFIX):
            physics.check_continuous(name[len(physics.PREFIX) :], "config.json: sweep")
    combination = env_values(data.get("combination") or {})
    physics.check_physics(physics.with_values(params, combination), dtype)


def is_evaluation(info: dict) -> bool:
    """Whether a ``config.json`` (read by :func:`read_run_config`) is an evaluation's
    (``python -m jaxcart.evaluate --out``): per-seed returns on other physics, no training."""
    return layout.EVALUATION_OF_KEY in info


def env_values(combination: dict) -> dict:
    """The physics entries of a combination, without their ``env.`` prefix."""
    prefix = physics.PREFIX
    return {k[len(prefix) :]: v for k, v in combination.items() if k.startswith(prefix)}


def run_env_params(info: dict, combination: int | None = None) -> EnvParams:
    """The physics a run (or one combination of a sweep) trained on, from its ``config.json``
    (read by :func:`read_run_config`): CartPole-v1's, with ``env_params`` and the
    combination's ``env.NAME`` values over them. A randomised field keeps its nominal value
    (``env_params``'), which is what a randomised run is evaluated on."""
    values = dict(info.get("env_params") or {})
    values.update(env_values(info.get("combination") or {}))
    if combination is not None:
        combos = recorded_combinations(info)
        if 0 <= combination < len(combos):
            values.update(env_values(combos[combination]))
    return physics.make_env_params(values)


def sweep_combinations(sweep: dict[str, list[float]]) -> list[dict[str, float]]:
    """Every combination of a sweep's values, in ``itertools.product`` order: the one run
    order (``config.json`` records the sweep, not its million combinations)."""
    if not sweep:
        return []
    names = list(sweep)
    return [dict(zip(names, values)) for values in itertools.product(*sweep.values())]


def finite_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def recorded_combinations(info: dict) -> list[dict[str, float]]:
    """A run's ``config.json`` ``combinations`` (``[]`` without a sweep), checked: a list of
    ``{name: number}``."""
    combos = info.get("combinations") or []
    if not isinstance(combos, list) or not all(
        isinstance(c, dict) and all(isinstance(k, str) and finite_number(v) for k, v in c.items())
        for c in combos
    ):
        raise RunDirError("config.json is corrupted: combinations is not a list of {name: value}")
    return combos


SHAPE_FIELDS = ("num_envs", "num_steps", "minibatch_size", "update_epochs", "hidden_sizes")
"""Settings a structural sweep groups by: each value changes the program's shapes."""
AXES_KEY = "shape_axes"
"""Of a structural sweep group's ``config.json``: the names of the sweep's shape axes."""


def group_label(group: dict) -> str:
    """``{"num_envs": 4, "hidden_sizes": (64, 64)}`` -> ``num_envs=4,hidden_sizes=64x64``."""
    show = lambda v: "x".join(map(str, v)) if isinstance(v, (tuple, list)) else str(v)
    return ",".join(f"{name}={show(value)}" for name, value in group.items())


def group_values(info: dict) -> dict:
    """A shape group's values of the sweep's shape axes, from its own config (``info``, its
    ``config.json`` as read): ``{"num_envs": 4}``."""
    axes = info.get(AXES_KEY) or []
    return {name: getattr(info["config"], name) for name in SHAPE_FIELDS if name in axes}


def read_groups(sweep_dir: str | os.PathLike) -> list[tuple[str, Path]]:
    """A structural sweep's shape groups (its ``group-NNN/`` run directories) as ``(label,
    run directory)`` in group order, each labelled from its own ``config.json``
    (``num_envs=4,hidden_sizes=64x64``, ``SWEEP/group-000``).

    Raises:
        RunDirError: a group directory that is a link or not a run directory.
    """
    names = sorted(p.name for p in Path(sweep_dir).glob(layout.GROUP_GLOB))
    if not names or len(names) > MAX_RUNS:
        raise RunDirError(f"{sweep_dir} is not a structural sweep: no group-000/")
    out = []
    for name in names:
        path = files.subdir(sweep_dir, name)  # a link is refused
        out.append((group_label(group_values(read_run_config(path))) or name, path))
    return out


def combo_dirs(sweep_dir: str | os.PathLike) -> list[Path]:
    """The run directories of a sweep's combinations, in combination order.

    Raises:
        RunDirError: the sweep holds none.
    """
    combos = sorted(Path(sweep_dir).glob(layout.COMBO_GLOB))
    combos = [files.subdir(sweep_dir, p.name) for p in combos]  # a link is refused
    if not combos:
        raise RunDirError(
            f"{sweep_dir} is a sweep without combination directories (combo-000/, ...)"
        )
    return combos


def read_metrics_csv(
    path: files.Target, max_rows: int | None = None, shape: tuple[int, int] | None = None
) -> dict[str, np.ndarray]:
    """Reads ``metrics.csv`` (:mod:`jaxcart.rundir.outputs`) back into leaves
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
        path = files.verified(directory, layout.METRICS_FILE, info)
        metrics = read_metrics_csv(path, num_seeds * iterations, (iterations, num_seeds))
    check_metrics(metrics, path, info["config"].env)
    return metrics


METRIC_BOUNDS = {
    "rollout/ep_rew_mean": (0.0, MAX_RETURN),
    "rollout/ep_len_mean": (0.0, MAX_RETURN),
    "rollout/ep_rew_max": (0.0, MAX_RETURN),
    "train/approx_kl": (-FLOAT32_MAX, FLOAT32_MAX),
    "train/clip_fraction": (0.0, 1.0),
    "train/value_loss": (0.0, FLOAT32_MAX),
    "train/learning_rate": (0.0, FLOAT32_MAX),
    "train/explained_variance": (-FLOAT32_MAX, 1.0),
    "time/fps": (0.0, FLOAT32_MAX),
    "time/elapsed": (0.0, FLOAT32_MAX),
}
"""What each metric can hold: episode statistics within the env's returns, fractions in
[0, 1], losses and rates within float32 (the stream stores float32). NaN is allowed (a
diverged run's iterations, and no finished episode yet); infinities never."""


def metric_bounds(env_id: str = DEFAULT_ENV) -> dict[str, tuple[float, float]]:
    """:data:`METRIC_BOUNDS` with the episode statistics of ``env_id``'s returns and lengths."""
    returns, limit = return_bounds(env_id), float(EPISODE_LIMITS[env_id])
    episodes = {"rollout/ep_rew_mean": returns, "rollout/ep_rew_max": returns}
    return {**METRIC_BOUNDS, **episodes, "rollout/ep_len_mean": (0.0, limit)}


def check_metrics(
    metrics: dict[str, np.ndarray], path: files.Target, env_id: str = DEFAULT_ENV
) -> None:
    """Refuses metrics outside what training on ``env_id`` can produce
    (:func:`metric_bounds`; any other column within float32)."""
    bounds = metric_bounds(env_id)
    for name, values in metrics.items():
        low, high = bounds.get(name, (-FLOAT32_MAX, FLOAT32_MAX))
        a = np.asarray(values, float)
        bad = np.isinf(a) | (a < low) | (a > high)
        if bad.any():
            raise RunDirError(
                f"{path}: {name} holds {a[bad].flat[0]!r}, outside [{low:g}, {high:g}]; refusing it"
            )


def read_evaluation(run_dir: files.Where, num_seeds: int | None = None) -> dict:
    """A run's ``evaluation.json`` (per-seed returns and solved flags), checked: one entry
    per seed (``num_seeds``, from its ``config.json``, when given), each with a finite
    ``gymnasium_mean`` and a boolean ``solved``. Its size is bounded by the seeds x episodes
    the run's ``config.json`` declares (a 100,000-seed run writes ~24 MB).
    """
    with files.opened(run_dir) as directory:
        config = read_json(directory, layout.CONFIG_FILE)
        data = read_json(directory, layout.EVALUATION_FILE, _evaluation_bytes(config))
        path = files.verified(directory, layout.EVALUATION_FILE, config)
    env_id = _env_of(config)
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


def _return_list(values: object, episodes: int | None) -> np.ndarray | None:
    """Episode returns as an array when they are a list of numbers of the right length."""
    if not isinstance(values, list) or not all(finite_number(v) for v in values):
        return None
    if not values or (episodes is not None and len(values) != episodes):
        return None
    return np.asarray(values, float)


def _env_of(config: object) -> str:
    """The env id a raw ``config.json`` names (CartPole-v1 when it names none), or refuses it."""
    inner = config.get("config") if isinstance(config, dict) else None
    env_id = inner.get("env", DEFAULT_ENV) if isinstance(inner, dict) else DEFAULT_ENV
    if env_id not in EPISODE_LIMITS:
        raise RunDirError(f"config.json names env {env_id!r:.40}, which jaxcart does not train")
    return env_id


def _seed_problem(seed: dict, episodes: int | None, env_id: str = DEFAULT_ENV) -> str | None:
    """What is wrong with one seed's entry of ``evaluation.json`` (None: nothing): returns
    outside the env's [least, greatest episode return], means and minima that are not theirs,
    and a ``solved`` that is not what the returns say."""
    low, high = return_bounds(env_id)
    within = lambda x: low <= x <= high
    span = f"[{low:g}, {high:g}]"
    mean = seed["gymnasium_mean"]
    if not within(mean):
        return f"has gymnasium_mean {mean!r:.20}, outside {span}"
    if "gymnasium_returns" not in seed:  # another library's entry: the mean and flag alone
        return (
            "says solved with a mean under the maximum"
            if seed["solved"] and env_id == DEFAULT_ENV and mean < MAX_RETURN
            else None
        )
    returns = _return_list(seed["gymnasium_returns"], episodes)
    if returns is None:
        return "has gymnasium_returns that are not a list of one number per episode"
    if returns.min() < low or returns.max() > high:
        return f"has returns outside {span}"
    if not math.isclose(mean, float(returns.mean()), rel_tol=1e-9, abs_tol=1e-9):
        return "has a gymnasium_mean that is not the mean of its returns"
    if "gymnasium_min" in seed and seed["gymnasium_min"] != float(returns.min()):
        return "has a gymnasium_min that is not the least of its returns"
    solved = bool(is_solved(returns, env_id))
    if seed["solved"] != solved:
        return f"says solved={seed['solved']} where its returns say {solved}"
    jax_returns = seed.get("jaxcart_returns")
    if jax_returns is not None:
        values = _return_list(jax_returns, None)
        if values is None or values.min() < low or values.max() > high:
            return f"has jaxcart_returns outside {span}"
    final = seed.get("final_ep_rew_mean")
    if final is not None and not (
        isinstance(final, (int, float)) and (math.isnan(final) or within(final))
    ):
        return f"has final_ep_rew_mean {final!r:.20}, outside {span}"
    return None


def _evaluation_bytes(info: dict) -> int:
    """The largest ``evaluation.json`` the run's ``config.json`` (``info``, as read) allows:
    its declared seeds x combinations x episodes (read as declared, within the reader's
    bounds)."""
    seeds, episodes = info.get("num_seeds", 1), info.get("eval_episodes", 20)
    seeds = seeds if bounded_int(seeds, 1, MAX_RUNS) else 1
    episodes = episodes if bounded_int(episodes, 1, MAX_EVAL_EPISODES) else 20
    per_seed = EVAL_JSON_BYTES_PER_SEED + episodes * EVAL_JSON_BYTES_PER_EPISODE
    return MAX_JSON_BYTES + seeds * per_seed


def params_headers(
    config: PPOConfig, num_seeds: int, dtype: np.dtype | type = np.float32
) -> dict[str, files.Header]:
    """The arrays ``params.npz`` holds for this config: names, ``[num_seeds, ...]`` shapes; the
    built-in network's of ``dtype`` (float64 for a run trained under x64: :func:`params_dtype`),
    another network's as its own initialisation gives them."""
    obs_dim = envs.make(config.env).obs_dim
    if isinstance(config.network, RecordedNetwork):  # its shapes need its code
        raise untrusted_code(recorded_code(config))
    if config.network is None:
        network = ActorCritic.from_config(config)
        shapes = files.flatten(network.shapes(obs_dim), is_leaf=lambda x: isinstance(x, tuple))
        return {name: ((num_seeds, *shape), np.dtype(dtype)) for name, shape in shapes.items()}
    shaped = param_shapes(config.network, obs_dim)
    leaves = files.flatten(shaped, is_leaf=lambda x: isinstance(x, tuple))
    return {name: ((num_seeds, *shape), dt) for name, (shape, dt) in leaves.items()}


def params_dtype(info: dict) -> np.dtype:
    """The float type a run trained in: float64 when its ``config.json`` records ``x64``."""
    return np.dtype(np.float64 if info.get(X64_KEY) else np.float32)


def is_sweep(directory: files.Dir) -> bool:
    """:func:`jaxcart.rundir.layout.is_sweep`, through the directory's descriptor."""
    return files.present(directory / layout.SWEEP_FILE) and not files.present(
        directory / layout.PARAMS_FILE
    )


def load_params(run_dir: files.Where, policy: str = "final", info: dict | None = None) -> dict:
    """Every seed's parameters from ``params.npz`` (``policy="best"``: the best policies of
    the periodic evaluation, ``params_best.npz``), leaves ``[num_seeds, ...]``. ``info`` is
    the run's config as already read (its network resolved: :func:`resolve_code`)."""
    name = policy_file(policy)
    with files.opened(run_dir) as directory:
        if is_sweep(directory):
            raise RunDirError(
                f"{directory} is a sweep: each combination is a run directory of its own, "
                f"e.g. {layout.combo_dir(directory.path, 0)}"
            )
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
    """Refuses a wave file (:class:`~jaxcart.rundir.outputs.Block`) that is not the one this
    run wrote for ``runs``: its headers (parameters of this network, metrics
    ``[iterations, n]``, returns ``[n, episodes]``) are checked before anything is read, then
    its digest and finite parameters.

    Raises:
        RunDirError: a link, torn, crafted, edited or of another shape.
    """
    n = len(runs)
    headers = params_headers(config, n, dtype).items()
    prefixes = (layout.BLOCK_PARAMS, layout.BLOCK_BEST_PARAMS)
    expected = {
        prefix + name: header
        for prefix in prefixes[: 2 if config.keep_best else 1]
        for name, header in headers
    }
    fixed = {"diverged_at": (n,), "gym_returns": (n, episodes), "jax_returns": (n, episodes)}
    if config.keep_best:
        fixed |= {"best_gym_returns": (n, episodes), "best_iteration": (n,), "best_score": (n,)}
    expected |= {name: (shape, None) for name, shape in fixed.items()}
    limit, what = 2 * _block_bytes(config, n, episodes), "this wave's results"
    arrays, meta = files.load_tree(path, limit, expected, what, exact=False)
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


def _block_bytes(config: PPOConfig, n: int, episodes: int) -> int:
    """A generous bound on a wave file of ``n`` runs."""
    params = files.nbytes(params_headers(config, n)) * (2 if config.keep_best else 1)
    metrics = (64 + len(config.extra_metric_names)) * config.num_iterations * n * 8
    return params + metrics + n * (2 * episodes + 1) * 8 + (1 << 20)
