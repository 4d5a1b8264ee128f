r"""Train Stable-Baselines3's PPO with its defaults and save it as a jaxcart run directory.

The CartPole course comparison: SB3's ``PPO("MlpPolicy", "CartPole-v1").learn(80_000)`` and
jaxcart's ``sb3`` preset on the same axes. SB3's own CSV log is converted to jaxcart's
``metrics.csv`` (same metric names), and each seed is evaluated greedily for 20 episodes in
Gymnasium's CartPole-v1, so ``python -m jaxcart.plot`` can overlay the two:

    benchmarks/.venv-bench/bin/python -m benchmarks.experiments.sb3_reference \
        --num-seeds 3 --out runs/sb3-torch
    python -m jaxcart.train --num-seeds 3 --out runs/jaxcart-sb3
    python -m jaxcart.plot runs/sb3-torch runs/jaxcart-sb3 --out benchmarks/results/sb3_vs_jaxcart.png

(needs ``torch`` and ``stable-baselines3``: ``bash benchmarks/setup_venvs.sh``).
"""

from __future__ import annotations

import csv
import multiprocessing
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from benchmarks import lib
from jaxcart.core.config import PPOConfig
from jaxcart.core.solved import EVAL_SEED, NUM_EVAL_EPISODES
from jaxcart.engine.trainer import METRIC_COLUMNS
from jaxcart.rundir import files, layout, outputs
from jaxcart.rundir.directory import package_versions

# SB3 dumps its log before each update, so train/* values appear one row after the rollout
# they belong to; rollout/* and time/* belong to the row they are on.
SHIFTED_PREFIX = "train/"


def train_one(seed: int, timesteps: int, threads: int) -> tuple[list[dict], object, float]:
    """SB3 PPO with defaults; returns its CSV log rows, the model and the training seconds."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    torch.set_num_threads(threads)
    with tempfile.TemporaryDirectory() as tmp:
        model = PPO("MlpPolicy", "CartPole-v1", seed=seed, device="cpu")
        model.set_logger(configure(tmp, ["csv"]))
        start = time.perf_counter()
        model.learn(timesteps)
        seconds = time.perf_counter() - start
        model.logger.dump(model.num_timesteps)  # the last update's train/* values
        with open(Path(tmp) / "progress.csv", newline="") as f:
            rows = list(csv.DictReader(f))
    return rows, model, seconds


def to_metrics(rows: list[dict], batch_size: int) -> dict[str, np.ndarray]:
    """SB3 CSV rows -> jaxcart metric arrays ``[iterations]`` (NaN where SB3 logged nothing)."""

    def value(row: dict, name: str) -> float:
        text = row.get(name, "")
        return float(text) if text not in ("", None) else np.nan

    rollout_rows = [r for r in rows if r.get("time/total_timesteps")]
    iterations = len(rollout_rows)
    out = {name: np.full(iterations, np.nan) for name in METRIC_COLUMNS}
    for i, row in enumerate(rollout_rows):
        for name in METRIC_COLUMNS:
            if not name.startswith(SHIFTED_PREFIX):
                out[name][i] = value(row, name)
        out["time/elapsed"][i] = value(row, "time/time_elapsed")
        # this iteration's update is logged on the next row (or the final dump)
        if i + 1 < len(rows):
            for name in METRIC_COLUMNS:
                if name.startswith(SHIFTED_PREFIX):
                    out[name][i] = value(rows[i + 1], name)
    return out


def greedy_returns(model, episodes: int) -> np.ndarray:
    import gymnasium as gym

    returns = []
    for e in range(episodes):
        env = gym.make("CartPole-v1")
        obs, _ = env.reset(seed=EVAL_SEED + e)
        total, done = 0.0, False
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, reward, terminated, truncated, _ = env.step(int(action))
            total += reward
            done = terminated or truncated
        returns.append(total)
    return np.array(returns)


def run_seed(seed: int, timesteps: int, threads: int) -> tuple[dict, np.ndarray, float]:
    """One seed end to end: SB3's training log as jaxcart metrics, greedy returns, seconds."""
    rows, model, seconds = train_one(seed, timesteps, threads)
    return (
        to_metrics(rows, PPOConfig().batch_size),
        greedy_returns(model, NUM_EVAL_EPISODES),
        seconds,
    )


def write_run(
    out: Path,
    config: PPOConfig,
    per_seed: list,
    evaluations: list,
    seconds: list,
    first_seed: int = 0,
    wall_seconds: float | None = None,
    jobs: int = 1,
):
    """Writes the seeds' metrics and evaluations as a jaxcart run directory ``out``."""
    num_seeds = len(per_seed)
    iterations = min(len(m["time/fps"]) for m in per_seed)
    metrics = {k: np.stack([m[k][:iterations] for m in per_seed], axis=1) for k in METRIC_COLUMNS}
    files.write_json(
        out / layout.CONFIG_FILE,
        {
            "format_version": layout.FORMAT_VERSION,
            "preset": "sb3",
            "framework": "stable-baselines3 (torch)",
            "num_seeds": num_seeds,
            "seed": first_seed,
            "jobs": jobs,
            "wall_seconds": wall_seconds,
            "config": config.to_dict(),
            "versions": package_versions(),
        },
    )
    outputs.write_metrics_csv(out / layout.METRICS_FILE, metrics, config.batch_size)
    files.write_json(
        out / layout.EVALUATION_FILE,
        {
            "episodes": NUM_EVAL_EPISODES,
            "seeds": [
                {
                    "seed_index": s,
                    "gymnasium_returns": r.tolist(),
                    "gymnasium_mean": float(r.mean()),
                    "gymnasium_min": float(r.min()),
                    "solved": bool((r >= 500).all()),
                    "train_seconds": seconds[s],
                }
                for s, r in enumerate(evaluations)
            ],
            "solved_seeds": int(sum((r >= 500).all() for r in evaluations)),
        },
    )


def main() -> None:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--num-seeds", type=int, default=3)
    parser.add_argument("--timesteps", type=int, default=80_000)
    parser.add_argument(
        "--threads", type=int, default=1, help="torch threads (1 is fastest for this tiny MLP)"
    )
    parser.add_argument(
        "--first-seed", type=int, default=0, help="seeds are first-seed ... first-seed+num-seeds-1"
    )
    parser.add_argument(
        "--jobs", type=int, default=1, help="seeds trained at once, one process each (one per core)"
    )
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=False)
    config = PPOConfig()  # SB3's defaults, as jaxcart's sb3 preset
    seeds = range(args.first_seed, args.first_seed + args.num_seeds)
    start = time.perf_counter()
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(args.jobs, mp_context=context) as pool:
        futures = [pool.submit(run_seed, s, args.timesteps, args.threads) for s in seeds]
        results = []
        for seed, future in zip(seeds, futures):
            results.append(future.result())
            secs, returns = results[-1][2], results[-1][1]
            print(f"seed {seed}: {secs:.1f} s, greedy mean {returns.mean():.1f}", flush=True)
    wall = time.perf_counter() - start
    per_seed, evaluations, seconds = (list(column) for column in zip(*results))
    write_run(out, config, per_seed, evaluations, seconds, args.first_seed, wall, args.jobs)
    print(f"wrote {out} ({wall:.1f} s wall, {args.jobs} job(s))")


if __name__ == "__main__":
    main()
