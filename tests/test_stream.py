"""The metrics stream: a run's metrics go to disk chunk by chunk, so training memory and the
checkpoint's size do not grow with the run's length, and rows written after the last
checkpoint are cut when the run continues."""

from __future__ import annotations

import os

import numpy as np
import pytest
from helpers import TINY, assert_same_run_dirs, stopped_run

from jaxcart.core.config import PPOConfig
from jaxcart.engine.loop import METRIC_COLUMNS, train
from jaxcart.run import lifecycle
from jaxcart.run.spec import RunOptions, RunSpec
from jaxcart.rundir import layout
from jaxcart.rundir.files import MetricsStream, RunDirError, read_stream

COLUMNS = ("a", "b")


def _chunk(start: int, rows: int, runs: int) -> dict[str, np.ndarray]:
    values = np.arange(start, start + rows * runs, dtype=np.float32).reshape(rows, runs)
    return {"a": values, "b": -values}


def test_rows_append_read_back_and_are_cut_to_the_checkpoint(tmp_path):
    path = tmp_path / "m.stream"
    stream = MetricsStream(path, COLUMNS, runs=3, rows=0)
    stream.append(_chunk(0, 2, 3))
    stream.append(_chunk(6, 4, 3))
    read = stream.read()
    np.testing.assert_array_equal(read["a"], np.arange(18, dtype=np.float32).reshape(6, 3))
    np.testing.assert_array_equal(read["b"], -read["a"])
    assert stream.rows == 6 and path.stat().st_size == 6 * 2 * 3 * 4
    (tmp_path / "plain").write_text("")  # the mode open() gives: 0o666 less the umask
    assert path.stat().st_mode & 0o777 == (tmp_path / "plain").stat().st_mode & 0o777
    stream.close()

    # reopened at a checkpoint of 2 rows: the 4 after it are cut, new ones follow
    again = MetricsStream(path, COLUMNS, runs=3, rows=2)
    assert path.stat().st_size == 2 * 2 * 3 * 4
    again.append(_chunk(100, 1, 3))
    np.testing.assert_array_equal(again.read()["a"][2], [100, 101, 102])
    again.close()
    assert read_stream(path, COLUMNS, 3, 0)["a"].shape == (0, 3)

    with pytest.raises(RunDirError, match="holds 3 iterations of metrics, fewer than the 5"):
        MetricsStream(path, COLUMNS, runs=3, rows=5)
    with pytest.raises(RunDirError, match="fewer than the 5 iterations"):
        read_stream(path, COLUMNS, 3, 5)
    os.symlink(path, tmp_path / "link")
    with pytest.raises(RunDirError, match="symbolic link"):
        MetricsStream(tmp_path / "link", COLUMNS, runs=3, rows=0)
    with pytest.raises(ValueError, match="expected 3 runs"):
        MetricsStream(path, COLUMNS, runs=3, rows=0).append(_chunk(0, 1, 2))


@pytest.mark.slow
def test_training_without_kept_metrics_holds_none_and_gives_every_chunk():
    chunks: list[dict] = []
    result = train(
        TINY, 2, 0, chunk_size=8, keep_metrics=False, on_chunk=lambda p: chunks.append(p.metrics)
    )
    kept = train(TINY, 2, 0, chunk_size=8)
    assert result.metrics == {} and len(chunks) == TINY.num_iterations // 8
    for name in METRIC_COLUMNS[:-2]:  # time/* are wall-clock
        np.testing.assert_array_equal(np.concatenate([c[name] for c in chunks]), kept.metrics[name])


@pytest.mark.slow
def test_the_checkpoint_does_not_grow_with_the_run(tmp_path):
    """A run 16 times longer writes a checkpoint of the same size (but for its metadata); its metrics are in the
    stream, one row per iteration."""
    sizes = {}
    for iterations in (2, 32):
        config = PPOConfig(**{**TINY.to_dict(), "total_timesteps": iterations * TINY.batch_size})
        out = tmp_path / str(iterations)
        lifecycle.run_new(RunSpec(config, num_seeds=2), out, RunOptions(eval_episodes=1))
        sizes[iterations] = (out / layout.CHECKPOINT_FILE).stat().st_size
        row = len(METRIC_COLUMNS) * 2 * 4
        assert (out / layout.METRICS_STREAM_FILE).stat().st_size == iterations * row
    # only the metadata's digits differ (30 more iterations of metrics would add 3.6 KB)
    assert abs(sizes[32] - sizes[2]) < 100


def test_rows_written_after_the_checkpoint_are_cut_on_resume(tmp_path):
    """A run killed after writing metrics past its checkpoint (the stream is appended every
    chunk, the checkpoint written every --checkpoint-every seconds): the resumed run cuts
    them and ends bit-identical to an uninterrupted one."""
    small = PPOConfig(**{**TINY.to_dict(), "total_timesteps": 1024})  # 8 iterations
    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2)
    spec = RunSpec(small, num_seeds=2, seed=3)
    lifecycle.run_new(spec, tmp_path / "whole", options)

    run, result = stopped_run(spec, tmp_path / "part", options, chunks=2)
    assert result.state.iteration == 4  # and so is the checkpoint
    run.directory.stream.append({k: np.full((3, 2), 7.0) for k in METRIC_COLUMNS})
    run.close()  # as if killed: 3 rows of junk after the checkpoint's 4
    stream = tmp_path / "part" / layout.METRICS_STREAM_FILE
    assert stream.stat().st_size == 7 * len(METRIC_COLUMNS) * 2 * 4

    resumed = lifecycle.resume_run(tmp_path / "part", options)
    assert resumed.run.resumed_from == 4 and not resumed.stopped
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")
