"""Stable-Baselines3's own PPO, trained and saved as a jaxcart run directory.

Each seed runs ``PPO("MlpPolicy", "CartPole-v1", seed=s).learn(total_timesteps)`` with SB3's
defaults (PyTorch, on the CPU). What it leaves becomes a run directory that ``plot``,
``compare``, ``evaluate`` and :func:`jaxcart.load_policy` read like one of jaxcart's:

- ``metrics.csv``: SB3's CSV log under the same metric names (SB3 dumps its log before each
  update, so the ``train/*`` values of iteration ``i`` are taken from the row after it);
- ``params.npz``: SB3's actor and critic MLPs under jaxcart's parameter names
  (:func:`sb3_params`; PyTorch's ``weight [out, in]`` is jaxcart's ``kernel [in, out]``);
- ``evaluation.json``: 20 greedy episodes per seed in Gymnasium's CartPole-v1 with SB3's own
  ``model.predict(obs, deterministic=True)``, reset seeds as jaxcart's evaluation;
- ``config.json``: the ``sb3`` preset's config (SB3's defaults), ``framework`` naming SB3.

While SB3 trains, each rollout reaches the loggers and the seed's progress bar as SB3 logs it
(:class:`LiveSeeds`).

SB3 and PyTorch are optional (:data:`INSTALL_HINT`); only :func:`train_seed` imports them.
"""

from __future__ import annotations

import importlib.util
import multiprocessing
import shutil
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxcart.core import networks
from jaxcart.core.config import PPOConfig
from jaxcart.core.solved import NUM_EVAL_EPISODES
from jaxcart.engine.loop import METRIC_COLUMNS
from jaxcart.run.greedy import evaluate_gymnasium
from jaxcart.run.loggers import SB3_NAMES, Logger, make_logger
from jaxcart.run.progress import SeedBars
from jaxcart.rundir import files, layout
from jaxcart.rundir.directory import evaluation_record, package_versions, write_metrics_csv
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.reader import bounded_int, params_headers, read_json

TORCH_CPU_INSTALL = "pip install torch --index-url https://download.pytorch.org/whl/cpu"
"""PyTorch's own install line for its CPU build on Linux (plain ``pip install torch`` pulls
the CUDA build and its GBs of libraries)."""
INSTALL_HINT = f"{TORCH_CPU_INSTALL} && pip install 'jaxcart[sb3]'"
"""What to install for SB3 (in a clone of jaxcart: ``pip install -e '.[sb3]'``)."""
FRAMEWORK = "stable-baselines3 (torch)"
"""``config.json``'s ``framework`` of a run trained by SB3."""
DEFAULT_TIMESTEPS = 80_000
"""``PPO.learn(80_000)``: 40 rollouts of 2048 steps (SB3 finishes the rollout it is in)."""


class SB3Unavailable(ImportError):
    """Stable-Baselines3 or PyTorch is not installed (the message says what to install)."""


def check_available() -> None:
    """Raises :class:`SB3Unavailable` unless both ``stable_baselines3`` and ``torch`` can be
    imported (cheap: nothing is imported)."""
    missing = [m for m in ("torch", "stable_baselines3") if importlib.util.find_spec(m) is None]
    if missing:
        raise SB3Unavailable(f"{' and '.join(missing)} not installed: {INSTALL_HINT}")


@dataclass
class SeedResult:
    """One SB3 seed: metrics ``name -> [iterations]``, parameters (jaxcart's tree, no seed
    axis), greedy returns ``[episodes]`` and training seconds."""

    metrics: dict[str, np.ndarray]
    params: dict
    returns: np.ndarray
    seconds: float


def to_metrics(rows: list[dict]) -> dict[str, np.ndarray]:
    """SB3 CSV rows -> jaxcart metric arrays ``[iterations]`` (NaN where SB3 logged nothing).

    SB3 dumps its log before each update, so a rollout's ``train/*`` values are on the row
    after it (the next rollout's, or the final dump); its ``rollout/*`` and ``time/*`` values
    are on its own row.

    Args:
        rows: SB3's ``progress.csv`` as dicts: one row per rollout (it has
            ``time/total_timesteps``), then the final dump holding the last update's values.
    """
    rollouts = [i for i, row in enumerate(rows) if row.get("time/total_timesteps")]
    rows = [*rows, {}]  # the last rollout's update, when its dump is not in yet
    out = {}
    for name in METRIC_COLUMNS:
        shift = int(name.startswith("train/"))
        texts = [rows[i + shift].get(SB3_NAMES.get(name, name)) for i in rollouts]
        out[name] = np.array([float(text) if text else np.nan for text in texts])
    return out


