"""The measured speed tricks behind :mod:`jaxcart.core.ppo`.

Each function here computes what a plainer version would, bit for bit or in distribution as
its docstring says, and exists because a measurement found the plainer version slower. Each
docstring names the plain version, the reason in one line, and where the measurement is
(``benchmarks/RESULTS.md`` and ``benchmarks/results/*.md``). Read :mod:`jaxcart.core.ppo` for
the algorithm; come here only to see how a step of it is made fast.
"""

from __future__ import annotations

from typing import TypeVar

import jax
import jax.numpy as jnp

Array = jax.Array
Fields = TypeVar("Fields", bound=tuple)
"""A NamedTuple of arrays with a leading batch axis (for example :class:`ppo.Batch`)."""


def categorical_log_prob(logits: Array, action: Array) -> Array:
    """``log pi(action)`` for logits ``[..., A]`` and integer actions ``[...]``.

    Plain version: ``distrax.Categorical(logits).log_prob(action)``, or a ``take_along_axis``
    gather. Why: distrax's TensorFlow-Probability import adds over a second to every start, and
    a one-hot sum fuses with its neighbours where a gather is a kernel of its own (measured with
    ``benchmarks/profile_step.py``). ``tests/test_ppo.py`` checks it against distrax.
    """
    log_p = jax.nn.log_softmax(logits)
    return (log_p * jax.nn.one_hot(action, logits.shape[-1], dtype=log_p.dtype)).sum(-1)


def categorical_entropy(logits: Array) -> Array:
    """Entropy of the categorical distribution with ``logits`` ``[..., A]``, in plain
    ``jax.nn`` for the same start-up reason as :func:`categorical_log_prob`."""
    log_p = jax.nn.log_softmax(logits)
    return -(jnp.exp(log_p) * log_p).sum(-1)


def pack_batch(batch: Fields) -> Array:
    """A NamedTuple of arrays ``[B, width]`` or ``[B]`` (one column) as one array of rows
    ``[B, columns]`` (``[B, obs_dim + 4]`` for a PPO batch), in its widest float dtype.

    Plain version: gather each field with the same permutation. Why: one gather of contiguous
    rows per epoch instead of one per field (``benchmarks/RESULTS.md``, "What was changed" in
    the update section; ``benchmarks/results/update_ablation.md``: the shuffle now costs 2-3%).
    Integer fields travel as floats, exact below 2**24, so the round trip is exact. A field
    that is None takes no column.
    """
    present = [f for f in batch if f is not None]
    floats = [f for f in present if jnp.issubdtype(f.dtype, jnp.floating)]
    dtype = jnp.result_type(*floats)  # no float field loses precision
    columns = [f.astype(dtype) if f.ndim == 2 else f.astype(dtype)[:, None] for f in present]
    return jnp.concatenate(columns, axis=-1)


def unpack_batch(rows: Array, like: Fields) -> Fields:
    """:func:`pack_batch` undone for rows ``[M, columns]``: fields of ``like``'s type, column
    widths and dtypes, ``[M, ...]``."""
    fields, start = [], 0
    for field in like:
        if field is None:
            fields.append(None)
            continue
        width = field.shape[-1] if field.ndim == 2 else 1
        column = rows[:, start : start + width] if field.ndim == 2 else rows[:, start]
        fields.append(column.astype(field.dtype))
        start += width
    return type(like)(*fields)


def random_permutations(key: Array, num: int, size: int) -> Array:
    """``num`` independent random permutations of ``range(size)``, shape ``[num, size]``.

    Plain version: ``jax.random.permutation`` per epoch. Why: its key-value sorts cost about
    8x more on CPU than one single-operand integer sort (``benchmarks/RESULTS.md``, the rejax
    comparison). Each round sorts one uint32 per element: random high bits with the index in
    the low bits. Elements whose random bits tie keep their relative order within a round; a
    second round (when the index takes more than 12 bits) makes such ties negligible.
    """
    index_bits = max(1, (size - 1).bit_length())
    if index_bits > 24:
        raise ValueError(f"batch of {size} transitions is too large to shuffle (max 2**24)")
    low = jnp.uint32((1 << index_bits) - 1)
    perms = jnp.broadcast_to(jnp.arange(size, dtype=jnp.uint32), (num, size))
    for round_key in jax.random.split(key, 1 if index_bits <= 12 else 2):
        bits = jax.random.bits(round_key, (num, size), jnp.uint32)
        order = jnp.sort((bits & ~low) | jnp.arange(size, dtype=jnp.uint32), axis=-1) & low
        perms = jnp.take_along_axis(perms, order.astype(jnp.int32), axis=-1)
    return perms.astype(jnp.int32)
