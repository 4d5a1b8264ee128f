"""The engine's lowering changes (jaxcart/engine/lowering.py) keep every bit of every number."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxcart.engine.lowering import fast_lowering, threefry2x32_unrolled

# Threefry-2x32, 20 rounds: the known-answer vectors of Random123 (Salmon et al., 2011), which
# JAX's own tests use: (key, counter) -> output.
KNOWN_ANSWERS = [
    ((0x00000000, 0x00000000), (0x00000000, 0x00000000), (0x6B200159, 0x99BA4EFE)),
    ((0xFFFFFFFF, 0xFFFFFFFF), (0xFFFFFFFF, 0xFFFFFFFF), (0x1CB996FC, 0xBB002BE7)),
    ((0x13198A2E, 0x03707344), (0x243F6A88, 0x85A308D3), (0xC4923A9C, 0x483DF7A0)),
]


@pytest.mark.parametrize("key, count, expected", KNOWN_ANSWERS)
def test_unrolled_threefry_matches_the_known_answers(key, count, expected):
    u32 = lambda v: jnp.asarray(np.uint32(v))
    out = threefry2x32_unrolled(u32(key[0]), u32(key[1]), u32(count[0]), u32(count[1]))
    assert tuple(int(x) for x in out) == expected


def _draws(key):
    """Every kind of draw the training step makes, and a few more."""
    keys = jax.random.split(key, 3)
    logits = jnp.linspace(-1.0, 1.0, 14).reshape(7, 2)
    return (
        keys,
        jax.random.split(keys[0]),
        jax.random.categorical(keys[1], logits),
        jax.random.bits(keys[2], (10, 2049)),
        jax.random.uniform(key, (5, 3)),
        jax.random.permutation(key, 37),
        jax.random.fold_in(key, 7),
    )


def _lower(fn, *args):
    # a fresh function each time: JAX caches lowerings per traced function
    return jax.jit(lambda *a: fn(*a)).lower(*args)


def test_draws_are_bit_identical_inside_and_outside_the_context():
    key = jax.random.PRNGKey(1234)
    plain = _lower(_draws, key)
    with fast_lowering():
        fast = _lower(_draws, key)
    after = _lower(_draws, key)
    # the context changed the program (no Threefry loop) and restored JAX's rule on exit
    assert "while" in plain.as_text() and "while" not in fast.as_text()
    assert "while" in after.as_text()
    for a, b in zip(plain.compile()(key), fast.compile()(key), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_context_restores_the_rule_after_an_error():
    key = jax.random.PRNGKey(0)
    with pytest.raises(RuntimeError), fast_lowering():
        raise RuntimeError("boom")
    assert "while" in _lower(_draws, key).as_text()
