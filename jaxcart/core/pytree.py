"""Frozen dataclasses that are JAX pytrees: what ``flax.struct.dataclass`` makes, registered
the way flax registers them (:func:`jax.tree_util.register_dataclass`), without importing flax
(about 0.3 s of every command's start-up, ``python -m jaxcart.env`` and ``--help`` included)."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np

T = TypeVar("T")


def dataclass(cls: type[T]) -> type[T]:
    """``cls`` as a frozen dataclass and a pytree: every field a leaf except those declared
    with :func:`static_field` (part of the structure), plus ``replace(**changes)``."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    fields = dataclasses.fields(cls)
    static = [f.name for f in fields if f.metadata.get("static")]
    data = [f.name for f in fields if f.name not in static]
    jax.tree_util.register_dataclass(cls, data_fields=data, meta_fields=static)
    cls.replace = dataclasses.replace  # type: ignore[attr-defined]
    return cls


def static_field(default: Any) -> Any:
    """A field that is not a leaf (flax's ``struct.field(pytree_node=False)``): a change to
    it is a new pytree structure, so a compiled program is specialised to its value."""
    return dataclasses.field(default=default, metadata={"static": True})


def per_run_field(default: Any) -> Any:
    """A leaf that may hold one value per run, an array ``[R]`` (a sweep's or a
    randomisation's), passed to the compiled program as an argument; the other leaves are
    one value for every run, constants of the program (:func:`split_per_run`)."""
    return dataclasses.field(default=default, metadata={"per_run": True})


def per_run_names(params: Any) -> tuple[str, ...]:
    """The fields of ``params`` declared with :func:`per_run_field` (none for a params pytree
    that declares none, e.g. gymnax's: its arrays, such as Acrobot's torques ``[3]``, are
    constants)."""
    if not dataclasses.is_dataclass(params):
        return ()
    return tuple(f.name for f in dataclasses.fields(params) if f.metadata.get("per_run"))


def split_per_run(params: T) -> tuple[T, dict[str, Any]]:
    """``(static, per_run)``: ``params`` with every :func:`per_run_field` that holds an array
    ``[R]`` set back to its default (a hashable constant for the compiled program), and
    those arrays as they are (NumPy or placed JAX arrays). Without arrays: ``params`` itself
    and ``{}``."""
    per_run = {n: getattr(params, n) for n in per_run_names(params)}
    per_run = {n: v for n, v in per_run.items() if np.ndim(v) > 0}
    if not per_run:
        return params, {}
    defaults = {f.name: f.default for f in dataclasses.fields(params) if f.name in per_run}
    return dataclasses.replace(params, **defaults), per_run


def with_values(params: T, values: dict[str, Any]) -> T:
    """``params`` with some fields replaced (numbers, or arrays ``[R]`` one per run)."""
    return dataclasses.replace(params, **values) if values else params


def float_dtype() -> np.dtype:
    """The float type training runs in: float32, or float64 when JAX runs with x64 enabled
    (``JAX_ENABLE_X64=1``, or inside ``jax.enable_x64``), so that the env state, the network
    and the update all follow."""
    return np.dtype(np.float64 if jax.config.jax_enable_x64 else np.float32)


def where(mask: jax.Array, on_true: T, on_false: T) -> T:
    """``jnp.where`` leaf by leaf over two pytrees of one structure, with ``mask`` (e.g. a
    batch's ``done [N]``) broadcast over each leaf's trailing axes (``[N, ...]``)."""

    def pick(a: jax.Array, b: jax.Array) -> jax.Array:
        return jnp.where(mask.reshape(mask.shape + (1,) * (b.ndim - mask.ndim)), a, b)

    return jax.tree.map(pick, on_true, on_false)
