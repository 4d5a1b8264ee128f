"""A new run's inputs as a trust boundary: seed counts past what a run directory holds,
physics that overflows the float type the env runs in, nested lists in a config file and a
backend JAX cannot start are each refused in one line, exit status 2, before anything is
written (no run directory, no default ``runs/`` one either)."""

from __future__ import annotations

import importlib.util
import subprocess
import sys

import numpy as np
import pytest
from conftest import FAULT_FIGURES
from helpers import TINY, TRAIN_ENV

from jaxcart import train
from jaxcart.core import physics
from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import ConfigError
from jaxcart.run import sweep as sweeps
from jaxcart.run.spec import RunSpec
from jaxcart.rundir.reader import MAX_RUNS

SMALL = ["--preset", "fast", "--total-timesteps", "512", "--quiet", "--no-compile-cache"]


def refused_in_one_line(argv: list[str], tmp_path, capsys, monkeypatch) -> str:
    """Runs ``train.main`` in an empty working directory; asserts exit 2, one line on
    stderr and nothing on disk; returns the line."""
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)  # where a run without --out would make runs/<preset>-<time>
    assert train.main([*SMALL, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err and "Traceback" not in err, err
    assert list(work.iterdir()) == []
    FAULT_FIGURES["hostile inputs: refused in one line, nothing written"] += 1
    return err


@pytest.mark.parametrize(
    "argv",
    [
        ["--num-seeds", "4294967296"],  # H1: grew to 22.7 GB before, and left files behind
        ["--num-seeds", "9223372036854775807"],  # T1: a NumPy traceback before
        ["--num-seeds", str(MAX_RUNS + 1), "--dry-run"],  # could train, but not be read
        ["--num-seeds", str(MAX_RUNS // 2 + 1), "--sweep", "learning_rate=1e-4,2e-4"],
    ],
)
def test_more_runs_than_a_run_directory_holds_are_refused(argv, tmp_path, capsys, monkeypatch):
    err = refused_in_one_line(argv, tmp_path, capsys, monkeypatch)
    assert "--num-seeds" in err and f"{MAX_RUNS:,}" in err


def test_the_bound_is_the_readers_and_is_reached_exactly():
    RunSpec(TINY, num_seeds=MAX_RUNS)  # accepted: the readers accept it
    RunSpec(TINY, num_seeds=MAX_RUNS // 4, sweep={"learning_rate": [1e-4, 2e-4, 3e-4, 4e-4]})
    with pytest.raises(ConfigError):
        RunSpec(TINY, num_seeds=MAX_RUNS + 1)
    with pytest.raises(ConfigError):  # explicit combinations (a search's trials) count too
        RunSpec(TINY, num_seeds=MAX_RUNS, combinations=({"learning_rate": 1e-4},) * 2)


def test_a_waves_configs_are_built_for_its_runs_only():
    """Planning allocates per wave: the arrays of a wave of 4 runs of 2**40 seeds are 4 long
    (the grid's every run would be terabytes), and equal to the full grid's slice."""
    combos = (
        {"learning_rate": 1e-3, "env.length": 0.5},
        {"learning_rate": 2e-3, "env.length": 1.0},
    )
    huge = sweeps.RunGrid(2**40, combos)
    wave = range(2**40 - 2, 2**40 + 2)  # straddles the two combinations
    config = sweeps.grid_config(TINY, huge, wave)
    assert config.learning_rate.tolist() == pytest.approx([1e-3, 1e-3, 2e-3, 2e-3])
    assert sweeps.grid_env_values(huge, wave)["length"].tolist() == [0.5, 0.5, 1.0, 1.0]
    assert huge.seed_indices(wave).tolist() == [2**40 - 2, 2**40 - 1, 0, 1]
    small = sweeps.RunGrid(3, combos)
    for runs in (range(0, 6), range(2, 5)):
        whole = sweeps.grid_config(TINY, small, range(small.num_runs))
        part = sweeps.grid_config(TINY, small, runs)
        for name in ("learning_rate", "clip_coef"):
            got, expected = getattr(part, name), getattr(whole, name)[runs.start : runs.stop]
            assert got.dtype == expected.dtype and np.array_equal(got, expected)


@pytest.mark.parametrize(
    "argv",
    [
        ["--env-param", "length=1e308"],  # S2: each run "diverged at iteration 1" before
        ["--env-param", "gravity=1e39"],
        ["--randomize", "env.length=0.1:1e308"],
        ["--sweep", "env.length=0.5,1e39"],
        ["--env-param", "length=1e-50"],  # positive, but 0 in float32
        ["--env-param", "length=1e-40"],  # the pole's acceleration from rest overflows
        ["--env-param", "masspole=3e38", "--env-param", "masscart=3e38"],  # the total mass
    ],
)
def test_physics_that_overflows_float32_is_refused(argv, tmp_path, capsys, monkeypatch):
    refused_in_one_line(argv, tmp_path, capsys, monkeypatch)


def test_physics_is_checked_in_the_float_type_the_env_runs_in():
    big = EnvParams(gravity=1e39)
    with pytest.raises(ConfigError, match="float32"):
        physics.check_physics(big)  # the tests run in float32
    physics.check_physics(big, np.float64)  # what JAX_ENABLE_X64=1 trains in
    physics.check_physics(EnvParams(length=3e38))  # near the edge: fine


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("nested.toml", "hidden_sizes = [[1, 2], [3]]\n"),  # S3: planned 1,2,3 before
        ("nested.toml", "sweep = {learning_rate = [[1e-3], 2e-3]}\n"),
        ("nested.yaml", "hidden_sizes:\n  - [64, 64]\n"),
    ],
)
def test_a_config_files_nested_list_is_refused(name, text, tmp_path, capsys, monkeypatch):
    path = tmp_path / name
    path.write_text(text)
    err = refused_in_one_line(["--config", str(path)], tmp_path, capsys, monkeypatch)
    assert str(path) in err


@pytest.mark.skipif(
    importlib.util.find_spec("jax_plugins") is not None, reason="a JAX GPU plugin is installed"
)
def test_a_backend_jax_cannot_start_is_one_line_with_what_to_do(tmp_path):
    out = tmp_path / "r"
    proc = subprocess.run(
        [sys.executable, "-m", "jaxcart.train", "--out", str(out)],
        env={**TRAIN_ENV, "JAX_PLATFORMS": "cuda"},  # JAX says only AssertionError
        capture_output=True,
        text=True,
        timeout=300,
    )
    err = proc.stderr.strip()
    assert proc.returncode == 2 and "\n" not in err and "Traceback" not in err, err
    assert "JAX_PLATFORMS" in err and "install" in err
    assert not out.exists()
    FAULT_FIGURES["hostile inputs: refused in one line, nothing written"] += 1
