"""train_speed's sbx contenders (``sbx-default-xS``, ``sbx-zoo-xS``): sbx's PPO (``sbx-rl``,
Stable-Baselines3's JAX port: SB3's API and rollout loop, flax networks and jitted updates)
at its defaults or at rl-zoo3's tuned CartPole-v1 settings, like the SB3 contenders.

S > 1 seeds are S one-seed trainings as parallel processes, one per core, each with XLA
limited to one thread. sbx pins its own jax/flax range, so these run in their own virtualenv
(``--sbx-python``).
"""

from __future__ import annotations

import importlib.util
import os
import sys

from benchmarks.train_speed.common import ChildUnavailable, configure_jax_cache
from benchmarks.train_speed.processes import run_seeds, train_model

ONE_THREAD_FLAGS = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def actor_layers(model) -> dict:
    """sbx's actor (``Dense_0`` ... ``Dense_k``, tanh, the last one the logits) as jaxcart's
    actor layers."""
    import jax
    import numpy as np

    params = jax.device_get(model.policy.actor_state.params["params"])
    dense = sorted((k for k in params if k.startswith("Dense_")), key=lambda k: int(k[6:]))
    names = [f"hidden_{i}" for i in range(len(dense) - 1)] + ["out"]
    return {
        name: {"kernel": np.asarray(params[k]["kernel"]), "bias": np.asarray(params[k]["bias"])}
        for name, k in zip(names, dense)
    }


def train_seed(config_name: str, seed: int, quick: bool, cache_dir, threads: int | None) -> dict:
    """One sbx training; ``threads`` 1 limits XLA to one thread (set before JAX is imported,
    so only in a fresh pool worker), None leaves XLA's default. Compilation happens inside
    ``learn`` and is not timed apart."""
    if threads == 1:
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {ONE_THREAD_FLAGS}".strip()
    import jax
    from sbx import PPO

    configure_jax_cache(cache_dir)
    info = {
        "compile_seconds": None,
        "jax_devices": [str(d) for d in jax.devices()],
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
    }
    return train_model(PPO, config_name, seed, quick, actor_layers, info)


def run(preset_name: str, num_seeds: int, quick: bool, cache_dir: str | None):
    """``num_seeds`` sbx trainings of ``preset_name`` (``default`` or ``zoo``).

    Returns:
        ``(data, policy)``: the timings and settings, and the seeds' stacked greedy policy
        (rebuilt from each model's weights) for the harness to evaluate.
    """
    if importlib.util.find_spec("sbx") is None:
        raise ChildUnavailable(f"sbx (sbx-rl) not installed in {sys.executable}")
    if preset_name not in ("default", "zoo"):
        raise ValueError(f"unknown sbx configuration {preset_name!r}")
    return run_seeds(train_seed, preset_name, num_seeds, quick, cache_dir, None)
