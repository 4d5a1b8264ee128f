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

from jaxcart import distributed
from jaxcart import env as cartpole
from jaxcart.config import PPOConfig
from jaxcart.ppo import METRIC_NAMES, Hyperparams, RunnerState, init_runner, train_chunk


def seed_keys(seed: int, num_seeds: int) -> jax.Array:
    """One PRNG key per seed index: ``fold_in(PRNGKey(seed), i)``, so seed index i's run does
    not depend on how many seeds train beside it."""
    base = jax.random.PRNGKey(seed)
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(num_seeds, dtype=jnp.uint32))


def seed_sharding(num_seeds: int, devices: list | None = None) -> NamedSharding:
    """Shards a leading seed axis over as many devices as divide ``num_seeds`` evenly.

    With several processes every device must take part: ``num_seeds`` must then be a multiple
    of ``jax.device_count()`` (the CLI checks this before starting).
    """
    devices = list(devices if devices is not None else jax.devices())
    if jax.process_count() > 1 and num_seeds % len(devices):
        raise ValueError(f"{num_seeds} runs cannot be split evenly over {len(devices)} devices")
    count = max(d for d in range(1, len(devices) + 1) if num_seeds % d == 0)
    mesh = Mesh(np.array(devices[:count]), ("seed",))
    return NamedSharding(mesh, PartitionSpec("seed"))


def init_runners(
    config: PPOConfig,
    num_seeds: int,
    seed: int,
    env_params: cartpole.EnvParams,
    seed_indices: np.ndarray | None = None,
) -> RunnerState:
    """Initial state of every run, leaves ``[S, ...]`` (NumPy; the caller places it).

    Run r draws from ``fold_in(PRNGKey(seed), seed_indices[r])`` (default ``r``); a sweep
    repeats the seed indices for every combination so combinations share random numbers.
    Built on the host with NumPy, the same distributions as :func:`jaxcart.ppo.init_runner`
    (orthogonal kernels with SB3's gains, zero biases, Adam state zero, resets uniform in
    the reset bounds) without compiling an initialisation program (seconds on CPU).
    """
    indices = np.arange(num_seeds) if seed_indices is None else np.asarray(seed_indices)
    keys = np.asarray(seed_keys(seed, int(indices.max()) + 1))[indices]
    template = jax.eval_shape(
        functools.partial(init_runner, config=config, env_params=env_params), keys[0]
    )
    dtype = np.dtype(template.obs.dtype)
    runs = []
    for key in keys:
        rng = np.random.default_rng([int(k) for k in key])
        params = host_init_params(rng, template.params)
        obs = rng.uniform(env_params.reset_low, env_params.reset_high, (config.num_envs, 4)).astype(
            dtype
        )
        runs.append((params, obs, rng.integers(0, 2**32, 2, dtype=np.uint32)))
    params = jax.tree.map(lambda *xs: np.stack(xs), *[r[0] for r in runs])
    obs = np.stack([r[1] for r in runs])
    zeros = lambda s: np.zeros((len(keys), *s.shape), s.dtype)
    steps = np.zeros((len(keys), config.num_envs), np.int32)
    return RunnerState(
        params=params,
        opt_state=jax.tree.map(zeros, template.opt_state),  # Adam's moments and count start at 0
        env_state=cartpole.EnvState(obs[..., 0], obs[..., 1], obs[..., 2], obs[..., 3], steps),
        obs=obs,
        episode_return=zeros(template.episode_return),
        episode_length=zeros(template.episode_length),
        episodes=jax.tree.map(zeros, template.episodes),
        key=np.stack([r[2] for r in runs]),
        diverged_at=np.full((len(keys),), -1, np.int32),
    )


def host_init_params(rng: np.random.Generator, shapes: dict) -> dict:
    """Actor-critic parameters with NumPy: orthogonal kernels (gain sqrt(2) for hidden
    layers, 0.01 for the policy head, 1 for the value head), zero biases."""

    def init(path, leaf):
        names = [getattr(p, "key", str(p)) for p in path]
        if names[-1] == "bias":
            return np.zeros(leaf.shape, leaf.dtype)
        gain = {"actor": 0.01, "critic": 1.0}[names[-3]] if names[-2] == "out" else np.sqrt(2.0)
        return (gain * orthogonal_matrix(rng, leaf.shape)).astype(leaf.dtype)

    return jax.tree_util.tree_map_with_path(init, shapes)


