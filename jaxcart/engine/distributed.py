"""Several processes (hosts) training one run with JAX's own distributed runtime.

One code path for one device, many devices and many processes: the run axis is sharded over
``jax.devices()`` (every process's devices), each process computes its own shard, and the
host-side pieces here move data between the global arrays and NumPy:

- :func:`initialize` starts ``jax.distributed`` (CPU processes talk through Gloo collectives);
- :func:`to_global` turns identical host data on every process into a global sharded array
  (each process materialises only its own shards);
- :func:`gather` brings a global array back to NumPy on every process (an all-gather across
  processes; a plain ``device_get`` in a single process);
- :func:`any_process` agrees on a flag (e.g. "a stop was requested") across processes.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from typing import Any

import numpy as np

from jaxcart.engine import signals


def initialize(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
) -> None:
    """``jax.distributed.initialize`` with CPU collectives; must run before any JAX work.

    Unset arguments come from ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and
    ``JAX_PROCESS_ID``, else from JAX's cluster auto-detection (SLURM, Open MPI, ...).

    Raises:
        ConfigError: it cannot start (its first line says why).
    """
    import jax

    from jaxcart.core.errors import ConfigError

    env = os.environ
    try:
        num_processes = num_processes or (
            int(env["JAX_NUM_PROCESSES"]) if "JAX_NUM_PROCESSES" in env else None
        )
        if process_id is None and "JAX_PROCESS_ID" in env:
            process_id = int(env["JAX_PROCESS_ID"])
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        # JAX's preemption service would take SIGTERM over from jaxcart's handler (and do
        # nothing with it): SIGTERM must stop a distributed run with a checkpoint, as it does
        # one process.
        jax.config.update("jax_enable_preemption_service", False)
        jax.distributed.initialize(coordinator_address, num_processes, process_id)
    except (ValueError, TypeError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"cannot start jax.distributed: {first}") from None


def leave() -> None:
    """Leaves ``jax.distributed`` together with the other processes, once the run ended in
    order (finished, or stopped with its checkpoint); a no-op with one process.

    Process 0 holds the coordination service: exiting before the others would make them
    abort (SIGABRT) as they finish. The shutdown waits for every process at a barrier. It
    is not called on an error, where an abort of the others is the quickest way out.
    """
    import jax

    if jax.process_count() > 1:
        jax.distributed.shutdown()


def is_main_process() -> bool:
    """Process 0 writes the run directory and prints."""
    import jax

    return jax.process_index() == 0


def to_global(tree: Any, sharding) -> Any:
    """Places host arrays (the same on every process) as global arrays with ``sharding``."""
    import jax

    if jax.process_count() == 1:
        return jax.device_put(tree, sharding)

    def place(x):
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda index: x[index])

    return jax.tree.map(place, tree)


def gather(tree: Any) -> Any:
    """NumPy copies of (possibly global, sharded) arrays, on every process."""
    import jax

    if jax.process_count() == 1:
        return jax.device_get(tree)
    from jax.experimental import multihost_utils

    def one(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return np.asarray(x)

    return jax.tree.map(one, tree)


def any_process(flag: bool) -> bool:
    """True on every process if ``flag`` is true on any (a no-op with one process)."""
    import jax

    if jax.process_count() == 1:
        return flag
    from jax.experimental import multihost_utils

    return bool(np.asarray(multihost_utils.process_allgather(np.int32(flag))).any())


def launch_local(
    argv: list[str],
    num_processes: int = 2,
    devices_per_process: int = 1,
    wait: bool = True,
    **popen: Any,
) -> list[int] | list[subprocess.Popen]:
    """Runs ``python -m jaxcart.train ARGV --distributed`` as ``num_processes`` processes on
    this machine, talking over 127.0.0.1: a way to try (and test) multi-process training.

    Each process sees ``devices_per_process`` CPU devices (its own ``XLA_FLAGS``; this
    process's environment is left as it is).

    Args:
        wait: wait for every process and return their exit codes, forwarding SIGINT and
            SIGTERM (Ctrl-C) to them meanwhile, so they checkpoint and stop together (a
            second one stops them at once). False returns the running processes at once.
        popen: passed to :class:`subprocess.Popen` (e.g. ``stdout``); reading pipes needs
            ``wait=False``, which leaves the waiting (and the signals) to the caller.

    Returns:
        The exit codes (``wait=True``), or the :class:`subprocess.Popen` objects.
    """
    if wait and subprocess.PIPE in (popen.get("stdout"), popen.get("stderr")):
        raise ValueError("launch_local(wait=True) cannot drain pipes: pass wait=False")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        address = f"127.0.0.1:{s.getsockname()[1]}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env.update(
        XLA_FLAGS=f"--xla_force_host_platform_device_count={devices_per_process}",
        JAX_PLATFORMS="cpu",
    )
    common = ["--distributed", "--coordinator-address", address]
    common += ["--num-processes", str(num_processes)]
    if wait:  # a terminal's Ctrl-C reaches this process only; it passes the signal on once
        popen.setdefault("process_group", 0)
    procs: list[subprocess.Popen] = []
    try:
        for i in range(num_processes):
            cmd = [sys.executable, "-m", "jaxcart.train", *argv, *common, "--process-id", str(i)]
            procs.append(subprocess.Popen(cmd, env=env, **popen))
    except BaseException:
        for p in procs:
            p.kill()
        raise
    if not wait:
        return procs

    def forward(signum: int, frame: object) -> None:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signum)

    # Outside the main thread (where Python cannot handle signals) this only waits.
    with signals.handling(forward):
        while any(p.poll() is None for p in procs):
            # short waits: a signal that another thread took is handled here within 0.1 s
            # (a blocking wait would only see it once the processes ended)
            time.sleep(0.1)
    return [p.returncode for p in procs]
