"""The measured speed tricks behind :mod:`jaxcart.core.ppo` and :mod:`jaxcart.core.env`.

Each function here computes what a plainer version would, bit for bit or in distribution as
its docstring says, and exists because a measurement found the plainer version slower. Each
docstring names the plain version, the reason in one line, and where the measurement is
(``benchmarks/RESULTS.md`` and ``benchmarks/results/*.md``). Read :mod:`jaxcart.core.ppo` for
the algorithm; come here only to see how a step of it is made fast.
"""

from __future__ import annotations

import math
from typing import Any, TypeVar

import jax
import jax.numpy as jnp

from jaxcart.core.config import TRACED_FIELDS, PPOConfig

Array = jax.Array
Fields = TypeVar("Fields", bound=tuple)
"""A NamedTuple of arrays with a leading batch axis (for example :class:`ppo.Batch`)."""


@jax.tree_util.register_pytree_with_keys_class
class Hyperparams:
    """The traced float hyperparameters (:data:`~jaxcart.core.config.TRACED_FIELDS`, declared on
    :class:`PPOConfig`) as arrays: scalars for one run, ``[R]`` for R runs.

    Plain version: the floats as static config fields. Why: as traced leaves a sweep over them
    is one vmap axis and one compiled program, not a compile per value (README, "Sweeps"). A
    hand-made pytree rather than a dataclass so that its fields are declared once, by
    ``traced(...)`` on :class:`PPOConfig`. Read them as attributes (``hp.clip_coef``).
    """

    __slots__ = ("_values",)

    def __init__(self, **values: Array) -> None:
        missing = set(TRACED_FIELDS) - set(values)
        unknown = set(values) - set(TRACED_FIELDS)
        if missing or unknown:
            raise TypeError(
                f"Hyperparams needs exactly {TRACED_FIELDS}; missing {missing}, unknown {unknown}"
            )
        object.__setattr__(self, "_values", {name: values[name] for name in TRACED_FIELDS})

    def __getattr__(self, name: str) -> Array:
        try:
            return self._values[name]
        except KeyError:
            raise AttributeError(name) from None

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError("Hyperparams is immutable; use .replace(name=value)")

    def __repr__(self) -> str:
        return f"Hyperparams({', '.join(f'{k}={v!r}' for k, v in self._values.items())})"

    def replace(self, **changes: Array) -> Hyperparams:
        """A copy with some values replaced."""
        return Hyperparams(**{**self._values, **changes})

    def tree_flatten_with_keys(self):
        return [(jax.tree_util.GetAttrKey(k), v) for k, v in self._values.items()], None

    @classmethod
    def tree_unflatten(cls, aux: None, leaves: list[Array]) -> Hyperparams:
        obj = object.__new__(cls)
        object.__setattr__(obj, "_values", dict(zip(TRACED_FIELDS, leaves)))
        return obj

    @classmethod
    def from_config(cls, config: PPOConfig) -> Hyperparams:
        """Scalar float32 hyperparameters taken from ``config``."""
        return cls(**{name: jnp.float32(getattr(config, name)) for name in TRACED_FIELDS})


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
    Integer fields travel as floats, exact below 2**24, so the round trip is exact.
    """
    floats = [f for f in batch if jnp.issubdtype(f.dtype, jnp.floating)]
    dtype = jnp.result_type(*floats)  # no float field loses precision
    columns = [f.astype(dtype) if f.ndim == 2 else f.astype(dtype)[:, None] for f in batch]
    return jnp.concatenate(columns, axis=-1)


def unpack_batch(rows: Array, like: Fields) -> Fields:
    """:func:`pack_batch` undone for rows ``[M, columns]``: fields of ``like``'s type, column
    widths and dtypes, ``[M, ...]``."""
    fields, start = [], 0
    for field in like:
        if field.ndim == 2:
            width = field.shape[-1]
            fields.append(rows[:, start : start + width].astype(field.dtype))
        else:
            width = 1
            fields.append(rows[:, start].astype(field.dtype))
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


def _fmix32(x: Array) -> Array:
    """MurmurHash3's 32-bit finaliser: a bijection with full avalanche."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x85EBCA6B)
    x = x ^ (x >> 13)
    x = x * jnp.uint32(0xC2B2AE35)
    return x ^ (x >> 16)


def hash_uniform(
    key: Array, shape: tuple[int, ...], dtype=None, minval: float = 0.0, maxval: float = 1.0
) -> Array:
    """Uniform numbers in ``[minval, maxval)`` from a keyed counter hash (the env's reset noise).

    Plain version: ``jax.random.uniform`` (Threefry). Why: drawing 4 Threefry uniforms per env
    and step cost about three times CartPole's physics, so the env was RNG-bound; with the hash
    the draw is 5 ns of a 24 ns env step (``benchmarks/RESULTS.md``, env throughput;
    ``benchmarks/results/env_step_ablation.md``, ``fixed-reset``). Same distribution, other
    numbers: every run's reset states depend on it, so it cannot change without changing them.

    Element ``i`` is ``fmix32(fmix32(i * golden + k0) ^ k1)`` for the key's two words
    ``(k0, k1)``: counter-based like Threefry, with about 12 integer operations per number
    instead of ~80 (``tests/test_env_parity.py`` checks uniformity and independence). float32
    gets 24 random bits, float64 53 (two hashes); the default dtype is JAX's default float.
    """
    dtype = dtype or jax.dtypes.canonicalize_dtype(jnp.float64)
    words = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    words = words.astype(jnp.uint32)
    size = math.prod(shape)
    counter = jnp.arange(size, dtype=jnp.uint32)

    def bits(c: Array) -> Array:
        return _fmix32(_fmix32(c * jnp.uint32(0x9E3779B9) + words[0]) ^ words[1])

    if jnp.dtype(dtype) == jnp.float64:
        hi = (bits(2 * counter) >> 6).astype(dtype)  # 26 bits
        lo = (bits(2 * counter + 1) >> 5).astype(dtype)  # 27 bits
        unit = (hi * 2.0**27 + lo) * 2.0**-53
    else:
        unit = (bits(counter) >> 8).astype(dtype) * jnp.asarray(2.0**-24, dtype)
    return (minval + (maxval - minval) * unit).reshape(shape).astype(dtype)


__all__ = [
    "Hyperparams",
    "categorical_entropy",
    "categorical_log_prob",
    "hash_uniform",
    "pack_batch",
    "random_permutations",
    "unpack_batch",
]
