"""Your own metrics: functions given as ``PPOConfig(metrics=...)`` are computed inside the
compiled program and reach metrics.csv, the checkpoint's stream, the loggers and plot; the
run directory records their names, so readers know the columns without the functions."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from custom_metrics import mean_abs_pole_angle, not_a_scalar, value_loss_again
from helpers import TINY, assert_same_run_dirs, stopped_run
from test_loggers import read_tfrecords

from jaxcart.core.config import ConfigError, PPOConfig, RecordedMetric, resolve_code
from jaxcart.core.metrics import METRIC_NAMES
from jaxcart.engine.loop import METRIC_COLUMNS, train
from jaxcart.run.lifecycle import resume_run, run_new
from jaxcart.run.spec import RunOptions, RunSpec
from jaxcart.rundir import layout, reader

SMALL = dataclasses.replace(TINY, total_timesteps=1024)  # 8 iterations
MINE = {"custom/pole_angle": mean_abs_pole_angle, "custom/value_loss": value_loss_again}


def test_metrics_are_recorded_by_name_and_rebuilt():
    config = dataclasses.replace(SMALL, metrics=MINE)
    assert config.metric_names == ("custom/pole_angle", "custom/value_loss")
    recorded = config.to_dict()["metrics"]
    assert recorded == {
        "custom/pole_angle": "custom_metrics:mean_abs_pole_angle",
        "custom/value_loss": "custom_metrics:value_loss_again",
    }
    recorded = PPOConfig.from_dict(json.loads(json.dumps(config.to_dict())))
    assert recorded.metric_names == config.metric_names  # readers: names, nothing imported
    assert all(isinstance(fn, RecordedMetric) for _, fn in recorded.metrics)
    assert recorded.to_dict() == config.to_dict()
    assert resolve_code(recorded, trust_code=True) == config  # a resume imports them
    assert "metrics" not in SMALL.to_dict()  # the default config.json is unchanged


@pytest.mark.parametrize(
    ("path", "message"),
    [
        ("__main__:f", "__main__:f: define it at the top level of an importable module"),
        ("nowhere:g", "nowhere:g: ModuleNotFoundError"),
    ],
)
def test_a_function_that_cannot_be_imported_keeps_its_name_and_refuses_to_resume(path, message):
    config = PPOConfig.from_dict({**SMALL.to_dict(), "metrics": {"custom/x": path}})
    assert config.metric_names == ("custom/x",)
    with pytest.raises(ConfigError, match=f"cannot rebuild the run's metric function {message}"):
        resolve_code(config, trust_code=True)


@pytest.mark.parametrize(
    ("metrics", "message"),
    [
        ({"train/loss": mean_abs_pole_angle}, "is a built-in column"),
        ({"seed_index": mean_abs_pole_angle}, "is a built-in column"),
        ({"a,b": mean_abs_pole_angle}, "must be 1-64 letters"),
        ({"custom/x": 3.0}, "must be a function"),
        ([mean_abs_pole_angle], "must be a mapping"),
    ],
)
def test_bad_metrics_are_refused_in_one_line(metrics, message):
    with pytest.raises(ConfigError, match=message):
        dataclasses.replace(SMALL, metrics=metrics)


def test_a_metric_must_return_one_number():
    with pytest.raises(ValueError, match="metric 'custom/r' must return a scalar"):
        train(dataclasses.replace(SMALL, metrics={"custom/r": not_a_scalar}), 1, chunk_size=8)


@pytest.mark.slow
def test_a_custom_metric_reaches_metrics_csv_tensorboard_plot_and_resume(tmp_path):
    pytest.importorskip("tensorboardX")
    from tensorboardX.proto.event_pb2 import Event

    from jaxcart.plot import draw_figure

    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2)
    spec = RunSpec(config=dataclasses.replace(SMALL, metrics=MINE), num_seeds=2)
    tb = dataclasses.replace(options, loggers=("tensorboard",))
    run_new(spec, out=tmp_path / "mine", options=tb)
    run_new(RunSpec(config=SMALL, num_seeds=2), out=tmp_path / "plain", options=options)
    mine = reader.read_metrics_csv(tmp_path / "mine" / layout.METRICS_FILE)

    # the built-in columns first, unchanged by the extra metrics; then the run's own
    assert list(mine)[1:] == [*METRIC_COLUMNS, *MINE]
    assert_same_run_dirs(tmp_path / "mine", tmp_path / "plain")
    np.testing.assert_allclose(mine["custom/value_loss"], mine["train/value_loss"], rtol=1e-6)
    assert np.all((mine["custom/pole_angle"] > 0) & (mine["custom/pole_angle"] < 0.21))

    events = next((tmp_path / "mine" / "tensorboard").glob("*/events.out.tfevents.*"))
    tags = {
        value.tag
        for record in read_tfrecords(events)
        for value in Event.FromString(record).summary.value
    }
    assert set(MINE) <= tags

    curves = reader.load_run(tmp_path / "mine")
    assert curves.custom_metrics == tuple(MINE)
    titles = {ax.get_title() for ax in draw_figure([curves]).axes}
    assert set(MINE) <= titles

    # interrupted after two chunks and resumed: bit-identical, the extra columns included
    run, _ = stopped_run(spec, tmp_path / "resumed", options)
    run.close()
    resume_run(tmp_path / "resumed", options, trust_code=True)
    again = reader.read_metrics_csv(tmp_path / "resumed" / layout.METRICS_FILE)
    for name in (*METRIC_NAMES, *MINE):
        np.testing.assert_array_equal(again[name], mine[name], err_msg=name)
