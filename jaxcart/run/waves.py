"""Planning: how many runs train at once, in how many waves, in how much memory and time.

Before anything is initialised, the host memory one run needs is estimated from the config
(:func:`bytes_per_run`) and compared with the memory available (:func:`available_bytes`).
When all runs do not fit, they train in **waves**: consecutive groups of runs, each sharded
over all devices, each trained, evaluated and saved before the next starts. A run's result
does not depend on which wave it is in beyond what its per-device batch width already
implies (see the README's Reproducibility section).

The estimate: the training state of one run (measured exactly from a one-run state),
counted three times (the host copy, the device arguments, the donated outputs), plus the
compiled program's temporaries, which scale with the rollout (``num_envs x num_steps``
transitions). ``TEMP_BYTES_PER_TRANSITION`` and ``FIXED_BYTES_PER_RUN`` were measured once
from XLA's own memory analysis of the compiled chunk (``compiled.memory_analysis()``) for
the sb3, fast and purejaxrl presets at 1 to 64 runs on the CPU (temporaries 0.63-0.71 KB per
transition plus about 0.2 MB per run); ``tests/test_waves.py`` checks that the estimate stays
above that measurement, so it errs on the side of more waves.

Waves are sized for throughput, not to fill memory: a wave holds the fewest runs per device
that keep the device busy (:func:`throughput_runs_per_device`), capped by memory. Larger
waves only cost memory and make every chunk, checkpoint and stop request slower. The plan
also estimates the job's wall time (:func:`plan_waves`), a model the run's own first
chunk then replaces with a measurement.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from jaxcart.core.config import ConfigError, PPOConfig

TEMP_BYTES_PER_TRANSITION = 800
FIXED_BYTES_PER_RUN = 300_000
EVAL_BYTES_PER_EPISODE = 8_000  # a Gymnasium env object and its bookkeeping, per episode
PROCESS_RESERVE_BYTES = 1_500_000_000  # Python, JAX, XLA and the compiled program itself
USABLE_FRACTION = 0.7
CPU_RUNS_PER_DEVICE = 32
"""Runs per CPU device in a wave. Why: on a shared 2-core host (+-2x) the fast preset cost 9-20
ms per run and iteration at 4 to 64 runs per device with no trend past 8, and the sb3 preset 95
ms at 32 runs per device but 149 ms at 256: a wider wave is no cheaper per run, and every chunk
takes longer."""
ACCELERATOR_ENVS_PER_DEVICE = 65_536
"""Parallel environments (runs x num_envs) per GPU or TPU: a model, not measured."""
CPU_SECONDS_PER_ENV_STEP = 1.2e-6
"""Seconds per environment step and update epoch of one run on one CPU device, for the
time estimate only: at 32 runs per device the sb3 preset takes about 1.1 us (0.793 s per
iteration of a million-seed run, ``benchmarks/RESULTS.md``, "Memory at scale") and fast about
0.9 us on a quiet 2-core host; a loaded host is several times slower, and the first chunks'
measurement replaces the estimate."""
ACCELERATOR_SECONDS_PER_ENV_STEP = 1e-8  # a guess; the first chunks' measurement follows
CSV_BYTES_PER_ROW = 250
"""One (seed, iteration) row of ``metrics.csv`` (measured: 244 bytes in a fast-preset run)."""
MEMORY_ENV = "JAXCART_MEMORY_BYTES"
"""Overrides the available memory (bytes), e.g. to plan for a smaller share of a machine."""


def bytes_per_run(config: PPOConfig, eval_episodes: int = 20) -> int:
    """Estimated peak host memory of one run while it trains and is evaluated, in bytes."""
    import jax

    from jaxcart.engine.loop import MAX_CHUNK_ITERATIONS, initial_state

    state = initial_state(config, 1, 0)
    state_bytes = sum(np.asarray(x).nbytes for x in jax.tree.leaves(state.runners))
    transitions = config.num_envs * config.num_steps
    # one chunk of metrics (its device buffer, the host copy and the rows appended to the
    # stream): a run directory streams them to disk, so the run's length costs no memory
    metrics = 3 * min(config.num_iterations, MAX_CHUNK_ITERATIONS) * len(state.metrics) * 4
    return (
        3 * state_bytes
        + transitions * TEMP_BYTES_PER_TRANSITION
        + FIXED_BYTES_PER_RUN
        + metrics
        + eval_episodes * EVAL_BYTES_PER_EPISODE
    )


def available_bytes() -> int:
    """Memory this process may use: ``$JAXCART_MEMORY_BYTES``, else the smaller of the
    kernel's MemAvailable and the cgroup's remaining limit."""
    if os.environ.get(MEMORY_ENV):
        value = os.environ[MEMORY_ENV].strip()
        try:
            memory = float(value)
        except ValueError:
            memory = math.nan
        if not 1 <= memory <= 2**60:  # NaN fails too
            raise ConfigError(f"{MEMORY_ENV}={value[:40]} must be a number of bytes in [1, 2**60]")
        return int(memory)
    candidates = []
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/meminfo") as f:
            found = [line.split()[1] for line in f if line.startswith("MemAvailable:")]
        candidates += [int(kb) * 1024 for kb in found]
    with contextlib.suppress(OSError, ValueError):
        limit = open("/sys/fs/cgroup/memory.max").read().strip()
        used = int(open("/sys/fs/cgroup/memory.current").read().strip())
        candidates += [int(limit) - used] if limit != "max" else []
    if not candidates:
        pages = os.sysconf("SC_AVPHYS_PAGES") if hasattr(os, "sysconf") else 0
        candidates.append(pages * os.sysconf("SC_PAGE_SIZE") if pages else 8 << 30)
    return max(0, min(candidates))


def throughput_runs_per_device(config: PPOConfig, backend: str) -> tuple[int, str]:
    """The runs per device that fill a device's parallel width, and why (one line)."""
    if backend == "cpu":
        why = "wider waves cost as much per run (measured on a 2-core CPU); --wave-size N overrides"
        return CPU_RUNS_PER_DEVICE, f"{CPU_RUNS_PER_DEVICE} runs per cpu device: {why}"
    runs = max(1, ACCELERATOR_ENVS_PER_DEVICE // config.num_envs)
    return runs, (
        f"{runs:,} runs per {backend} device: {ACCELERATOR_ENVS_PER_DEVICE:,} parallel "
        "environments fill one (a model, not measured); --wave-size N overrides"
    )


def format_duration(seconds: float) -> str:
    """``45 s``, ``12 min``, ``3.5 h``, ``41 days``."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:,.0f} days"


@dataclass(frozen=True)
class WavePlan:
    """``num_runs`` runs trained ``wave_size`` at a time (the last wave may be smaller)."""

    num_runs: int
    wave_size: int
    bytes_per_run: int
    available: int
    wave_seconds: float = 0.0  # estimated wall time of one full wave (0: not estimated)
    why: str = ""  # one line: how the wave width was chosen
    disk_bytes: int = 0  # estimated disk the run's metrics take (0: not estimated)

    @property
    def num_waves(self) -> int:
        return math.ceil(self.num_runs / self.wave_size)

    def waves(self) -> Iterator[range]:
        """The runs of each wave, in order."""
        return (self.wave(w) for w in range(self.num_waves))

    def wave(self, index: int) -> range:
        """The runs of wave ``index``."""
        start = index * self.wave_size
        return range(start, min(start + self.wave_size, self.num_runs))

    def describe(self, what: str = "runs") -> str:
        """``1,000,000 runs in 13 waves of 77,824 (estimated 1.6 GB per wave of 23 GB
        available; about 20 min per wave, 4.3 h in all)``."""
        per_wave = self.wave_size * self.bytes_per_run / 1e9
        waves = f"{self.num_waves:,} waves of {self.wave_size:,}"
        if self.num_waves == 1:
            waves = f"one wave of {self.num_runs:,}"
        timing = ""
        if self.wave_seconds:
            total = self.wave_seconds * self.num_runs / self.wave_size
            timing = (
                f"; about {format_duration(self.wave_seconds)} per wave, "
                f"{format_duration(total)} in all"
            )
        disk = ""
        if self.disk_bytes >= 1e9:  # small runs' metrics are not worth a word
            disk = f"; {self.disk_bytes / 1e9:,.3g} GB of metrics on disk"
        what = what.removesuffix("s") if self.num_runs == 1 else what
        return (
            f"{self.num_runs:,} {what} in {waves} (estimated {per_wave:.2g} GB per wave of "
            f"{self.available / 1e9:.3g} GB available{timing}{disk})"
        )


def plan_waves(
    config: PPOConfig,
    num_runs: int,
    num_devices: int,
    eval_episodes: int = 20,
    available: int | None = None,
    backend: str = "cpu",
    wave_size: int | None = None,
) -> WavePlan:
    """Waves of the fewest runs that fill the devices (:func:`throughput_runs_per_device`,
    a multiple of ``num_devices``), fewer when memory is short, balanced so the last wave is
    not much narrower; or ``wave_size`` runs when given.

    Raises:
        ConfigError: not even one run per device fits, or ``wave_size`` does not fit.
    """
    per_run = bytes_per_run(config, eval_episodes)
    available = available_bytes() if available is None else available
    budget = max(0, int((available - PROCESS_RESERVE_BYTES) * USABLE_FRACTION))
    fit = budget // per_run // num_devices * num_devices
    if fit < num_devices:
        raise ConfigError(
            f"not enough memory for one run per device: a run of this config needs about "
            f"{per_run / 1e6:.0f} MB x {num_devices} device(s), and {available / 1e9:.2g} GB "
            f"are available; use a smaller num_envs x num_steps or free memory"
        )
    if wave_size is not None:
        if wave_size > max(fit, num_devices):
            raise ConfigError(
                f"--wave-size {wave_size:,} needs about {wave_size * per_run / 1e9:.2g} GB; "
                f"{fit:,} runs fit in the share of the {available / 1e9:.2g} GB available "
                f"that jaxcart plans for"
            )
        size, why = min(wave_size, num_runs), f"{wave_size:,} runs per wave (--wave-size)"
    else:
        per_device, why = throughput_runs_per_device(config, backend)
        size = min(fit, per_device * num_devices, num_runs)
        if size == fit and fit < per_device * num_devices:
            why = f"{fit // num_devices:,} runs per device: as many as fit in memory"
        waves = math.ceil(num_runs / size)  # balanced: equal waves where the count allows
        size = min(num_runs, -(-math.ceil(num_runs / waves) // num_devices) * num_devices)
    # the time: one device's runs (the devices work in parallel), each iteration's env steps
    # x (1 + update epochs) at a per-step cost
    per_step = CPU_SECONDS_PER_ENV_STEP if backend == "cpu" else ACCELERATOR_SECONDS_PER_ENV_STEP
    steps = -(-size // num_devices) * config.batch_size * (1 + config.update_epochs)
    seconds = config.num_iterations * steps * per_step
    disk = metrics_disk_bytes(config, num_runs, size)
    return WavePlan(num_runs, size, per_run, available, seconds, why, disk)


def metrics_disk_bytes(config: PPOConfig, num_runs: int, wave_size: int) -> int:
    """Estimated bytes of a run's metrics on disk: ``metrics.csv``, the stream of the wave
    being trained and, in waves, each finished wave's copy (float32 per metric, run and
    iteration). Training memory does not grow with them: they are streamed."""
    from jaxcart.engine.loop import METRIC_COLUMNS

    row = len(METRIC_COLUMNS) * 4
    waved = num_runs if wave_size < num_runs else 0
    return config.num_iterations * (num_runs * CSV_BYTES_PER_ROW + (wave_size + waved) * row)
