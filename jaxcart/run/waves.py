"""Memory-aware planning: how many runs train at once, and in how many waves.

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
"""

from __future__ import annotations

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
MEMORY_ENV = "JAXCART_MEMORY_BYTES"
"""Overrides the available memory (bytes), e.g. to plan for a smaller share of a machine."""


def bytes_per_run(config: PPOConfig, eval_episodes: int = 20) -> int:
    """Estimated peak host memory of one run while it trains and is evaluated, in bytes."""
    import jax

    from jaxcart.engine.trainer import initial_state

    state = initial_state(config, 1, 0)
    state_bytes = sum(np.asarray(x).nbytes for x in jax.tree.leaves(state.runners))
    transitions = config.num_envs * config.num_steps
    metrics = config.num_iterations * len(state.metrics) * 4
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
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    candidates.append(int(line.split()[1]) * 1024)
    except OSError:
        pass
    try:
        limit = open("/sys/fs/cgroup/memory.max").read().strip()
        used = int(open("/sys/fs/cgroup/memory.current").read().strip())
        if limit != "max":
            candidates.append(int(limit) - used)
    except (OSError, ValueError):
        pass
    if not candidates:
        pages = os.sysconf("SC_AVPHYS_PAGES") if hasattr(os, "sysconf") else 0
        candidates.append(pages * os.sysconf("SC_PAGE_SIZE") if pages else 8 << 30)
    return max(0, min(candidates))


@dataclass(frozen=True)
class WavePlan:
    """``num_runs`` runs trained ``wave_size`` at a time (the last wave may be smaller)."""

    num_runs: int
    wave_size: int
    bytes_per_run: int
    available: int

    @property
    def num_waves(self) -> int:
        return math.ceil(self.num_runs / self.wave_size)

    def waves(self) -> Iterator[range]:
        """The runs of each wave, in order."""
        size = self.wave_size
        return (range(s, min(s + size, self.num_runs)) for s in range(0, self.num_runs, size))

    def wave(self, index: int) -> range:
        """The runs of wave ``index``."""
        start = index * self.wave_size
        return range(start, min(start + self.wave_size, self.num_runs))

    def describe(self, what: str = "runs") -> str:
        """``1,000,000 runs in 13 waves of 77,824 (estimated 1.6 GB per wave of 23 GB
        available)``."""
        per_wave = self.wave_size * self.bytes_per_run / 1e9
        return (
            f"{self.num_runs:,} {what} in {self.num_waves:,} waves of {self.wave_size:,} "
            f"(estimated {per_wave:.2g} GB per wave of {self.available / 1e9:.3g} GB available)"
        )


def plan_waves(
    config: PPOConfig,
    num_runs: int,
    num_devices: int,
    eval_episodes: int = 20,
    available: int | None = None,
) -> WavePlan:
    """The largest waves that fit, a multiple of ``num_devices`` runs each.

    Raises:
        ConfigError: not even one run per device fits.
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
    return WavePlan(num_runs, min(fit, num_runs), per_run, available)