def sb3_params(state_dict: dict[str, np.ndarray], config: PPOConfig) -> dict:
    """SB3 ``MlpPolicy`` weights as jaxcart's parameter tree (no seed axis, float32).

    SB3's policy keeps two MLPs, then the heads ``action_net`` and ``value_net``; they become
    jaxcart's ``actor`` and ``critic`` layers ``hidden_0, ..., out``
    (:func:`jaxcart.core.networks.sb3_layers`).

    Args:
        state_dict: ``model.policy.state_dict()`` as NumPy arrays (``weight [out, in]``,
            ``bias [out]``).
        config: the run's config (its ``hidden_sizes`` fix the number of layers).

    Raises:
        KeyError: a layer is missing (not an ``MlpPolicy`` of this shape).
    """
    hidden = len(config.hidden_sizes)
    tree: dict = {networks.ACTOR: {}, networks.CRITIC: {}}
    for head, layer, module in networks.sb3_layers(hidden, hidden):
        tree[head][layer] = {
            "kernel": np.asarray(state_dict[f"{module}.weight"], np.float32).T,
            "bias": np.asarray(state_dict[f"{module}.bias"], np.float32),
        }
    return {networks.ROOT: tree}


def train_seed(
    seed: int, total_timesteps: int, threads: int, on_row: Callable[[dict], None]
) -> SeedResult:
    """``PPO("MlpPolicy", "CartPole-v1", seed=seed).learn(total_timesteps)`` on the CPU,
    then its greedy evaluation (runs in a worker process when seeds train in parallel).

    ``on_row(row)`` sees SB3's log as it is written: ``{}`` when training starts, then each
    row of SB3's ``progress.csv`` (name -> text, as its CSV writer writes it): one per
    rollout, then the final dump (see :func:`to_metrics`).
    """
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import KVWriter, Logger, filter_excluded_keys

    rows: list[dict] = []

    class Rows(KVWriter):
        """SB3's CSV rows, kept in memory and passed on at once."""

        def write(self, key_values: dict, key_excluded: dict, step: int = 0) -> None:
            values = filter_excluded_keys(key_values, key_excluded, "csv")
            rows.append({k: str(v) for k, v in values.items() if v is not None})
            on_row(rows[-1])

        def close(self) -> None:
            pass

    torch.set_num_threads(threads)  # 1 is fastest for this tiny MLP
    on_row({})
    model = PPO("MlpPolicy", "CartPole-v1", seed=seed, device="cpu")
    model.set_logger(Logger(None, [Rows()]))
    start = time.perf_counter()
    model.learn(total_timesteps)
    seconds = time.perf_counter() - start
    model.logger.dump(model.num_timesteps)  # the last update's train/* values
    weights = {k: v.detach().cpu().numpy() for k, v in model.policy.state_dict().items()}
    # jaxcart's own evaluation: episode e reset with seed EVAL_SEED + e
    act = lambda obs: model.predict(obs[0], deterministic=True)[0][None]
    returns = evaluate_gymnasium(act, 1, NUM_EVAL_EPISODES)[0]
    return SeedResult(to_metrics(rows), sb3_params(weights, PPOConfig()), returns, seconds)


