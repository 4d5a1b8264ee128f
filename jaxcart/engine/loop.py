"""Host side of training: builds the batch of runs, shards it over devices, compiles the fused
chunk once (timed on its own), and runs it chunk by chunk so progress can be reported.

This is the engine under :mod:`jaxcart.run.lifecycle`: it knows runs (the vmapped axis), not run
directories, combinations or printing. A run is one independent agent; without a sweep the
runs are the seeds.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxcart.core import envs, physics
from jaxcart.core.config import PPOConfig, float_dtype
from jaxcart.core.metrics import METRIC_NAMES
from jaxcart.core.ppo import RunnerState, make_network
from jaxcart.core.pytree import split_per_run, with_values
from jaxcart.engine import distributed
from jaxcart.engine.chunk import UPDATE_GROUP, initial_runners, roll_back_diverged, train_chunk
from jaxcart.engine.signals import wait_interruptibly


def seed_index_keys(seed: int, indices: np.ndarray) -> np.ndarray:
    """One PRNG key per seed index, ``fold_in(PRNGKey(seed), i)``, as NumPy ``[len(indices),
    2]`` uint32: seed index i's run does not depend on how many seeds train beside it, and a
    wave far into a million seeds draws only its own keys."""
    base = jax.random.PRNGKey(seed)
    fold = jax.vmap(lambda i: jax.random.fold_in(base, i))
    return np.asarray(fold(jnp.asarray(np.asarray(indices), dtype=jnp.uint32)))


def init_runners(
    config: PPOConfig,
    seed: int,
    seed_indices: np.ndarray,
    env_params: Any = None,
    on_progress: Callable[[int, int], None] | None = None,
    episode_ranges: dict[str, tuple[float, float]] | None = None,
) -> RunnerState:
    """Initial state of every run, NumPy leaves ``[R, ...]`` (the caller places them).

    Run r draws from ``fold_in(PRNGKey(seed), seed_indices[r])``: seed index i starts the same
    whatever runs beside it, and a sweep repeats the seed indices for every combination so
    combinations share random numbers. The built-in network and, for an env with a
    ``host_reset`` (CartPole), the first episodes are drawn on the host (:meth:`ActorCritic.host_init
    <jaxcart.core.networks.ActorCritic.host_init>`), so there is no initialisation program to
    compile; another env resets in one compiled call; another
    flax network is initialised by its own ``init``, all runs in one call. ``on_progress(done, total)`` is called every
    1024 runs (it may raise to abandon the initialisation). With ``episode_ranges``
    (``{field: (low, high)}``), every env's physics are drawn per episode: the env state is a
    :class:`~jaxcart.core.physics.EpisodeState` whose first values come from the run's host
    generator after everything else it draws (so the other draws are the same).
    """
    env = envs.make(config.env)
    env_params = split_per_run(env_params or env.default_params())[0]
    keys = seed_index_keys(seed, seed_indices)
    reset_obs = jax.eval_shape(env.reset, jax.random.PRNGKey(0), env_params)[0]
    dtype, obs_dim = reset_obs.dtype, reset_obs.shape[-1]
    network = make_network(config)
    on_host = hasattr(network, "host_init")  # the built-in MLP: SB3's initialisation in NumPy
    params, init_seeds, starts, run_keys, episodes = [], [], [], [], []
    for i, key in enumerate(keys):
        if on_progress is not None and i % 1024 == 0:
            on_progress(i, len(keys))
        rng = np.random.default_rng([int(k) for k in key])
        if on_host:
            params.append(network.host_init(rng, obs_dim, dtype))  # float64 under x64, as the env
        else:
            init_seeds.append(rng.integers(0, 2**31))
        if env.host_reset is not None:  # the env draws its first episodes here: no program
            starts.append(env.host_reset(rng, env_params, config.num_envs, dtype))
        else:  # a key per env for the env's own reset
            starts.append(rng.integers(0, 2**32, (config.num_envs, 2), dtype=np.uint32))
        run_keys.append(rng.integers(0, 2**32, 2, dtype=np.uint32))
        if episode_ranges:
            n = config.num_envs
            episodes.append({k: rng.uniform(lo, hi, n) for k, (lo, hi) in episode_ranges.items()})
    stack = functools.partial(jax.tree.map, lambda *xs: np.stack(xs))
    if on_host:
        stacked = stack(*params)
    else:  # flax's own initialisation, every run's in one compiled call
        example = jnp.zeros((1, obs_dim), dtype)
        init = jax.jit(jax.vmap(lambda seed: network.init(jax.random.PRNGKey(seed), example)))
        stacked = jax.tree.map(np.asarray, dict(init(jnp.asarray(init_seeds, jnp.uint32))))
    if env.host_reset is not None:
        first_obs, env_state = stack(*starts)
    else:
        first_obs, env_state = reset_envs(env, np.stack(starts), env_params)
    if episode_ranges:
        values = {k: np.stack([e[k] for e in episodes]) for k in episode_ranges}
        env_state = physics.episode_state(env_state, values, episode_ranges, first_obs.dtype)
    return initial_runners(stacked, first_obs, np.stack(run_keys), config, env_state)


def reset_envs(env: envs.Env, keys: np.ndarray, env_params: Any) -> tuple[np.ndarray, Any]:
    """``env.reset`` of every env of every run from raw keys ``[R, num_envs, 2]``: observations
    ``[R, num_envs, obs_dim]`` and the state pytree (leaves ``[R, num_envs]``), in NumPy."""
    reset = jax.vmap(jax.vmap(env.reset, in_axes=(0, None)), in_axes=(0, None))
    obs, state = jax.jit(reset)(jnp.asarray(keys), env_params)
    # the step counters the scan carries as int32 whatever type the env's reset gave them
    state = jax.tree.map(
        lambda x: np.asarray(x, np.int32 if x.dtype.kind in "iu" else x.dtype), state
    )
    return np.asarray(obs), state


CHUNK_SECONDS = 2.0
"""The wall time a chunk aims at when its length adapts (the default): a stop request, a
checkpoint due and the progress bar wait at most about this long, whatever the run's size."""
MAX_CHUNK_ITERATIONS = 1024
CHUNK_METRICS_BYTES = 64 << 20  # the chunk's metrics buffer [chunk_size, R] stays below this


