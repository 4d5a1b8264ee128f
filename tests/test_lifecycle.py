"""The run lifecycle as a library, as a notebook uses it: run, stop, resume and evaluate a run
with a few calls, events through hooks, and nothing printed."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import TINY, assert_same_run_dirs, stopped_run

from jaxcart.core.config import ConfigError, PPOConfig
from jaxcart.run import lifecycle
from jaxcart.run.greedy import evaluate_params
from jaxcart.run.spec import Hooks, RunOptions, RunSpec
from jaxcart.rundir import layout, reader
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.policy import run_params

SMALL = PPOConfig(**{**TINY.to_dict(), "total_timesteps": 1024})  # 8 iterations
OPTIONS = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2)


def test_run_new_writes_a_run_directory_and_prints_nothing(tmp_path, capsys):
    events: dict[str, list] = {"start": [], "compiled": [], "chunk": []}
    hooks = Hooks(
        on_start=lambda run, n, backend: events["start"].append((run.out, n, backend)),
        on_compiled=events["compiled"].append,
        on_chunk=lambda p: events["chunk"].append(p.iteration),
    )
    spec = RunSpec(SMALL, preset="custom", num_seeds=2, seed=4)
    outcome = lifecycle.run_new(spec, tmp_path / "run", OPTIONS, hooks)
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err == ""
    assert events["start"] == [(tmp_path / "run", 2, "cpu")]
    assert len(events["compiled"]) == 1 and events["chunk"] == [2, 4, 6, 8]
    assert not outcome.stopped and outcome.evaluation.gym_returns.shape == (2, 2)
    assert outcome.evaluation.solved.shape == (2,) and outcome.ranking is None
    for name in ("config.json", "metrics.csv", "params.npz", "evaluation.json", "checkpoint.npz"):
        assert (tmp_path / "run" / name).is_file(), name
    info = json.loads((tmp_path / "run" / "config.json").read_text())
    assert info["preset"] == "custom" and info["num_seeds"] == 2 and info["seed"] == 4
    returns = evaluate_params(run_params(tmp_path / "run"), 2)
    np.testing.assert_array_equal(returns, outcome.evaluation.gym_returns)


def test_stop_then_resume_run_matches_an_uninterrupted_run(tmp_path):
    spec = RunSpec(SMALL, num_seeds=2, seed=6)
    lifecycle.run_new(spec, tmp_path / "whole", OPTIONS)

    # A run stopped after its second chunk (as Ctrl-C in a notebook would)...
    run, result = stopped_run(spec, tmp_path / "part", OPTIONS, chunks=2)
    assert result.stopped and result.state.iteration == 4
    with pytest.raises(RunDirError, match="in use by another jaxcart process"):
        lifecycle.resume_run(tmp_path / "part", OPTIONS)  # this process still holds it
    run.close()
    # ...resumes from its checkpoint and ends bit-identical.
    resumed = lifecycle.resume_run(tmp_path / "part", OPTIONS)
    assert resumed.run.resumed_from == 4 and not resumed.stopped
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")
    with pytest.raises(RunDirError, match="nothing to resume"):
        lifecycle.resume_run(tmp_path / "part", OPTIONS)


@pytest.mark.slow
def test_sweep_through_the_library(tmp_path):
    spec = RunSpec(SMALL, num_seeds=2, sweep={"learning_rate": [1e-3, 3e-3]})
    outcome = lifecycle.run_new(spec, tmp_path / "sweep", OPTIONS)
    assert outcome.run.grid.num_runs == 4 and len(outcome.ranking) == 2
    assert reader.is_sweep(tmp_path / "sweep")
    for c in range(2):
        combo = json.loads((layout.combo_dir(tmp_path / "sweep", c) / "config.json").read_text())
        assert combo["config"]["learning_rate"] == [1e-3, 3e-3][c]


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"num_seeds": 0}, "num_seeds must be a positive integer"),
        ({"seed": -1}, "seed must be in"),
        ({"sweep": {"gamma": [0.9, 2.0]}}, "out of range"),
    ],
)
def test_bad_specs_fail_before_anything_is_created(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        RunSpec(SMALL, **kwargs)


def test_bad_options_and_directories(tmp_path):
    with pytest.raises(ConfigError, match="eval_episodes"):
        RunOptions(eval_episodes=0)
    with pytest.raises(ConfigError, match="checkpoint_every"):
        RunOptions(checkpoint_every=0)
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("")
    with pytest.raises(ConfigError, match="not empty"):
        lifecycle.create_run(RunSpec(SMALL), tmp_path / "full")
    with pytest.raises(RunDirError, match="not a directory"):
        lifecycle.resume_run(tmp_path / "missing")


@pytest.mark.slow
def test_a_finished_run_extends_like_a_longer_run(tmp_path, capsys):
    """--resume RUN --total-timesteps N: a finished constant-rate run trains on to N steps
    and ends bit-identical to a run started with N (same chunking)."""
    from jaxcart.train import main

    longer = PPOConfig(**{**SMALL.to_dict(), "anneal_lr": False, "total_timesteps": 2048})
    shorter = PPOConfig(**{**longer.to_dict(), "total_timesteps": 1024})
    lifecycle.run_new(RunSpec(longer, num_seeds=2), tmp_path / "long", OPTIONS)
    lifecycle.run_new(RunSpec(shorter, num_seeds=2), tmp_path / "ext", OPTIONS)
    outcome = lifecycle.resume_run(tmp_path / "ext", OPTIONS, total_timesteps=2048)
    assert not outcome.stopped and outcome.run.resumed_from == 8
    assert_same_run_dirs(tmp_path / "long", tmp_path / "ext")
    info = json.loads((tmp_path / "ext" / "config.json").read_text())
    assert info["config"]["total_timesteps"] == 2048 and info["extended_from"] == [1024]
    # through the command line, and the refusals
    assert main(["--resume", str(tmp_path / "ext"), "--total-timesteps", "4096", "--quiet"]) == 0
    assert "resuming from iteration 16/32" in capsys.readouterr().out
    assert main(["--resume", str(tmp_path / "ext"), "--total-timesteps", "1024"]) == 2
    assert "does not extend" in capsys.readouterr().err


@pytest.mark.slow
def test_an_annealed_run_extends_against_the_new_total(tmp_path):
    """An annealed learning rate, extended from 8 to 16 iterations: iterations 0-7 trained
    at lr * (1 - i/8), the extension at lr * (1 - i/16) (SB3's progress against the new
    total), and config.json records both pieces of the schedule."""
    annealed = PPOConfig(**{**SMALL.to_dict(), "anneal_lr": True})
    lifecycle.run_new(RunSpec(annealed), tmp_path / "annealed", OPTIONS)
    outcome = lifecycle.resume_run(tmp_path / "annealed", OPTIONS, total_timesteps=2048)
    assert not outcome.stopped and outcome.run.resumed_from == 8
    info = json.loads((tmp_path / "annealed" / "config.json").read_text())
    assert info["config"]["total_timesteps"] == 2048 and info["extended_from"] == [1024]
    assert info["lr_schedule"] == [
        {"from_iteration": 0, "num_iterations": 8},
        {"from_iteration": 8, "num_iterations": 16},
    ]
    rates = reader.read_metrics_csv(tmp_path / "annealed" / "metrics.csv")["train/learning_rate"]
    i = np.arange(16)
    expected = annealed.learning_rate * np.where(i < 8, 1 - i / 8, 1 - i / 16)
    np.testing.assert_allclose(rates[:, 0], expected, rtol=1e-6)


@pytest.mark.slow
def test_replay_one_seed_alone_bit_identical_to_its_batch(tmp_path):
    """Seed 2 of a 5-seed run (3 per device on 2 devices), trained again alone: padded to
    its width it matches bit for bit; at its own width of 1 it does not have to."""
    spec = RunSpec(SMALL, num_seeds=5, seed=9)
    lifecycle.run_new(spec, tmp_path / "five", OPTIONS)
    replayed = lifecycle.replay_seed(tmp_path / "five", 2)
    metrics = reader.read_metrics_csv(tmp_path / "five" / "metrics.csv")
    np.testing.assert_array_equal(
        replayed.metrics["train/value_loss"][:, 0], metrics["train/value_loss"][:, 2]
    )
    params = reader.load_params(tmp_path / "five")
    np.testing.assert_array_equal(
        np.asarray(replayed.params["params"]["actor"]["out"]["kernel"])[0],
        params["params"]["actor"]["out"]["kernel"][2],
    )
    with pytest.raises(ConfigError, match="seed_index"):
        lifecycle.replay_seed(tmp_path / "five", 5)


@pytest.mark.slow
def test_replay_of_a_one_seed_run(tmp_path):
    """One seed on a 2-device machine trains on one device; its replay does the same."""
    lifecycle.run_new(RunSpec(SMALL, seed=2), tmp_path / "one", OPTIONS)
    replayed = lifecycle.replay_seed(tmp_path / "one", 0)
    assert replayed.num_devices == 1
    metrics = reader.read_metrics_csv(tmp_path / "one" / "metrics.csv")
    np.testing.assert_array_equal(replayed.metrics["train/value_loss"], metrics["train/value_loss"])


@pytest.mark.slow
def test_replay_above_the_update_group_width_is_bit_identical(tmp_path):
    """17 seeds on 2 devices: 9 per device, so the update runs in groups (2 of width 5, the
    second padded in the program by a copy). Seeds from a first group, a padded group and
    the other device replay alone bit for bit: a run's numbers depend on the width only."""
    spec = lifecycle.RunSpec(SMALL, num_seeds=17, seed=3)
    lifecycle.run_new(spec, tmp_path / "many", OPTIONS)
    metrics = reader.read_metrics_csv(tmp_path / "many" / "metrics.csv")
    params = reader.load_params(tmp_path / "many")
    for seed_index in (1, 7, 12):
        replayed = lifecycle.replay_seed(tmp_path / "many", seed_index)
        np.testing.assert_array_equal(
            replayed.metrics["train/value_loss"][:, 0], metrics["train/value_loss"][:, seed_index]
        )
        np.testing.assert_array_equal(
            np.asarray(replayed.params["params"]["critic"]["out"]["kernel"])[0],
            params["params"]["critic"]["out"]["kernel"][seed_index],
        )