def write_run(
    out: Path,
    config: PPOConfig,
    results: list[SeedResult],
    first_seed: int = 0,
    wall_seconds: float | None = None,
    jobs: int = 1,
) -> None:
    """Writes the seeds' results as a jaxcart run directory ``out`` (which must exist).

    Seeds are cut to the fewest iterations any of them logged; parameters are stacked to
    ``[num_seeds, ...]``.
    """
    num_seeds = len(results)
    iterations = min(len(r.metrics["time/fps"]) for r in results)
    metrics = {
        k: np.stack([r.metrics[k][:iterations] for r in results], axis=1) for k in METRIC_COLUMNS
    }
    info = {
        "format_version": layout.FORMAT_VERSION,
        "preset": "sb3",
        "framework": FRAMEWORK,
        "num_seeds": num_seeds,
        "seed": first_seed,
        "jobs": jobs,
        "wall_seconds": wall_seconds,
        "config": config.to_dict(),
        "versions": package_versions(),
    }
    stacked = files.flatten(
        jax.tree.map(lambda *seeds: np.stack(seeds), *[r.params for r in results])
    )
    evaluation = evaluation_record(np.stack([r.returns for r in results]))
    for s, seed in enumerate(evaluation["seeds"]):
        seed["final_ep_rew_mean"] = float(metrics["rollout/ep_rew_mean"][-1, s])
        seed["train_seconds"] = results[s].seconds
    with files.opened(out) as directory:  # every file through it, recorded in its manifest
        listing = files.Manifest(directory)
        files.write_config(listing, info)
        listing.write(layout.METRICS_FILE, write_metrics_csv, metrics, config.batch_size)
        listing.write(layout.PARAMS_FILE, files.save_tree, stacked)
        listing.write_json(layout.EVALUATION_FILE, evaluation)


_ROWS: Any = None
"""In a worker process: the queue that takes ``(seed, row)`` to the parent."""


def _start_worker(rows: Any) -> None:
    """Worker processes leave Ctrl-C to the parent, which saves what finished and stops them,
    and send SB3's rows to it as they are written."""
    global _ROWS
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _ROWS = rows


def _train_seed_job(job: tuple[int, int, int]) -> tuple[int, SeedResult]:
    seed, total_timesteps, threads = job
    return seed, train_seed(seed, total_timesteps, threads, lambda row: _ROWS.put((seed, row)))


def save_seed(out: Path, seed: int, result: SeedResult, elapsed: float) -> None:
    """Keeps one finished seed in ``out/sb3-seeds/`` (atomically), so an interrupted run
    loses at most the seeds still training; ``elapsed``: wall seconds since the run began."""
    arrays = {f"params/{k}": v for k, v in files.flatten(result.params).items()}
    arrays["metrics"] = np.stack([result.metrics[k] for k in METRIC_COLUMNS], axis=1)
    arrays["returns"] = np.asarray(result.returns, np.float64)
    arrays["seconds"] = np.array([result.seconds, elapsed])  # training's, the run's so far
    files.subdir(out, layout.SB3_SEEDS_DIR, create=True)
    files.save_tree(layout.sb3_seed_file(out, seed), arrays, {"seed": seed})


def load_seed(out: Path, seed: int, config: PPOConfig) -> tuple[SeedResult, float] | None:
    """A seed :func:`save_seed` kept, checked (names, shapes, finite weights, returns and
    seconds: the store's :func:`~jaxcart.rundir.files.load_tree`), with the run's elapsed
    seconds when it was saved; None when that seed has not finished."""
    path = layout.sb3_seed_file(out, seed)
    files.subdir(out, layout.SB3_SEEDS_DIR)
    if files.refuse_link(path) is None:
        return None
    headers = params_headers(config, 1).items()
    expected = {f"params/{k}": (shape[1:], dtype) for k, (shape, dtype) in headers}
    expected["returns"] = ((NUM_EVAL_EPISODES,), np.dtype(np.float64))
    expected["seconds"] = ((2,), np.dtype(np.float64))
    what = f"SB3 seed {seed} of this run"
    arrays, meta = files.load_tree(path, 1 << 24, expected, what, exact=False)
    metrics = arrays.pop("metrics", np.empty(0))  # [iterations, columns], NaN where unlogged
    shape_ok = metrics.shape[1:] == (len(METRIC_COLUMNS),)
    if set(arrays) != set(expected) or not shape_ok or meta != {"seed": seed}:
        raise RunDirError(f"{path} does not hold {what}; refusing it")
    seconds, elapsed = arrays.pop("seconds")
    returns = arrays.pop("returns")
    tree = files.unflatten({k[len("params/") :]: v for k, v in arrays.items()})
    result = SeedResult(dict(zip(METRIC_COLUMNS, metrics.T)), tree, returns, float(seconds))
    return result, float(elapsed)


