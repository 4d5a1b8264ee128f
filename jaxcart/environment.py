"""The environment variables JAX reads, checked before any command runs: a value JAX or XLA
cannot use becomes one line on stderr and exit code 2 (JAX raises a traceback, XLA aborts the
process with a fatal log line).

:func:`import_jax` imports JAX, and turns a value JAX refuses at import
(``JAX_ENABLE_X64=junk``, ``JAX_DEFAULT_MATMUL_PRECISION=junk``, ...) into that line: every
command calls it before its first import of JAX, once its command line is parsed
(:meth:`jaxcart.cli.Parser.parse_args`; ``--help`` imports no JAX) or, in a command whose own
module imports JAX, before that import. :func:`check_backend` does the same for
what JAX reads when it starts its backend (``JAX_PLATFORMS``, ``XLA_FLAGS``), which
:func:`jaxcart.cli.command_main` calls before the command's ``main``.
"""

from __future__ import annotations

import os
import subprocess
import sys

EXIT_USAGE = 2
DEVICE_COUNT_FLAG = "--xla_force_host_platform_device_count"
"""The one XLA flag jaxcart sets itself (checked by :mod:`jaxcart.engine.devices`)."""


def _refuse(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(EXIT_USAGE)


def import_jax() -> None:
    """Imports JAX; a JAX_* value it refuses becomes one line and exit code 2."""
    try:
        import jax  # noqa: F401  (it reads JAX_* variables as it is imported)
    except ValueError as exc:  # JAX's message names the variable or its flag
        _refuse(f"{str(exc).splitlines()[0]}; fix or unset that environment variable")


def xla_flags_problem(flags: str) -> str | None:
    """What is wrong with an ``XLA_FLAGS`` value that XLA would abort on, read without
    starting XLA: a token that is not a ``--flag`` (XLA reads it as a file of flags)."""
    for token in flags.split():
        if not token.startswith("--"):
            return (
                f"XLA_FLAGS holds {token!r}, which is not a --flag (XLA would read it as a "
                "file of flags and abort); fix or unset XLA_FLAGS"
            )
    return None


def _probe_backend() -> str | None:
    """Starts JAX's backend in a child process (XLA aborts the whole process on an unknown
    flag, and a backend started here could not be given ``jax.distributed`` any more): its
    last line on failure, None when it starts."""
    proc = subprocess.run(
        [sys.executable, "-c", "import jax; jax.devices()"],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    if proc.returncode == 0:
        return None
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    return lines[-1][-300:] if lines else f"exit code {proc.returncode}"


def check_backend() -> None:
    """Refuses, in one line (exit 2), ``XLA_FLAGS`` or ``JAX_PLATFORMS`` values the backend
    cannot start with. Starts nothing in this process; probes in a child only when a value
    is one jaxcart does not set itself (flags other than the device count, a platform other
    than ``cpu``)."""
    flags, platforms = os.environ.get("XLA_FLAGS", ""), os.environ.get("JAX_PLATFORMS", "")
    if flags.strip():
        problem = xla_flags_problem(flags)
        needs_probe = not all(t.startswith(DEVICE_COUNT_FLAG) for t in flags.split())
        if problem is None and needs_probe and (failure := _probe_backend()) is not None:
            problem = f"XLA cannot start with XLA_FLAGS={flags!r}: {failure}"
        if problem is not None:
            _refuse(problem)
    if {p.strip() for p in platforms.split(",") if p.strip()} - {"cpu"}:
        failure = _probe_backend()
        if failure is not None and failure.isidentifier():  # a bare exception: no plugin
            _refuse(
                f"JAX_PLATFORMS={platforms!r}: this JAX cannot start that backend (it says only "
                f"{failure}); install JAX for it (cuda: pip install -U 'jax[cuda12]') or unset "
                "JAX_PLATFORMS to run on the CPU"
            )
        if failure is not None:
            _refuse(f"JAX_PLATFORMS={platforms!r}: {failure}; fix or unset JAX_PLATFORMS")
