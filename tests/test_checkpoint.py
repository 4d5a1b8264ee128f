"""Checkpoints: one tree-file format (leaves under their tree paths), structure/shape checks,
torn files rejected, and the iteration-0 checkpoint of a new run."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from helpers import TINY

from jaxcart.core.config import PPOConfig
from jaxcart.engine.loop import METRIC_COLUMNS, initial_state
from jaxcart.rundir import files
from jaxcart.rundir.directory import save_checkpoint
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.reader import load_checkpoint, read_checkpoint_meta


def test_checkpoint_rejects_other_structures(tmp_path):
    state = initial_state(TINY, 2, 0)
    path = tmp_path / "c.npz"
    save_checkpoint(path, state, {})
    other = initial_state(PPOConfig(**{**TINY.to_dict(), "hidden_sizes": (32, 32)}), 2, 0)
    with pytest.raises(RunDirError, match="shape"):
        load_checkpoint(path, other)
    deeper = initial_state(PPOConfig(**{**TINY.to_dict(), "hidden_sizes": (64, 64, 64)}), 2, 0)
    with pytest.raises(RunDirError, match="different structure"):
        load_checkpoint(path, deeper)
    path.write_bytes(path.read_bytes()[:1000])  # torn file
    with pytest.raises(RunDirError, match="corrupted"):
        read_checkpoint_meta(path)


def test_leaves_are_stored_under_their_tree_paths(tmp_path):
    """The documented format: names like state/runners/params/params/actor/hidden_0/kernel,
    the same names params.npz uses below its root."""
    state = initial_state(TINY, 2, 0)
    path = tmp_path / "c.npz"
    save_checkpoint(path, state, {"k": 1})
    arrays, meta = files.load_tree(path)
    assert meta["k"] == 1 and meta["iteration"] == 0 and meta["checkpoint_format"] == 3
    kernel = arrays["state/runners/params/params/actor/hidden_0/kernel"]
    np.testing.assert_array_equal(
        kernel, state.runners.params["params"]["actor"]["hidden_0"]["kernel"]
    )
    assert "state/hyperparams/learning_rate" in arrays
    assert not any(name.startswith("metrics/") for name in arrays)  # in metrics.stream
    assert meta["metrics_columns"] == list(METRIC_COLUMNS)
    files.save_tree(tmp_path / "params.npz", files.flatten(state.runners.params))
    params, _ = files.load_tree(tmp_path / "params.npz")
    np.testing.assert_array_equal(params["params/actor/hidden_0/kernel"], kernel)


def test_round_trip_restores_every_leaf(tmp_path):
    state = initial_state(TINY, 3, 4)
    path = tmp_path / "c.npz"
    save_checkpoint(path, state, {})
    loaded = load_checkpoint(path, initial_state(TINY, 3, 99))
    for x, y in zip(jax.tree.leaves(state.runners), jax.tree.leaves(loaded.runners), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert loaded.metrics == {}  # the metrics so far are the stream's


def test_old_format_refused_with_a_clear_message(tmp_path):
    path = tmp_path / "c.npz"
    files.save_tree(path, {"leaf0": np.zeros(3)}, {"checkpoint_format": 1})
    with pytest.raises(RunDirError, match="format 1"):
        read_checkpoint_meta(path)