def orthogonal_matrix(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """A Haar-random matrix with orthonormal rows or columns (QR of a Gaussian matrix)."""
    rows, cols = max(shape), min(shape)
    q, r = np.linalg.qr(rng.standard_normal((rows, cols)))
    q = q * np.sign(np.diag(r))
    return q if shape[0] >= shape[1] else q.T


def default_chunk_size(num_iterations: int, updates: int = 20) -> int:
    """Iterations per compiled chunk so that progress is reported about ``updates`` times,
    preferably a divisor of ``num_iterations`` (then the chunk needs no end-of-run guard)."""
    target = max(1, -(-num_iterations // updates))
    divisors = [d for d in range(max(1, target // 2), 2 * target + 1) if num_iterations % d == 0]
    return min(divisors, key=lambda d: abs(d - target)) if divisors else target


METRIC_COLUMNS = (*METRIC_NAMES, "time/fps", "time/elapsed")
"""Every per-iteration metric a run records, leaves ``[iterations, S]``."""


@dataclass
class TrainState:
    """Everything needed to continue a run: per-seed state (leaves ``[S, ...]``), the
    hyperparameters, iterations done, seconds of training so far and the metrics so far."""

    runners: RunnerState
    hyperparams: Hyperparams
    iteration: int
    elapsed: float
    metrics: dict[str, np.ndarray]  # METRIC_COLUMNS -> [iteration, S]
    chunk_size: int


@dataclass
class Progress:
    """What the host knows after each chunk (passed to the ``on_chunk`` callback)."""

    iteration: int  # iterations completed
    num_iterations: int
    env_steps: int  # per seed
    elapsed: float  # seconds of training so far (resumed runs include earlier sessions)
    metrics: dict[str, np.ndarray]  # this chunk's metrics, leaves [iterations_in_chunk, S]
    state: Callable[[], TrainState]  # the full state now (valid only during the callback)
    diverged_at: np.ndarray  # [S] int: -1, or the iteration at which that run went non-finite


@dataclass
class TrainResult:
    """Outcome of :func:`train`: final per-seed state, metrics ``[iterations, S]`` and timings."""

    config: PPOConfig
    num_seeds: int
    seed: int
    state: TrainState
    compile_seconds: float
    run_seconds: float  # this session's training time, compile excluded
    num_devices: int
    stopped: bool = False  # interrupted before num_iterations (resumable from ``state``)
    extra: dict = field(default_factory=dict)

    @property
    def runners(self) -> RunnerState:
        return self.state.runners

    @property
    def metrics(self) -> dict[str, np.ndarray]:
        return self.state.metrics

    @property
    def env_steps(self) -> int:
        """Environment steps taken in this session, all seeds together."""
        return (
            (self.state.iteration - self.extra.get("start_iteration", 0))
            * self.config.batch_size
            * self.num_seeds
        )

    @property
    def params(self) -> dict:
        """Network parameters with a leading seed axis ``[S, ...]``."""
        return self.state.runners.params


def broadcast_hyperparams(config: PPOConfig, num_seeds: int) -> Hyperparams:
    """The config's float hyperparameters repeated for every seed, leaves ``[S]``."""
    hp = Hyperparams.from_config(config)
    return jax.tree.map(lambda x: jnp.full((num_seeds,), x, x.dtype), hp)


def initial_state(
    config: PPOConfig,
    num_seeds: int,
    seed: int,
    hyperparams: Hyperparams | None = None,
    env_params: cartpole.EnvParams | None = None,
    chunk_size: int | None = None,
    seed_indices: np.ndarray | None = None,
) -> TrainState:
    """The state before the first iteration (also the template a checkpoint is loaded into)."""
    env_params = env_params or cartpole.EnvParams()
    hps = hyperparams if hyperparams is not None else broadcast_hyperparams(config, num_seeds)
    return TrainState(
        runners=init_runners(config, num_seeds, seed, env_params, seed_indices),
        hyperparams=hps,
        iteration=0,
        elapsed=0.0,
        metrics={k: np.zeros((0, num_seeds), np.float32) for k in METRIC_COLUMNS},
        chunk_size=chunk_size or default_chunk_size(config.num_iterations),
    )


def train(
    config: PPOConfig,
    num_seeds: int = 1,
    seed: int = 0,
    *,
    hyperparams: Hyperparams | None = None,
    env_params: cartpole.EnvParams | None = None,
    chunk_size: int | None = None,
    devices: list | None = None,
    resume: TrainState | None = None,
    on_compiled: Callable[[float], None] | None = None,
    on_chunk: Callable[[Progress], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    seed_indices: np.ndarray | None = None,
) -> TrainResult:
    """Trains ``num_seeds`` independent PPO agents in one compiled program.

    Args:
        config: shapes and (default) hyperparameters.
        num_seeds: independent runs, a vmap axis sharded over ``devices``.
        seed: base seed; run i uses ``fold_in(PRNGKey(seed), seed_indices[i])``.
        hyperparams: per-run float hyperparameters with leaves ``[num_seeds]`` (a sweep);
            defaults to the config's values for every run.
        chunk_size: iterations per compiled call between progress reports.
        resume: continue from this state (e.g. a loaded checkpoint) instead of starting anew;
            the result is bit-identical to a run that was never interrupted.
        on_compiled: called with the compile time in seconds.
        on_chunk: called with a :class:`Progress` after every chunk.
        should_stop: polled after every chunk; when it returns True training stops early with
            ``TrainResult.stopped`` set and a resumable state.
        seed_indices: per-run seed index (default ``arange(num_seeds)``).
    """
    env_params = env_params or cartpole.EnvParams()
    state = resume or initial_state(
        config, num_seeds, seed, hyperparams, env_params, chunk_size, seed_indices
    )
    chunk_size = state.chunk_size
    sharding = seed_sharding(num_seeds, devices)
    runners = distributed.to_global(state.runners, sharding)
    hps = distributed.to_global(state.hyperparams, sharding)

    start = time.perf_counter()
    compiled, fresh = compiled_chunk(config, env_params, chunk_size, runners, hps)
    compile_seconds = time.perf_counter() - start
    if on_compiled:
        on_compiled(compile_seconds)

    chunks = [state.metrics]
    done, start_iteration, elapsed_before = state.iteration, state.iteration, state.elapsed
    stopped = False
    run_start = time.perf_counter()
    while done < config.num_iterations:
        # every process must agree, or one would wait forever for the others' next chunk
        if should_stop is not None and distributed.any_process(should_stop()):
            stopped = True
            break
        runners, metrics = compiled(runners, hps, jnp.int32(done))
        metrics = distributed.gather(metrics)
        now = elapsed_before + time.perf_counter() - run_start
        take = min(chunk_size, config.num_iterations - done)
        metrics = {k: np.asarray(v[:take]) for k, v in metrics.items()}
        # time/fps as SB3 logs it (steps of this seed / seconds since start); inside a chunk
        # the iterations are timed by spreading the chunk's time evenly.
        prev = float(chunks[-1]["time/elapsed"][-1, 0]) if len(chunks[-1]["time/elapsed"]) else 0.0
        elapsed = prev + (now - prev) * np.arange(1, take + 1) / take
        steps = (done + np.arange(1, take + 1)) * config.batch_size
        metrics["time/fps"] = np.repeat((steps / elapsed)[:, None], num_seeds, 1).astype(np.float32)
        metrics["time/elapsed"] = np.repeat(elapsed[:, None], num_seeds, 1).astype(np.float32)
        chunks.append(metrics)
        done += take

        def snapshot(runners=runners, done=done, now=now) -> TrainState:
            return TrainState(runners, hps, done, now, _concat(chunks), chunk_size)

        if on_chunk:
            diverged = np.asarray(distributed.gather(runners.diverged_at))
            on_chunk(
                Progress(
                    done,
                    config.num_iterations,
                    done * config.batch_size,
                    now,
                    metrics,
                    snapshot,
                    diverged,
                )
            )
    jax.block_until_ready(runners)
    run_seconds = time.perf_counter() - run_start
    final = TrainState(
        runners, hps, done, elapsed_before + run_seconds, _concat(chunks), chunk_size
    )
    return TrainResult(
        config=config,
        num_seeds=num_seeds,
        seed=seed,
        state=final,
        compile_seconds=compile_seconds,
        run_seconds=run_seconds,
        num_devices=len(sharding.mesh.devices.flat),
        stopped=stopped,
        extra={"start_iteration": start_iteration, "compiled": fresh},
    )


_COMPILED: dict = {}


def compiled_chunk(
    config: PPOConfig, env_params: cartpole.EnvParams, chunk_size: int, runners, hps
) -> tuple[Callable, bool]:
    """The compiled :func:`~jaxcart.ppo.train_chunk` for these shapes and devices.

    Kept per process, keyed by everything that shapes the program (config, env constants,
    chunk size, the runs' array shapes and shardings) but not by the traced float
    hyperparameters: new learning rates, clip ranges, ... reuse the same executable.

    Returns:
        ``(compiled, fresh)`` where ``fresh`` says whether it was compiled just now.
    """
    signature = tuple(
        (leaf.shape, str(leaf.dtype), str(leaf.sharding))
        for leaf in jax.tree.leaves((runners, hps))
    )
    key = (config, env_params, chunk_size, signature)
    if key in _COMPILED:
        return _COMPILED[key], False
    local = functools.partial(
        train_chunk, config=config, env_params=env_params, chunk_size=chunk_size
    )
    sharding = jax.tree.leaves(runners)[0].sharding
    if isinstance(sharding, NamedSharding) and sharding.mesh.size > 1:
        # Every device runs the same program on its own seeds with no communication: say so
        # with shard_map rather than leaving it to the SPMD partitioner (faster to compile).
        spec = sharding.spec
        local = jax.shard_map(
            local,
            mesh=sharding.mesh,
            in_specs=(spec, spec, PartitionSpec()),
            out_specs=(spec, PartitionSpec(None, *spec)),
            check_vma=False,  # per-seed metrics vs the skip branch's constants
        )
    chunk = jax.jit(local, donate_argnums=0)
    _COMPILED[key] = chunk.lower(runners, hps, jnp.int32(0)).compile()
    return _COMPILED[key], True


def _concat(chunks: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    return {k: np.concatenate([c[k] for c in chunks]) for k in METRIC_COLUMNS}
