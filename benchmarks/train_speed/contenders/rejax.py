"""train_speed's rejax contenders, S seeds as a ``vmap`` over ``train`` sharded over the CPU
devices like jaxcart's:

- ``rejax-sb3-xS``: rejax's PPO at SB3's hyperparameters;
- ``rejax-cartpole-xS``: rejax's PPO at its own CartPole-v1 configuration, the ``ppo`` entry of
  ``configs/gymnax/cartpole.yaml`` in rejax's repository (``REJAX_CARTPOLE``; the pip package
  ships no configs).

rejax 0.1.3 needs gymnax 0.0.x, so these run in their own virtualenv (``--rejax-python``).
"""

from __future__ import annotations

import os
import sys
import time

from benchmarks.train_speed.common import (
    QUICK_TIMESTEPS,
    SB3_TIMESTEPS,
    ChildUnavailable,
    configure_jax_cache,
)

# Where rejax's PPO differs from SB3's at these settings (it has no options for them).
REJAX_DIFFERENCES = (
    "Adam eps 1e-8 (SB3 1e-5), separate Adam optimisers and gradient clipping for actor and "
    "critic, clipped value loss, default (lecun-normal) rather than orthogonal init, and "
    "time-limit truncation treated as termination"
)


# keraJLi/rejax configs/gymnax/cartpole.yaml, ppo (the same values as the older
# configs/cartpole.yaml); its eval_freq (1000) is left out: evaluation is a no-op here.
REJAX_CARTPOLE = dict(
    num_envs=5,
    num_steps=100,
    num_epochs=5,
    num_minibatches=5,
    learning_rate=0.00075,
    max_grad_norm=0.5,
    total_timesteps=100_000,
    gamma=0.99,
    gae_lambda=0.95,
    clip_eps=0.2,
    ent_coef=0.01,
    vf_coef=0.5,
    agent_kwargs={"activation": "tanh"},  # hidden layers: rejax's default (64, 64)
)


def rejax_cartpole_config(quick: bool) -> dict:
    """rejax ``PPO.create`` arguments of rejax's own CartPole-v1 configuration."""
    total = QUICK_TIMESTEPS["cartpole"] if quick else REJAX_CARTPOLE["total_timesteps"]
    return dict(
        REJAX_CARTPOLE,
        env="CartPole-v1",
        total_timesteps=total,
        eval_freq=total,  # one evaluation period, and the evaluation a no-op (see below)
        skip_initial_evaluation=True,
    )


def rejax_config(quick: bool) -> dict:
    """rejax ``PPO.create`` arguments for SB3's PPO defaults on CartPole-v1."""
    iterations = -(-(QUICK_TIMESTEPS["sb3"] if quick else SB3_TIMESTEPS) // 2048)
    total = iterations * 2048
    return dict(
        env="CartPole-v1",
        num_envs=1,
        num_steps=2048,
        num_epochs=10,
        num_minibatches=32,  # 2048 / 64
        learning_rate=3e-4,
        max_grad_norm=0.5,
        gamma=0.99,
        gae_lambda=0.95,
        clip_eps=0.2,
        ent_coef=0.0,
        vf_coef=0.5,
        total_timesteps=total,
        # One evaluation "period" spanning the whole run, and the evaluation itself replaced
        # by a no-op below, so rejax's in-training evaluation costs nothing.
        eval_freq=total,
        skip_initial_evaluation=True,
        agent_kwargs={"activation": "tanh", "hidden_layer_sizes": (64, 64)},
    )


def greedy_policy(p: dict):
    """jaxcart's NumPy policy over the seeds' stacked rejax actor parameters (``params``)."""
    from jaxcart.rundir.policy import NumpyPolicy

    layers = {
        "hidden_0": p["features"]["Dense_0"],
        "hidden_1": p["features"]["Dense_1"],
        "out": p["action_logits"],
    }
    return NumpyPolicy(layers, "tanh", stacked=True)


def run(preset_name: str, num_seeds: int, quick: bool, cache_dir: str | None):
    """Trains ``num_seeds`` rejax PPO agents at SB3's settings (``preset_name`` ``sb3``) or at
    rejax's own CartPole configuration (``cartpole``).

    Returns:
        ``(data, policy)``: the timings and settings, and the seeds' stacked greedy policy
        for the harness to evaluate.
    """
    flag = "--xla_force_host_platform_device_count"
    if flag not in os.environ.get("XLA_FLAGS", ""):
        cores = len(os.sched_getaffinity(0))
        os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}={cores}".strip()
    try:
        import jax
        import jax.numpy as jnp
        import numpy as np
        from jax.sharding import Mesh, NamedSharding, PartitionSpec
        from rejax import PPO
    except ImportError as e:
        raise ChildUnavailable(f"rejax not installed in {sys.executable} ({e})") from None
    configure_jax_cache(cache_dir)

    configs = {"sb3": rejax_config, "cartpole": rejax_cartpole_config}
    if preset_name not in configs:
        raise ValueError(f"unknown rejax configuration {preset_name!r}")
    config = configs[preset_name](quick)
    t0 = time.perf_counter()
    algo = PPO.create(**config)
    algo = algo.replace(eval_callback=lambda algo, ts, rng: jnp.zeros(()))
    devs = jax.devices()
    count = max(d for d in range(1, len(devs) + 1) if num_seeds % d == 0)
    sharding = NamedSharding(Mesh(np.array(devs[:count]), ("seed",)), PartitionSpec("seed"))
    base = jax.random.PRNGKey(0)
    keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(num_seeds, dtype=jnp.uint32))
    keys = jax.device_put(keys, sharding)
    train = jax.jit(jax.vmap(algo.train))
    c0 = time.perf_counter()
    compiled = train.lower(keys).compile()
    t1, cpu1 = time.perf_counter(), time.process_time()
    ts, _ = compiled(keys)
    jax.block_until_ready(ts)
    t2, cpu2 = time.perf_counter(), time.process_time()

    data = {
        "num_seeds": num_seeds,
        "env_steps": int(np.sum(jax.device_get(ts.global_step))),
        "setup_seconds": t1 - t0,
        "compile_seconds": t1 - c0,
        "train_seconds": t2 - t1,
        "train_cpu_seconds": cpu2 - cpu1,
        "jax_devices": [str(d) for d in devs],
        "devices_used": count,
        "config": {k: v for k, v in config.items() if k != "env"},
        **({"differences_from_sb3": REJAX_DIFFERENCES} if preset_name == "sb3" else {}),
    }
    return data, greedy_policy(jax.device_get(ts.actor_ts.params["params"]))
