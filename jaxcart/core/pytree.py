"""Frozen dataclasses that are JAX pytrees: what ``flax.struct.dataclass`` makes, registered
the way flax registers them (:func:`jax.tree_util.register_dataclass`), without importing flax
(about 0.3 s of every command's start-up, ``python -m jaxcart.env`` and ``--help`` included)."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax

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
