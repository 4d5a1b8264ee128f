"""How the training program is lowered so that XLA compiles it fast, with the same numbers.

:func:`fast_lowering` wraps the lowering of the compiled chunk (:mod:`jaxcart.engine.trainer`,
and ``benchmarks/ablations/compile_time.py`` which times it). Each change here has its reason
and its measurement in ``benchmarks/RESULTS.md``, "Cold compile".
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import jax
import numpy as np
from jax import lax
from jax.extend.random import threefry2x32_p
from jax.interpreters import mlir

_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))


def _rotate_left(x: jax.Array, bits: int) -> jax.Array:
    return lax.shift_left(x, np.uint32(bits)) | lax.shift_right_logical(x, np.uint32(32 - bits))


def threefry2x32_unrolled(
    key1: jax.Array, key2: jax.Array, x1: jax.Array, x2: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The Threefry-2x32 hash (20 rounds, key injection every 4) as straight-line uint32
    arithmetic: the formula of JAX's own lowering for accelerators, so the same bits as on CPU."""
    ks = (key1, key2, key1 ^ key2 ^ np.uint32(0x1BD11BDA))
    x1, x2 = x1 + ks[0], x2 + ks[1]
    for block in range(5):
        for rotation in _ROTATIONS[block % 2]:
            x1 = x1 + x2
            x2 = x1 ^ _rotate_left(x2, rotation)
        x1 = x1 + ks[(block + 1) % 3]
        x2 = x2 + ks[(block + 2) % 3] + np.uint32(block + 1)
    return x1, x2


def _cpu_lowerings() -> dict | None:
    """JAX's table of CPU-specific lowering rules, or None where this JAX has none we know."""
    try:
        from jax._src.interpreters import mlir as _mlir

        return _mlir._platform_specific_lowerings["cpu"]
    except (ImportError, AttributeError, KeyError, TypeError):
        return None


@contextlib.contextmanager
def unrolled_threefry() -> Iterator[None]:
    """While active, programs lowered for CPU compute every ``jax.random`` hash (Threefry)
    as straight-line arithmetic (:func:`threefry2x32_unrolled`) instead of JAX's CPU lowering.

    Plain version: JAX lowers Threefry on CPU as a 5-step loop at every call site, which
    XLA:CPU compiles into one kernel of its own per call site, unrolled again by LLVM (the
    default training step has five: the rollout's key split and action sample, the update's key
    split, the shuffle's key and bits; 380 KB of its 2.3 MB of optimised LLVM IR). Why:
    straight-line, each hash fuses into an ordinary element-wise kernel; the cold compile of the
    default step takes about 0.7 s less CPU (``benchmarks/RESULTS.md``, "Cold compile"). Same
    bits: integer arithmetic, the same formula (``tests/test_lowering.py`` checks known-answer
    vectors, and the golden runs are unchanged). The previous rule is restored on exit, so
    programs lowered outside this context (a user's own) are lowered as JAX would.
    """
    table = _cpu_lowerings()
    primitive = threefry2x32_p
    if table is None:  # an unknown JAX: lower as it would (slower to compile, same bits)
        yield
        return
    previous = table.get(primitive)
    rule = mlir.lower_fun(threefry2x32_unrolled, multiple_results=True)
    mlir.register_lowering(primitive, rule, platform="cpu", inline=False)
    try:
        yield
    finally:
        if previous is None:
            table.pop(primitive, None)
        else:
            table[primitive] = previous


def fast_lowering() -> contextlib.AbstractContextManager:
    """Everything :mod:`jaxcart.engine` does to lower its programs fast (:func:`unrolled_threefry`)."""
    return unrolled_threefry()


__all__ = ["fast_lowering", "threefry2x32_unrolled", "unrolled_threefry"]
