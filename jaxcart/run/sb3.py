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

SB3 and PyTorch are optional (:data:`INSTALL_HINT`); only :func:`train_seed` imports them.
"""

from __future__ import annotations

import csv
import importlib.util
import multiprocessing
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxcart.core import networks
from jaxcart.core.config import PPOConfig
from jaxcart.core.solved import EVAL_SEED, NUM_EVAL_EPISODES, SOLVED_DEFINITION, is_solved
from jaxcart.engine.trainer import METRIC_COLUMNS
from jaxcart.rundir import files, layout, outputs
from jaxcart.rundir.directory import package_versions

TORCH_CPU_INSTALL = "pip install torch --index-url https://download.pytorch.org/whl/cpu"
"""PyTorch's own install line for its CPU build on Linux (plain ``pip install torch`` pulls
the CUDA build and its GBs of libraries)."""
INSTALL_HINT = f"{TORCH_CPU_INSTALL} && pip install 'jaxcart[sb3]'"
"""What to install for SB3 (in a clone of jaxcart: ``pip install -e '.[sb3]'``)."""
FRAMEWORK = "stable-baselines3 (torch)"
"""``config.json``'s ``framework`` of a run trained by SB3."""
DEFAULT_TIMESTEPS = 80_000
"""``PPO.learn(80_000)``: 40 rollouts of 2048 steps (SB3 finishes the rollout it is in)."""

