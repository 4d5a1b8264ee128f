"""rl-zoo3-style Optuna tuning of Stable-Baselines3's PPO on CartPole-v1, the contender of
``python -m benchmarks.tune``: ``study.optimize(objective, n_trials, n_jobs=cores)`` as
rl-zoo3's ``--optimize`` runs it, one seed per trial, one torch thread per job, SB3's PPO
defaults with the trial's values, the trial's score its greedy mean return.

Run by the harness in the benchmark venv (``benchmarks/.venv-bench`` with ``optuna``)::

    python -m benchmarks.tune.sb3_study --storage sqlite:///S.db --study-name sb3 \\
        --trials 32 --timesteps 80000 --space learning_rate=log:1e-5:1e-2 --space clip_coef=0.1:0.3
"""

from __future__ import annotations

import argparse
import os

EVAL_EPISODES = 20


def parse_space(specs: list[str]) -> dict[str, tuple[float, float, bool]]:
    """``NAME=LOW:HIGH`` or ``NAME=log:LOW:HIGH`` (the float ranges both contenders take)."""
    space = {}
    for spec in specs:
        name, _, text = spec.partition("=")
        parts = text.split(":")
        log = parts[0] == "log"
        low, high = float(parts[-2]), float(parts[-1])
        space[name] = (low, high, log)
    return space


SB3_NAMES = {
    "learning_rate": "learning_rate",
    "clip_coef": "clip_range",
    "ent_coef": "ent_coef",
    "gamma": "gamma",
    "gae_lambda": "gae_lambda",
    "vf_coef": "vf_coef",
    "max_grad_norm": "max_grad_norm",
}
"""jaxcart's config names -> PPO's arguments."""


def objective(trial, space: dict, timesteps: int) -> float:
    """One trial: SB3's PPO at its defaults and the trial's values, one seed (the trial's
    number), trained for ``timesteps`` and scored by its greedy mean return."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.evaluation import evaluate_policy

    torch.set_num_threads(1)  # rl-zoo3's n_jobs: one core each
    kwargs = {
        SB3_NAMES[name]: trial.suggest_float(name, low, high, log=log)
        for name, (low, high, log) in space.items()
    }
    model = PPO("MlpPolicy", "CartPole-v1", seed=trial.number, device="cpu", **kwargs)
    model.learn(timesteps)
    mean, _ = evaluate_policy(model, model.get_env(), EVAL_EPISODES, deterministic=True)
    return float(mean)


def main() -> None:
    import optuna

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--storage", required=True)
    parser.add_argument("--study-name", required=True)
    parser.add_argument("--trials", type=int, required=True)
    parser.add_argument("--timesteps", type=int, required=True)
    parser.add_argument("--space", action="append", default=[])
    parser.add_argument("--jobs", type=int, default=len(os.sched_getaffinity(0)))
    args = parser.parse_args()
    space = parse_space(args.space)
    study = optuna.create_study(
        storage=args.storage,
        study_name=args.study_name,
        sampler=optuna.samplers.TPESampler(),
        direction="maximize",
        load_if_exists=True,
    )
    study.optimize(lambda t: objective(t, space, args.timesteps), args.trials, n_jobs=args.jobs)


if __name__ == "__main__":
    main()