PLAN_BOUNDS = {"num_seeds": 100_000, "first_seed": 2**31 - 1, "total_timesteps": 10**9}
"""What a run trains, fixed once it starts (``plan.json``), and the largest value of each."""


def read_plan(out: Path) -> dict:
    """What an unfinished ``python -m jaxcart.sb3`` run was asked to train (checked).

    Raises:
        RunDirError: ``out`` is not an unfinished SB3 run, or its plan is damaged.
    """
    if not Path(out).is_dir():
        raise RunDirError(f"{out} is not a directory")
    if files.refuse_link(Path(out) / layout.EVALUATION_FILE) is not None:
        raise RunDirError(f"{out} is a finished run; there is nothing to resume")
    if files.refuse_link(Path(out) / layout.SB3_PLAN_FILE) is None:
        raise RunDirError(f"{out} is not an unfinished python -m jaxcart.sb3 run (no plan)")
    plan = read_json(out, layout.SB3_PLAN_FILE)
    if set(plan) != set(PLAN_BOUNDS) or not all(
        bounded_int(plan[k], int(k != "first_seed"), high) for k, high in PLAN_BOUNDS.items()
    ):
        raise RunDirError(f"{Path(out) / layout.SB3_PLAN_FILE} is damaged; refusing it")
    return plan


def train_run(
    out: Path,
    plan: dict | None,
    on_start: Callable[[dict, int], None],
    on_seed: Callable[[int, SeedResult], None],
    jobs: int = 1,
    threads: int = 1,
    loggers: tuple[str, ...] = (),
    logger_dir: Path | None = None,
) -> list[SeedResult]:
    """Trains SB3's seeds into the run directory ``out``, then writes the run directory (and
    removes the plan and kept seeds). Each seed is kept as it finishes, so an interrupted run
    continues where it stopped.

    Args:
        out: the run directory: created for a new ``plan`` (it must not exist), else an
            unfinished SB3 run, whose seeds not kept yet are trained.
        plan: a new run's :data:`PLAN_BOUNDS` values (seeds ``first_seed ... first_seed +
            num_seeds - 1``); None resumes ``out``.
        on_start: ``on_start(plan, kept)`` before training.
        on_seed: ``on_seed(seed, result)`` as each seed finishes (printed above the progress
            bars, one per seed: :class:`jaxcart.run.progress.SeedBars`).
        jobs, threads: seeds trained at once (one process each) and PyTorch's threads.
        loggers, logger_dir: as for :func:`jaxcart.run.loggers.make_logger`: each seed's
            curve is logged as SB3 writes its log (an iteration once its update is logged,
            one rollout later), under the names SB3 itself logs; the kept seeds' curves when
            training starts.

    Raises:
        SB3Unavailable: SB3 or PyTorch is not installed.
        FileExistsError: a new run's ``out`` exists.
        RunDirError: ``out`` is not an unfinished SB3 run, or a kept seed is damaged.
    """
    check_available()
    out = Path(out)
    if plan is not None:
        out.mkdir(parents=True, exist_ok=False)
        files.write_json(out / layout.SB3_PLAN_FILE, plan)
    plan = read_plan(out)
    config = PPOConfig(total_timesteps=plan["total_timesteps"])  # SB3's defaults: sb3 preset
    seeds = range(plan["first_seed"], plan["first_seed"] + plan["num_seeds"])
    kept = {s: found for s in seeds if (found := load_seed(out, s, config)) is not None}
    on_start(plan, len(kept))
    names = [f"seed{i}" for i in range(len(seeds))]  # seed indices, as jaxcart names runs
    info = {"framework": FRAMEWORK, "preset": "sb3", "config": config.to_dict()}
    bars = SeedBars(config.num_iterations * config.batch_size)
    with make_logger(loggers, out, names, info, logger_dir) as logger:
        live = LiveSeeds(logger, config, seeds.start, bars)
        for seed, (result, _) in kept.items():
            live.log(seed, 0, result.metrics)
        offset = max((elapsed for _, elapsed in kept.values()), default=0.0)
        start = time.perf_counter()
        jobs_left = [(s, plan["total_timesteps"], threads) for s in seeds if s not in kept]
        try:
            for seed, result in _train(jobs_left, jobs, live):
                elapsed = offset + time.perf_counter() - start
                save_seed(out, seed, result, elapsed)
                kept[seed] = (result, elapsed)
                with bars.outside():
                    on_seed(seed, result)
        finally:
            bars.close()
        results = [kept[s][0] for s in seeds]
        elapsed = offset + time.perf_counter() - start
        write_run(out, config, results, plan["first_seed"], elapsed, jobs)
        shutil.rmtree(files.subdir(out, layout.SB3_SEEDS_DIR), ignore_errors=True)
        (out / layout.SB3_PLAN_FILE).unlink()
    return results


