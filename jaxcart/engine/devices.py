"""Device set-up that must happen before JAX initialises its backends."""

from __future__ import annotations

import os
import sys
import warnings
from pathlib import Path

DEVICE_COUNT_FLAG = "--xla_force_host_platform_device_count"


def use_all_host_cores(count: int | None = None) -> None:
    """Exposes the host's cores to JAX as ``count`` CPU devices (default: all cores).

    XLA on CPU runs one program on one core; with several host devices the run axis is
    sharded over them and each core trains its share. The command line calls it; from
    Python, call ``jaxcart.use_all_host_cores()`` before any JAX work to train the same way
    (otherwise JAX gives one CPU device). Only effective before JAX creates its CPU backend
    (a warning says when it is too late); an explicit
    ``--xla_force_host_platform_device_count`` in ``XLA_FLAGS`` is left alone. GPUs are
    unaffected (the flag only concerns the host platform).
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if DEVICE_COUNT_FLAG in flags:
        check_device_count_flag(flags)
        return
    if count is None:
        count = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if "jax" in sys.modules:  # JAX is loaded: its own option, refused once backends exist
        import jax

        try:
            jax.config.update("jax_num_cpu_devices", count or 1)
        except RuntimeError:
            warnings.warn(
                "use_all_host_cores() comes too late: JAX has started with its devices already; "
                "call it before any JAX work (or set XLA_FLAGS before starting Python)",
                RuntimeWarning,
                stacklevel=2,
            )
        return
    os.environ["XLA_FLAGS"] = f"{flags} {DEVICE_COUNT_FLAG}={count or 1}".strip()


MAX_HOST_DEVICES = 4096


def check_device_count_flag(flags: str) -> None:
    """Refuses an ``XLA_FLAGS`` device count XLA cannot start with (0, negative, not a
    number, over :data:`MAX_HOST_DEVICES`): JAX would fail later with a long traceback.

    Raises:
        ConfigError: the flag's value, and what it must be.
    """
    from jaxcart.core.errors import ConfigError

    for token in flags.split():
        if token.startswith(DEVICE_COUNT_FLAG):
            value = token[len(DEVICE_COUNT_FLAG) :].lstrip("=")
            if not value.isdigit() or not 1 <= int(value[:6]) <= MAX_HOST_DEVICES:
                raise ConfigError(
                    f"XLA_FLAGS {token} must give a device count in [1, {MAX_HOST_DEVICES}]"
                )


def compilation_cache_dir() -> Path:
    """``$JAXCART_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxcart/jax``, else
    ``~/.cache/jaxcart/jax`` (the XDG base-directory rule: an unset, empty or relative
    ``XDG_CACHE_HOME`` is ignored)."""
    if os.environ.get("JAXCART_CACHE_DIR"):
        return Path(os.environ["JAXCART_CACHE_DIR"])
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".cache"
    return base / "jaxcart" / "jax"


def enable_compilation_cache() -> None:
    """Turns on JAX's persistent compilation cache so repeated runs skip XLA compilation.

    Raises:
        ConfigError: ``$JAXCART_CACHE_DIR`` names a place that is not a writable directory
            (the user chose it, so it is a mistake to report, where an unwritable default
            cache only costs compile time and is skipped).
    """
    import jax

    from jaxcart.core.errors import ConfigError

    path = compilation_cache_dir()
    try:
        path.mkdir(parents=True, exist_ok=True)
        usable = path.is_dir() and os.access(path, os.W_OK | os.X_OK)
        reason = "it is not a writable directory"
    except OSError as exc:
        usable, reason = False, exc.strerror or str(exc)
    if not usable:
        if os.environ.get("JAXCART_CACHE_DIR"):
            raise ConfigError(
                f"JAXCART_CACHE_DIR={path} cannot hold the compilation cache: {reason}; "
                "choose another directory, unset it, or pass --no-compile-cache"
            )
        return  # the default place: an unwritable cache only costs compile time
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