# SB3 dumps its log before each update, so train/* values appear one row after the rollout
# they belong to; rollout/* and time/* belong to the row they are on.
SHIFTED_PREFIX = "train/"
SB3_NAMES = {"time/elapsed": "time/time_elapsed"}
"""jaxcart metric -> SB3's name where they differ."""


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

    Args:
        rows: SB3's ``progress.csv`` as dicts: one row per rollout (it has
            ``time/total_timesteps``), then the final dump holding the last update's values.
    """

    def value(row: dict, name: str) -> float:
        text = row.get(SB3_NAMES.get(name, name), "")
        return float(text) if text not in ("", None) else np.nan

    rollout_rows = [r for r in rows if r.get("time/total_timesteps")]
    out = {name: np.full(len(rollout_rows), np.nan) for name in METRIC_COLUMNS}
    for i, row in enumerate(rollout_rows):
        # this iteration's update is logged on the next row (or the final dump)
        update = rows[i + 1] if i + 1 < len(rows) else {}
        for name in METRIC_COLUMNS:
            out[name][i] = value(update if name.startswith(SHIFTED_PREFIX) else row, name)
    return out


def sb3_params(state_dict: dict[str, np.ndarray], config: PPOConfig) -> dict:
    """SB3 ``MlpPolicy`` weights as jaxcart's parameter tree (no seed axis, float32).

    SB3's policy keeps two MLPs, ``mlp_extractor.policy_net`` and ``.value_net`` (``Linear``
    at indices 0, 2, ... between activations), then the heads ``action_net`` and
    ``value_net``; they become jaxcart's ``actor`` and ``critic`` layers ``hidden_0, ...,
    out``.

    Args:
        state_dict: ``model.policy.state_dict()`` as NumPy arrays (``weight [out, in]``,
            ``bias [out]``).
        config: the run's config (its ``hidden_sizes`` fix the number of layers).

    Raises:
        KeyError: a layer is missing (not an ``MlpPolicy`` of this shape).
    """
    hidden = len(config.hidden_sizes)
    heads = {
        networks.ACTOR: ("mlp_extractor.policy_net", "action_net"),
        networks.CRITIC: ("mlp_extractor.value_net", "value_net"),
    }
    tree: dict = {networks.ROOT: {}}
    for head, (body, out) in heads.items():
        sources = [f"{body}.{2 * i}" for i in range(hidden)] + [out]
        tree[networks.ROOT][head] = {
            name: {
                "kernel": np.asarray(state_dict[f"{src}.weight"], np.float32).T,
                "bias": np.asarray(state_dict[f"{src}.bias"], np.float32),
            }
            for name, src in zip(networks.layer_names(hidden), sources)
        }
    return tree


def greedy_returns(act: Callable[[np.ndarray], int], episodes: int) -> np.ndarray:
    """``[episodes]`` returns of ``act`` in ``gymnasium.make("CartPole-v1")``, episode ``e``
    reset with seed ``EVAL_SEED + e`` (as jaxcart's evaluation)."""
    import gymnasium as gym

    returns = []
    env = gym.make("CartPole-v1")
    for e in range(episodes):
        obs, _ = env.reset(seed=EVAL_SEED + e)
        total, done = 0.0, False
        while not done:
            obs, reward, terminated, truncated, _ = env.step(act(obs))
            total += float(reward)
            done = terminated or truncated
        returns.append(total)
    env.close()
    return np.array(returns)


def train_seed(seed: int, total_timesteps: int, threads: int = 1) -> SeedResult:
    """``PPO("MlpPolicy", "CartPole-v1", seed=seed).learn(total_timesteps)`` on the CPU,
    then its greedy evaluation (runs in a worker process when seeds train in parallel)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    torch.set_num_threads(threads)  # 1 is fastest for this tiny MLP
    with tempfile.TemporaryDirectory() as tmp:
        model = PPO("MlpPolicy", "CartPole-v1", seed=seed, device="cpu")
        model.set_logger(configure(tmp, ["csv"]))
        start = time.perf_counter()
        model.learn(total_timesteps)
        seconds = time.perf_counter() - start
        model.logger.dump(model.num_timesteps)  # the last update's train/* values
        with open(Path(tmp) / "progress.csv", newline="") as f:
            rows = list(csv.DictReader(f))
    weights = {k: v.detach().cpu().numpy() for k, v in model.policy.state_dict().items()}
    returns = greedy_returns(
        lambda obs: int(model.predict(obs, deterministic=True)[0]), NUM_EVAL_EPISODES
    )
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
    files.write_json(
        out / layout.CONFIG_FILE,
        {
            "format_version": layout.FORMAT_VERSION,
            "preset": "sb3",
            "framework": FRAMEWORK,
            "num_seeds": num_seeds,
            "seed": first_seed,
            "jobs": jobs,
            "wall_seconds": wall_seconds,
            "config": config.to_dict(),
            "versions": package_versions(),
        },
    )
    outputs.write_metrics_csv(out / layout.METRICS_FILE, metrics, config.batch_size)
    stacked = _stack([r.params for r in results])
    files.save_tree(out / layout.PARAMS_FILE, files.flatten(stacked))
    returns = np.stack([r.returns for r in results])
    solved = is_solved(returns)
    episodes = returns.shape[1]
    seeds = [
        {
            "seed_index": s,
            "gymnasium_returns": returns[s].tolist(),
            "gymnasium_mean": float(returns[s].mean()),
            "gymnasium_min": float(returns[s].min()),
            "solved": bool(solved[s]),
            "final_ep_rew_mean": float(metrics["rollout/ep_rew_mean"][-1, s]),
            "train_seconds": results[s].seconds,
        }
        for s in range(num_seeds)
    ]
    files.write_json(
        out / layout.EVALUATION_FILE,
        {
            "episodes": episodes,
            "solved_definition": SOLVED_DEFINITION.format(episodes=episodes),
            "seeds": seeds,
            "solved_seeds": int(solved.sum()),
        },
    )


def _stack(trees: list[dict]) -> dict:
    """Nested dicts of arrays -> the same dict with arrays stacked on a new leading axis."""
    if isinstance(trees[0], dict):
        return {k: _stack([t[k] for t in trees]) for k in trees[0]}
    return np.stack(trees)


def train_run(
    out: Path,
    num_seeds: int,
    total_timesteps: int = DEFAULT_TIMESTEPS,
    first_seed: int = 0,
    jobs: int = 1,
    threads: int = 1,
    on_seed: Callable[[int, SeedResult], None] | None = None,
) -> list[SeedResult]:
    """Trains seeds ``first_seed ... first_seed + num_seeds - 1`` with SB3, ``jobs`` processes
    at once, and writes them as the run directory ``out`` (created; it must not exist).

    Raises:
        SB3Unavailable: SB3 or PyTorch is not installed.
        FileExistsError: ``out`` exists.
    """
    check_available()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=False)
    config = PPOConfig(total_timesteps=total_timesteps)  # SB3's defaults: the sb3 preset
    seeds = range(first_seed, first_seed + num_seeds)
    start = time.perf_counter()
    # spawn: a forked child would inherit the parent's threads (JAX's) in an unknown state
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(train_seed, s, total_timesteps, threads) for s in seeds]
        results = []
        for seed, future in zip(seeds, futures):
            results.append(future.result())
            if on_seed is not None:
                on_seed(seed, results[-1])
    write_run(out, config, results, first_seed, time.perf_counter() - start, jobs)
    return results