class LiveSeeds:
    """SB3's rows, seed by seed, as they are written (``on_row`` of :func:`train_seed`): each
    finished iteration to the logger (run ``seed - first_seed``), the env steps to the bars.

    A rollout's row holds its ``rollout/*`` and ``time/*`` values; its update's ``train/*``
    come in the next row (or the final dump), so iteration ``i`` is logged then.
    """

    def __init__(self, logger: Logger, config: PPOConfig, first_seed: int, bars: SeedBars):
        self.logger, self.config, self.first_seed, self.bars = logger, config, first_seed, bars
        self.rows: dict[int, list[dict]] = {}

    def __call__(self, seed: int, row: dict) -> None:
        if not row:  # the seed starts (again, after an interruption)
            self.rows[seed] = []
            self.bars.update(seed, 0)
            return
        rows = self.rows[seed]
        rows.append(row)
        if len(rows) > 1:  # rows[-2]'s iteration is complete
            metrics = to_metrics(rows[-2:])  # rows[-1] may be a rollout too: its own iteration
            self.log(seed, len(rows) - 2, {k: v[:1] for k, v in metrics.items()})
        if row.get("time/total_timesteps"):
            ep_rew_mean = float(row.get("rollout/ep_rew_mean", "nan"))
            self.bars.update(seed, int(row["time/total_timesteps"]), ep_rew_mean)
        else:  # the final dump: training is over
            self.bars.close(seed)

    def log(self, seed: int, first_iteration: int, metrics: dict[str, np.ndarray]) -> None:
        """Logs seed ``seed``'s ``metrics`` (name -> ``[n]``, as :func:`to_metrics` makes
        them) of iterations ``first_iteration + 1 ... first_iteration + n``, with SB3's
        ``train/n_updates`` and ``train/clip_range``."""
        clip, run = np.full(1, float(self.config.clip_coef)), seed - self.first_seed
        self.logger.log_iterations(first_iteration, metrics, self.config, clip, run)


def _train(
    jobs_left: list[tuple[int, int, int]], jobs: int, on_row: Callable[[int, dict], None]
) -> Iterator[tuple[int, SeedResult]]:
    """Each seed's result as it finishes: in this process for one job, else in ``jobs``
    spawned processes (stopped at once when the caller stops, e.g. on Ctrl-C).
    ``on_row(seed, row)`` as :func:`train_seed`'s, from a thread of this process for jobs > 1
    (a seed's last rows may follow its result)."""
    if jobs == 1:
        for seed, total, threads in jobs_left:
            yield seed, train_seed(seed, total, threads, lambda row, s=seed: on_row(s, row))
        return
    # spawn: a forked child would inherit the parent's threads (JAX's) in an unknown state
    context = multiprocessing.get_context("spawn")
    rows = context.Queue()
    drain = threading.Thread(target=lambda: [on_row(*e) for e in iter(rows.get, None)], daemon=True)
    drain.start()
    try:
        processes = min(jobs, max(len(jobs_left), 1))
        with context.Pool(processes, initializer=_start_worker, initargs=(rows,)) as pool:
            yield from pool.imap_unordered(_train_seed_job, jobs_left)
            pool.close()
            pool.join()  # every row is in the queue before the stop mark
    finally:
        rows.put(None)
        drain.join(timeout=10)  # a worker killed mid-row could leave it waiting
