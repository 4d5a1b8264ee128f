"""Host side of training: builds the seed batch, shards it over devices, compiles the fused
chunk once (timed on its own), and runs it chunk by chunk so progress can be reported.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxcart import env as cartpole
from jaxcart.config import PPOConfig
from jaxcart.ppo import METRIC_NAMES, Hyperparams, RunnerState, init_runner, train_chunk


def seed_keys(seed: int, num_seeds: int) -> jax.Array:
    """One PRNG key per seed index: ``fold_in(PRNGKey(seed), i)``, so seed index i's run does
    not depend on how many seeds train beside it."""
    base = jax.random.PRNGKey(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(num_seeds, dtype=jnp.uint32))


def seed_sharding(num_seeds: int, devices: list | None = None) -> NamedSharding:
    """Shards a leading seed axis over as many devices as divide ``num_seeds`` evenly."""
    devices = list(devices if devices is not None else jax.devices())
    count = max(d for d in range(1, len(devices) + 1) if num_seeds % d == 0)
    mesh = Mesh(np.array(devices[:count]), ("seed",))
    return NamedSharding(mesh, PartitionSpec("seed"))


def init_runners(
    config: PPOConfig, num_seeds: int, seed: int, env_params: cartpole.EnvParams
) -> RunnerState:
    """Initial state of every seed, leaves ``[S, ...]``, built on one device.

    Not sharded on purpose: the orthogonal initialiser's batched QR runs on jaxlib's LAPACK
    kernel, whose parallel batch loop can deadlock when two CPU devices run it at once
    (seen with jaxlib 0.10.2); the result is placed on the devices afterwards.
    """
    init = jax.jit(jax.vmap(functools.partial(init_runner, config=config, env_params=env_params)))
    return init(seed_keys(seed, num_seeds))


def default_chunk_size(num_iterations: int, updates: int = 20) -> int:
    """Iterations per compiled chunk so that progress is reported about ``updates`` times."""
    return max(1, -(-num_iterations // updates))


@dataclass
class Progress:
    """What the host knows after each chunk (passed to the ``on_chunk`` callback)."""

    iteration: int  # iterations completed
    num_iterations: int
    env_steps: int  # per seed
    elapsed: float  # seconds of running, compile excluded
    metrics: dict[str, np.ndarray]  # this chunk's metrics, leaves [iterations_in_chunk, S]


@dataclass
class TrainResult:
    """Outcome of :func:`train`: final per-seed state, metrics ``[iterations, S]`` and timings."""

    config: PPOConfig
    num_seeds: int
    seed: int
    runners: RunnerState
    metrics: dict[str, np.ndarray]
    compile_seconds: float
    run_seconds: float
    num_devices: int
    extra: dict = field(default_factory=dict)

    @property
    def env_steps(self) -> int:
        """Environment steps taken, all seeds together."""
        return self.config.env_steps_per_seed * self.num_seeds

    @property
    def params(self) -> dict:
        """Network parameters with a leading seed axis ``[S, ...]``."""
        return self.runners.params


def broadcast_hyperparams(config: PPOConfig, num_seeds: int) -> Hyperparams:
    """The config's float hyperparameters repeated for every seed, leaves ``[S]``."""
    hp = Hyperparams.from_config(config)
    return jax.tree.map(lambda x: jnp.full((num_seeds,), x, x.dtype), hp)


def train(
    config: PPOConfig,
    num_seeds: int = 1,
    seed: int = 0,
    *,
    hyperparams: Hyperparams | None = None,
    env_params: cartpole.EnvParams | None = None,
    chunk_size: int | None = None,
    devices: list | None = None,
    on_compiled: Callable[[float], None] | None = None,
    on_chunk: Callable[[Progress], None] | None = None,
) -> TrainResult:
    """Trains ``num_seeds`` independent PPO agents in one compiled program.

    Args:
        config: shapes and (default) hyperparameters.
        num_seeds: independent runs, a vmap axis sharded over ``devices``.
        seed: base seed; run i uses ``fold_in(PRNGKey(seed), i)``.
        hyperparams: per-run float hyperparameters with leaves ``[num_seeds]`` (a sweep);
            defaults to the config's values for every run.
        chunk_size: iterations per compiled call between progress reports.
        on_compiled: called with the compile time in seconds.
        on_chunk: called with a :class:`Progress` after every chunk.
    """
    env_params = env_params or cartpole.EnvParams()
    chunk_size = chunk_size or default_chunk_size(config.num_iterations)
    sharding = seed_sharding(num_seeds, devices)
    hps = hyperparams if hyperparams is not None else broadcast_hyperparams(config, num_seeds)

    runners = jax.device_put(init_runners(config, num_seeds, seed, env_params), sharding)
    hps = jax.device_put(hps, sharding)

    chunk = jax.jit(
        functools.partial(train_chunk, config=config, env_params=env_params, chunk_size=chunk_size),
        donate_argnums=0,
    )
    start = time.perf_counter()
    compiled = chunk.lower(runners, hps, jnp.int32(0)).compile()
    compile_seconds = time.perf_counter() - start
    if on_compiled:
        on_compiled(compile_seconds)

    chunks: list[dict[str, np.ndarray]] = []
    run_start = time.perf_counter()
    done = 0
    while done < config.num_iterations:
        runners, metrics = compiled(runners, hps, jnp.int32(done))
        metrics = jax.device_get(metrics)
        now = time.perf_counter() - run_start
        take = min(chunk_size, config.num_iterations - done)
        metrics = {k: np.asarray(v[:take]) for k, v in metrics.items()}
        # time/fps as SB3 logs it (steps of this seed / seconds since start); inside a chunk
        # the iterations are timed by spreading the chunk's time evenly.
        prev = chunks[-1]["_elapsed"][-1] if chunks else 0.0
        elapsed = prev + (now - prev) * np.arange(1, take + 1) / take
        steps = (done + np.arange(1, take + 1)) * config.batch_size
        metrics["time/fps"] = np.repeat((steps / elapsed)[:, None], num_seeds, axis=1).astype(
            np.float32
        )
        metrics["_elapsed"] = elapsed
        chunks.append(metrics)
        done += take
        if on_chunk:
            on_chunk(
                Progress(
                    iteration=done,
                    num_iterations=config.num_iterations,
                    env_steps=done * config.batch_size,
                    elapsed=now,
                    metrics={k: v for k, v in metrics.items() if not k.startswith("_")},
                )
            )
    jax.block_until_ready(runners)
    run_seconds = time.perf_counter() - run_start
    names = list(METRIC_NAMES) + ["time/fps"]
    all_metrics = {k: np.concatenate([c[k] for c in chunks]) for k in names}
    elapsed = np.concatenate([c["_elapsed"] for c in chunks])
    all_metrics["time/elapsed"] = np.repeat(elapsed[:, None], num_seeds, axis=1)
    return TrainResult(
        config=config,
        num_seeds=num_seeds,
        seed=seed,
        runners=runners,
        metrics=all_metrics,
        compile_seconds=compile_seconds,
        run_seconds=run_seconds,
        num_devices=len(sharding.mesh.devices.flat),
    )