def test_progress_true_draws_one_bar_that_closes_when_training_ends(tmp_path, monkeypatch):
    """``run_new(progress=True)``: a ``tqdm.auto`` bar (a widget in a notebook) over every
    iteration, alongside the caller's hooks, closed before the evaluation starts."""
    import io

    import tqdm.auto

    bars = []

    class Recorded(tqdm.auto.tqdm):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **{**kwargs, "file": io.StringIO()})
            self.total_asked, self.updates, self.closed_at = kwargs["total"], [], None
            bars.append(self)

        def update(self, n=1):
            self.updates.append(n)
            super().update(n)

        def close(self):
            if self.closed_at is None:
                self.closed_at = sum(self.updates)
            super().close()

    monkeypatch.setattr(tqdm.auto, "tqdm", Recorded)
    chunks = []
    hooks = Hooks(on_chunk=lambda p: chunks.append(p.iteration))
    spec = RunSpec(SMALL, num_seeds=2, seed=4)
    lifecycle.run_new(spec, tmp_path / "run", OPTIONS, hooks, progress=True)
    (bar,) = bars
    assert chunks == [2, 4, 6, 8]  # the caller's hooks still run
    assert bar.total_asked == 8 and bar.updates == [2, 2, 2, 2] and bar.closed_at == 8
