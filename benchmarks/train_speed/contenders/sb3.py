"""train_speed's Stable-Baselines3 contenders: PyTorch on the CPU.

- ``sb3``: ``PPO("MlpPolicy", "CartPole-v1", seed=0)``, every hyperparameter at its default,
  torch's default thread count; ``sb3-1thread``: the same after ``torch.set_num_threads(1)``.
- ``sb3-zoo-xS``: rl-zoo3's tuned CartPole-v1 settings (``ZOO_CARTPOLE``), one torch thread.
- ``sb3-default-xS``, ``sb3-zoo-xS`` with S > 1: S one-seed trainings (seeds 0 ... S-1) as
  parallel processes, one per core, one torch thread each.
"""

from __future__ import annotations

import importlib.util
import sys

from benchmarks.train_speed.common import ChildUnavailable
from benchmarks.train_speed.processes import run_seeds, train_model

# preset name -> (configuration, torch threads for one seed; None = torch's default). The
# tuned configuration gets one thread, SB3's best setting for this MLP: with two threads a
# core busy with anything else slows it several times (a --quick run on a loaded 2-core
# machine took 46 s with two threads).
CONFIGS = {"default": ("default", None), "1thread": ("default", 1), "zoo": ("zoo", 1)}


def actor_layers(model) -> dict:
    """The policy network of SB3's ``MlpPolicy`` (4-64-64-2, tanh) as jaxcart's actor layers:
    ``kernel [in, out]`` (torch stores ``[out, in]``) and ``bias [out]``."""
    import torch

    policy = model.policy
    hidden = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    layers = [*hidden, policy.action_net]
    names = [f"hidden_{i}" for i in range(len(hidden))] + ["out"]
    return {
        name: {
            "kernel": layer.weight.detach().numpy().T.copy(),
            "bias": layer.bias.detach().numpy().copy(),
        }
        for name, layer in zip(names, layers)
    }


def train_seed(config_name: str, seed: int, quick: bool, cache_dir, threads: int | None) -> dict:
    """One SB3 training (``threads``: torch threads, None = its default); no JAX, so
    ``cache_dir`` is unused. Runs in the contender's process or in a pool worker."""
    import torch
    from stable_baselines3 import PPO

    if threads is not None:  # the usual advice for small MLPs on CPU; SB3 leaves the default
        torch.set_num_threads(threads)
    info = {"compile_seconds": 0.0, "torch_threads": torch.get_num_threads()}
    return train_model(PPO, config_name, seed, quick, actor_layers, info)


def run(preset_name: str, num_seeds: int, quick: bool, cache_dir: str | None):
    """``num_seeds`` SB3 trainings of ``preset_name`` (``default``, ``1thread``, ``zoo``).

    Returns:
        ``(data, policy)``: the timings and settings, and the seeds' stacked greedy policy
        (rebuilt from each model's weights) for the harness to evaluate.
    """
    # Looked up, not imported: with S > 1 seeds this process only waits for the pool.
    missing = [m for m in ("torch", "stable_baselines3") if importlib.util.find_spec(m) is None]
    if missing:
        raise ChildUnavailable(f"{' and '.join(missing)} not installed in {sys.executable}")
    if preset_name not in CONFIGS:
        raise ValueError(f"unknown SB3 configuration {preset_name!r}")
    config_name, threads = CONFIGS[preset_name]
    return run_seeds(train_seed, config_name, num_seeds, quick, cache_dir, threads)