def default_chunk_size(num_iterations: int, num_runs: int = 1) -> int:
    """The capacity of an adaptive chunk (the most iterations one compiled call can run), in
    constant time whatever ``num_iterations``: at most :data:`MAX_CHUNK_ITERATIONS`, and
    small enough that its metrics ``[chunk_size, num_runs]`` stay under
    :data:`CHUNK_METRICS_BYTES`. How many of them each call runs is set from the time the
    previous call took (:data:`CHUNK_SECONDS`)."""
    per_iteration = max(1, num_runs) * len(METRIC_NAMES) * 4
    return max(1, min(num_iterations, MAX_CHUNK_ITERATIONS, CHUNK_METRICS_BYTES // per_iteration))


def next_chunk_length(capacity: int, previous: int, seconds: float, target: float) -> int:
    """How many iterations the next adaptive chunk runs: enough to take about ``target``
    seconds at the pace of the previous chunk (``previous`` iterations in ``seconds``),
    growing at most eightfold at a time, within ``[1, capacity]``."""
    pace = seconds / max(1, previous)
    wanted = int(target / pace) if pace > 0 else capacity
    return max(1, min(capacity, 8 * previous, wanted))


METRIC_COLUMNS = (*METRIC_NAMES, "time/fps", "time/elapsed")
"""Every per-iteration metric a run of the default config records, leaves ``[iterations, R]``."""


def metric_columns(config: PPOConfig) -> tuple[str, ...]:
    """Every per-iteration metric a run of ``config`` records: :data:`METRIC_COLUMNS`, then
    the periodic evaluation's and the config's own metrics (``config.extra_metric_names``)."""
    return (*METRIC_COLUMNS, *config.extra_metric_names)


@dataclass
class TrainState:
    """Everything needed to continue training: per-run state (leaves ``[R, ...]``), every
    run's config (traced fields ``[R]``), iterations done, seconds of training so far and the
    metrics so far."""

    runners: RunnerState
    config: PPOConfig
    iteration: int
    elapsed: float
    metrics: dict[str, np.ndarray]  # METRIC_COLUMNS -> [iteration, R] ({}: kept elsewhere)
    chunk_size: int  # the most iterations one compiled call runs
    chunk_seconds: float | None = None  # None: every call runs chunk_size; else adapts to this


@dataclass
class Progress:
    """What the host knows after each chunk (passed to the ``on_chunk`` callback)."""

    iteration: int  # iterations completed
    num_iterations: int
    env_steps: int  # per run
    elapsed: float  # seconds of training so far (resumed runs include earlier sessions)
    metrics: dict[str, np.ndarray]  # this chunk's metrics, leaves [iterations_in_chunk, R]
    state: Callable[[], TrainState]  # the full state now (valid only during the callback)
    diverged_at: np.ndarray  # [R] int: -1, or the iteration at which that run went non-finite


@dataclass
class TrainResult:
    """Outcome of :func:`train`: final state of every run, metrics ``[iterations, R]``, timings."""

    config: PPOConfig
    state: TrainState
    compile_seconds: float
    run_seconds: float  # this session's training time, compile excluded
    num_devices: int
    start_iteration: int  # where this session started (> 0 when resumed)
    compiled: bool  # whether this call compiled the program (False: reused in-process)
    stopped: bool = False  # interrupted before num_iterations (resumable from ``state``)

    @property
    def num_runs(self) -> int:
        return int(self.state.runners.diverged_at.shape[0])

    @property
    def runners(self) -> RunnerState:
        return self.state.runners

    @property
    def metrics(self) -> dict[str, np.ndarray]:
        return self.state.metrics

    @property
    def env_steps(self) -> int:
        """Environment steps taken in this session, all runs together."""
        return (
            (self.state.iteration - self.start_iteration) * self.config.batch_size * self.num_runs
        )

    @property
    def params(self) -> dict:
        """Network parameters with a leading run axis ``[R, ...]``."""
        return self.state.runners.params


def initial_state(
    config: PPOConfig,
    num_runs: int,
    seed: int,
    env_params: Any = None,
    chunk_size: int | None = None,
    seed_indices: np.ndarray | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    episode_ranges: dict[str, tuple[float, float]] | None = None,
) -> TrainState:
    """The state before the first iteration (also the template a checkpoint is loaded into).

    ``config``'s traced fields are floats (every run the same) or arrays ``[num_runs]`` (a
    value per run: :meth:`PPOConfig.per_run`).

    ``seed_indices`` defaults to ``arange(num_runs)`` (every run its own seed index);
    ``on_progress`` and ``episode_ranges`` as in :func:`init_runners`. Without
    ``chunk_size`` the chunks adapt their length to take about :data:`CHUNK_SECONDS` each;
    with it, every chunk runs that many iterations. Neither changes a number (only when the
    host looks).
    """
    indices = np.arange(num_runs) if seed_indices is None else np.asarray(seed_indices)
    return TrainState(
        runners=init_runners(config, seed, indices, env_params, on_progress, episode_ranges),
        config=config.per_run(num_runs),
        iteration=0,
        elapsed=0.0,
        metrics={k: np.zeros((0, num_runs), np.float32) for k in metric_columns(config)},
        chunk_size=chunk_size or default_chunk_size(config.num_iterations, num_runs),
        # several processes must run the same chunk lengths: they keep fixed chunks
        chunk_seconds=None if chunk_size or jax.process_count() > 1 else CHUNK_SECONDS,
    )


def train(
    config: PPOConfig,
    num_runs: int = 1,
    seed: int = 0,
    *,
    env_params: Any = None,
    chunk_size: int | None = None,
    devices: list | None = None,
    resume: TrainState | None = None,
    on_compiled: Callable[[float], None] | None = None,
    on_chunk: Callable[[Progress], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    seed_indices: np.ndarray | None = None,
    runs_per_device: int | None = None,
    keep_metrics: bool = True,
    episode_ranges: dict[str, tuple[float, float]] | None = None,
) -> TrainResult:
    """Trains ``num_runs`` independent PPO agents in one compiled program.

    Args:
        config: the runs' config; its traced fields are floats (every run the same) or
            arrays ``[num_runs]`` with one value per run (a sweep: :meth:`PPOConfig.per_run`).
        num_runs: independent runs, a vmap axis sharded over ``devices``.
        seed: base seed; run r uses ``fold_in(PRNGKey(seed), seed_indices[r])``.
        env_params: the env's params (default its ``default_params()``); a
            :func:`~jaxcart.core.pytree.per_run_field` may hold an array ``[num_runs]``, one
            value per run (a physics sweep or randomisation), which the program takes as an
            argument: other values reuse the executable.
        chunk_size: iterations per compiled call between progress reports (default: calls
            that adapt to take about :data:`CHUNK_SECONDS` each).
        resume: continue from this state (e.g. a loaded checkpoint), bit-identically.
        on_compiled, on_chunk: called with the compile seconds; with a :class:`Progress`
            after every chunk.
        should_stop: polled before every chunk; when it returns True training stops early
            with ``TrainResult.stopped`` set and a resumable state.
        seed_indices: per-run seed index (default ``arange(num_runs)``).
        runs_per_device: pad the run axis to at least this many runs per device (a run's
            numbers depend on that width only: padding replays one seed bit for bit).
        keep_metrics: keep every iteration's metrics (``TrainResult.metrics``); False: only
            ``on_chunk`` sees them, so memory does not grow with the run (they are ``{}``).
        episode_ranges: ``{field: (low, high)}``: draw these physics fields uniformly at
            every reset (:func:`init_runners`); ignored with ``resume``, whose state has them.
    """
    env_params = env_params or envs.make(config.env).default_params()
    state = resume or initial_state(
        config, num_runs, seed, env_params, chunk_size, seed_indices, None, episode_ranges
    )
    devices = _devices(devices, num_runs, runs_per_device)
    runners, run_configs = place((state.runners, state.config), devices, num_runs, runs_per_device)
    env_params = place_env_params(env_params, devices, num_runs, runs_per_device)

    start = time.perf_counter()
    compiled, fresh = None, False
    if state.iteration < config.num_iterations:  # a finished state needs no program
        sizes = (state.chunk_size, runners, run_configs, state.chunk_seconds)
        compiled, fresh = wait_interruptibly(lambda: compiled_chunk(env_params, *sizes))
    compile_seconds = time.perf_counter() - start
    if on_compiled:
        on_compiled(compile_seconds)

    # the host's bookkeeping between chunks: iterations done, training time and, when kept,
    # every chunk's metrics (after the state's own, if it has any: a state loaded from a
    # checkpoint has none, they are in its run directory's stream), with SB3's time/fps and
    # time/elapsed added
    columns, chunk_seconds = metric_columns(config), state.chunk_seconds
    empty = {k: np.zeros((0, num_runs), np.float32) for k in columns}
    chunks = [state.metrics or empty] if keep_metrics else None
    count = 1 if chunk_seconds else state.chunk_size  # the next call's iterations
    done, previous_elapsed, stopped = state.iteration, state.elapsed, False
    last = start = time.perf_counter()

    def snapshot(runners: RunnerState, done: int, now: float) -> TrainState:
        """The state of the real runs (device arrays with the padding sliced off)."""
        real = functools.partial(jax.tree.map, lambda x: x[:num_runs])
        metrics = {k: np.concatenate([c[k] for c in chunks]) for k in columns} if chunks else {}
        sizes = (state.chunk_size, chunk_seconds)
        return TrainState(real(runners), real(run_configs), done, now, metrics, *sizes)

    while done < config.num_iterations:
        # every process must agree, or one would wait forever for the others' next chunk
        if should_stop is not None and distributed.any_process(should_stop()):
            stopped = True
            break
        end, metrics = compiled(runners, run_configs, jnp.int32(done), jnp.int32(count))
        # waits for the chunk on a worker thread, so that signals are handled meanwhile
        metrics = wait_interruptibly(functools.partial(distributed.gather, metrics))
        now = state.elapsed + time.perf_counter() - start
        take = min(count, config.num_iterations - done)
        if chunk_seconds:
            seconds, last = time.perf_counter() - last, time.perf_counter()
            count = next_chunk_length(state.chunk_size, take, seconds, chunk_seconds)
        metrics = {k: np.asarray(v[:take, :num_runs]) for k, v in metrics.items()}
        # time/fps as SB3 logs it (steps of this run / seconds since start); inside a chunk
        # the iterations are timed by spreading the chunk's time evenly.
        elapsed = previous_elapsed + (now - previous_elapsed) * np.arange(1, take + 1) / take
        previous_elapsed = float(elapsed[-1])
        steps = (done + np.arange(1, take + 1)) * config.batch_size
        metrics["time/fps"] = np.repeat((steps / elapsed)[:, None], num_runs, 1).astype(np.float32)
        metrics["time/elapsed"] = np.repeat(elapsed[:, None], num_runs, 1).astype(np.float32)
        if chunks is not None:
            chunks.append(metrics)
        done += take
        diverged = np.asarray(distributed.gather(end.diverged_at))
        # rolled back on the host, only once a run has diverged: the chunk carries no rollback
        runners = roll_back_diverged(runners, end) if (diverged >= 0).any() else end
        if on_chunk:
            snap = functools.partial(snapshot, runners, done, now)
            args = (done, config.num_iterations, done * config.batch_size, now, metrics, snap)
            on_chunk(Progress(*args, diverged[:num_runs]))
    jax.block_until_ready(runners)
    final = snapshot(runners, done, state.elapsed + time.perf_counter() - start)
    return TrainResult(
        config=config,
        state=final,
        compile_seconds=compile_seconds,
        run_seconds=final.elapsed - state.elapsed,
        num_devices=len(devices),
        start_iteration=state.iteration,
        compiled=fresh,
        stopped=stopped,
    )


def _devices(devices: list | None, num_runs: int, runs_per_device: int | None) -> list:
    """All devices; or, with fewer runs than devices in one process, one device per run."""
    devices = list(devices if devices is not None else jax.devices())
    if num_runs < len(devices) and not runs_per_device and jax.process_count() == 1:
        return devices[:num_runs]
    return devices


def place(tree: Any, devices: list, num_runs: int, runs_per_device: int | None) -> Any:
    """Host arrays ``[num_runs, ...]`` (the runs' state, their configs) sharded over
    ``devices`` (every device of every process) along the run axis, padded so that every
    device takes an equal share (at least ``runs_per_device``): the padding runs, copies of
    the last run, are computed and discarded."""
    padded = max(-(-num_runs // len(devices)), runs_per_device or 0) * len(devices)

    def pad(x: Any) -> np.ndarray:
        x = np.asarray(x)
        extra = padded - x.shape[0]
        return x if extra == 0 else np.concatenate([x, np.repeat(x[-1:], extra, axis=0)])

    sharding = NamedSharding(Mesh(np.array(devices), ("runs",)), PartitionSpec("runs"))
    return distributed.to_global(jax.tree.map(pad, tree), sharding)


def place_env_params(
    env_params: Any, devices: list, num_runs: int, runs_per_device: int | None
) -> Any:
    """``env_params`` with its per-run fields (arrays ``[num_runs]``, if any) in the training's
    float type, padded and placed as :func:`place` places the runs; unchanged without them."""
    static, per_run = split_per_run(env_params)
    for name, values in per_run.items():
        if np.shape(values) != (num_runs,):
            raise ValueError(f"env param {name} holds {np.shape(values)}; expected ({num_runs},)")
    if not per_run:
        return env_params
    arrays = {n: np.asarray(v, float_dtype()) for n, v in per_run.items()}
    return with_values(static, place(arrays, devices, num_runs, runs_per_device))


_COMPILED: dict = {}


def compiled_chunk(
    env_params: Any,
    chunk_size: int,
    runners: RunnerState,
    config: PPOConfig,
    chunk_seconds: float | None = None,
) -> tuple[Callable, bool]:
    """The compiled :func:`~jaxcart.engine.chunk.train_chunk` for these shapes and devices.

    Kept per process, keyed by what shapes the program: the config's pytree structure (its
    static fields), the env and its constants, the chunk size and the array shapes and shardings of
    the runners and of the config's traced fields (``[R]``). The traced values are not part
    of the key (nor of the program): new learning rates, clip ranges, ... reuse the same
    executable. So are env params that differ between runs (arrays ``[R]`` on
    ``env_params``, placed as the runners): the returned callable passes them to the program,
    whose key holds only their names. The program takes ``(runners, config, start_iteration, count)``; ``count``
    (how many of the chunk's iterations run) is honoured when ``chunk_seconds`` is set
    (adaptive chunks), else every call runs ``chunk_size`` iterations.

    Returns:
        ``(compiled, fresh)`` where ``fresh`` says whether it was compiled just now.
    """
    static_env, per_run = split_per_run(env_params)
    signature = tuple(
        (leaf.shape, str(leaf.dtype), str(leaf.sharding))
        for leaf in jax.tree.leaves((runners, config, per_run))
    )
    adaptive = bool(chunk_seconds)
    key = (
        envs.make(config.env),  # an env registered again under its id is another program
        jax.tree.structure(config),
        params_key(static_env),
        tuple(per_run),
        chunk_size,
        adaptive,
        signature,
    )
    fresh = key not in _COMPILED
    if fresh:
        sharding = jax.tree.leaves(runners)[0].sharding
        program = chunk_program(static_env, chunk_size, sharding, adaptive, bool(per_run))
        extra = (per_run,) if per_run else ()
        lowered = program.lower(runners, config, jnp.int32(0), jnp.int32(1), *extra)
        _COMPILED[key] = lowered.compile()
    compiled = _COMPILED[key]
    if per_run:  # called with the runs' own env param values [R]
        return lambda *args: compiled(*args, per_run), fresh
    return compiled, fresh


def params_key(env_params: Any) -> tuple:
    """A hashable stand-in for env params: their structure and every leaf's value (gymnax's
    Acrobot keeps its torques in an array, which cannot be hashed)."""
    leaves, structure = jax.tree.flatten(env_params)
    values = tuple((np.shape(x), str(np.asarray(x).dtype), np.asarray(x).tobytes()) for x in leaves)
    return structure, values


def chunk_program(
    env_params: Any,
    chunk_size: int,
    sharding: jax.sharding.Sharding,
    adaptive: bool,
    per_run_env: bool = False,
) -> Callable:
    """The jitted :func:`~jaxcart.engine.chunk.train_chunk` that :func:`compiled_chunk`
    compiles, ``(runners, config, start_iteration, count) -> (runners, metrics)`` for runners
    placed with ``sharding``; with ``per_run_env``, a fifth argument holds the env params that
    differ between runs, ``{name: [R]}``, placed as the runners.

    The runners are not donated: a run that diverges is rolled back to them
    (:func:`~jaxcart.engine.chunk.roll_back_diverged`)."""
    # Groups keep a CPU core's working set in its cache; a GPU wants the widest vmap instead.
    on_cpu = all(d.platform == "cpu" for d in sharding.device_set)
    update_group = UPDATE_GROUP if on_cpu else None

    def training_chunk(
        runners: RunnerState,
        config: PPOConfig,
        start: jax.Array,
        count: jax.Array,
        per_run: dict | None = None,
    ):
        count = count if adaptive else None
        env = with_values(env_params, per_run or {})
        return train_chunk(runners, config, start, env, chunk_size, update_group, count)

    if isinstance(sharding, NamedSharding) and sharding.mesh.size > 1:
        # Every device runs the same program on its own runs with no communication: say so
        # with shard_map rather than leaving it to the SPMD partitioner (faster to compile).
        spec = sharding.spec
        training_chunk = jax.shard_map(
            training_chunk,
            mesh=sharding.mesh,
            in_specs=(spec, spec, PartitionSpec(), PartitionSpec(), *[spec] * per_run_env),
            out_specs=(spec, PartitionSpec(None, *spec)),
            check_vma=False,  # per-run metrics vs the skip branch's constants
        )
    return jax.jit(training_chunk)  # XLA's module: jit_training_chunk
