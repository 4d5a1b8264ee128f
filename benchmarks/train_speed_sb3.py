"""train_speed.py's Stable-Baselines3 contenders (``sb3``, ``sb3-1thread``): PPO with every
hyperparameter at its default, PyTorch on the CPU."""

from __future__ import annotations

import time

from train_speed_common import QUICK_TIMESTEPS, SB3_TIMESTEPS, ChildUnavailable


def run(preset_name: str, num_seeds: int, quick: bool, cache_dir: str | None):
    """Trains ``PPO("MlpPolicy", "CartPole-v1", seed=0)``; ``preset_name`` ``"1thread"`` first
    sets torch to one thread. One seed; no JAX, so ``cache_dir`` is unused.

    Returns:
        ``(data, policy)``: the timings and settings, and the greedy policy (observations
        ``[..., 4]`` -> actions) for the harness to evaluate.
    """
    try:
        import torch
        from stable_baselines3 import PPO
    except ImportError as e:
        raise ChildUnavailable(f"stable-baselines3/torch not installed ({e})") from None
    import numpy as np

    if preset_name == "1thread":  # the usual advice for small MLPs on CPU; SB3 leaves the default
        torch.set_num_threads(1)

    timesteps = QUICK_TIMESTEPS["sb3"] if quick else SB3_TIMESTEPS
    t0 = time.perf_counter()
    model = PPO("MlpPolicy", "CartPole-v1", seed=0, device="cpu")
    t1, c1 = time.perf_counter(), time.process_time()
    model.learn(timesteps)
    t2, c2 = time.perf_counter(), time.process_time()

    def policy(obs: np.ndarray) -> np.ndarray:
        actions, _ = model.predict(obs.reshape(-1, 4), deterministic=True)
        return np.asarray(actions).reshape(obs.shape[:-1])

    data = {
        "num_seeds": 1,
        "env_steps": int(model.num_timesteps),
        "setup_seconds": t1 - t0,
        "compile_seconds": 0.0,
        "train_seconds": t2 - t1,
        "train_cpu_seconds": c2 - c1,
        "torch_threads": torch.get_num_threads(),
        "hyperparameters": {
            "n_steps": model.n_steps,
            "batch_size": model.batch_size,
            "n_epochs": model.n_epochs,
            "learning_rate": model.learning_rate,
        },
    }
    return data, policy
