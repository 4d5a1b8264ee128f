"""Memory-aware planning: the estimate, the plan, and runs trained in waves (one run
directory, resumable mid-wave, each wave's runs as they train in a batch of that width)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import jax
import numpy as np
import pytest
from helpers import TINY, TRAIN_ENV, assert_same_run_dirs, tiny_args

from jaxcart.core.config import ConfigError, PPOConfig, preset
from jaxcart.core.env import EnvParams
from jaxcart.engine.trainer import compiled_chunk, initial_state, train
from jaxcart.run.waves import PROCESS_RESERVE_BYTES, USABLE_FRACTION, bytes_per_run, plan_waves
from jaxcart.rundir import reader


def memory_for(config: PPOConfig, runs: int, episodes: int = 2) -> int:
    """The available memory at which ``runs`` runs of ``config`` just fit in one wave."""
    return (
        int(PROCESS_RESERVE_BYTES + runs * bytes_per_run(config, episodes) / USABLE_FRACTION) + 10
    )


@pytest.mark.parametrize("name, runs", [("fast", 2), ("sb3", 2), ("purejaxrl", 4)])
def test_estimate_is_above_xlas_own_memory_analysis(name, runs):
    """Measured once, checked always: the estimate per run covers the compiled program's
    arguments, outputs and temporaries as XLA counts them."""
    config = preset(name, total_timesteps=preset(name).batch_size * 4)
    state = initial_state(config, runs, 0)
    runners, hps = jax.device_put(state.runners), jax.device_put(state.hyperparams)
    exe, _ = compiled_chunk(config, EnvParams(), state.chunk_size, runners, hps)
    m = exe.memory_analysis()
    measured = (m.temp_size_in_bytes + m.argument_size_in_bytes + m.output_size_in_bytes) / runs
    assert bytes_per_run(config) >= measured


def test_plan_fills_memory_in_multiples_of_the_device_count():
    per_run = bytes_per_run(TINY, 2)
    plan = plan_waves(TINY, 1_000_000, 2, eval_episodes=2, available=memory_for(TINY, 77_825))
    assert plan.wave_size == 77_824 and plan.num_waves == 13
    assert plan.wave_size % 2 == 0 and plan.bytes_per_run == per_run
    waves = list(plan.waves())
    assert waves[0] == range(0, 77_824) and waves[-1].stop == 1_000_000 and len(waves) == 13
    text = plan.describe("seeds")
    assert text.startswith("1,000,000 seeds in 13 waves of 77,824 (estimated ")
    assert "GB per wave of" in text and "GB available" in text
    assert plan_waves(TINY, 3, 2, available=10**12).num_waves == 1


def test_not_even_one_run_per_device_is_a_clear_error():
    with pytest.raises(ConfigError, match="not enough memory for one run per device"):
        plan_waves(preset("sb3"), 8, 2, available=PROCESS_RESERVE_BYTES + 1000)


WAVED = [*tiny_args(1024, num_seeds=5, eval_episodes=2), "--seed", "3", "--no-compile-cache"]
WAVED_CONFIG = preset(
    "sb3", num_envs=4, num_steps=32, total_timesteps=1024, minibatch_size=64, update_epochs=2
)  # what WAVED trains


@pytest.fixture(scope="module")
def waved_run(tmp_path_factory):
    """5 seeds in waves of 2 (memory limited by JAXCART_MEMORY_BYTES)."""
    from jaxcart.train import main

    out = tmp_path_factory.mktemp("waves") / "run"
    config = PPOConfig(**{**WAVED_CONFIG.to_dict()})
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JAXCART_MEMORY_BYTES", str(memory_for(config, 2)))
        assert main([*WAVED, "--out", str(out)]) == 0
    return out


def test_waves_make_one_run_directory(waved_run):
    info = json.loads((waved_run / "config.json").read_text())
    assert info["wave_size"] == 2 and info["num_seeds"] == 5
    assert sorted(p.name for p in (waved_run / "waves").iterdir()) == [
        "wave-00000.npz",
        "wave-00001.npz",
        "wave-00002.npz",
    ]
    evaluation = json.loads((waved_run / "evaluation.json").read_text())
    assert [s["seed_index"] for s in evaluation["seeds"]] == [0, 1, 2, 3, 4]
    assert evaluation["waves"] == 3
    metrics = reader.read_metrics_csv(waved_run / "metrics.csv")
    assert metrics["train/value_loss"].shape == (8, 5)
    assert reader.load_params(waved_run)["params"]["actor"]["out"]["kernel"].shape == (5, 64, 2)


def test_each_wave_trains_as_a_batch_of_its_width(waved_run):
    """Seeds 2 and 3 (wave 1) match those seeds trained together alone, bit for bit."""
    config = reader.read_run_config(waved_run)["config"]
    alone = train(config, 2, seed=3, seed_indices=np.array([2, 3]))
    metrics = reader.read_metrics_csv(waved_run / "metrics.csv")
    np.testing.assert_array_equal(
        metrics["train/value_loss"][:, 2:4], alone.metrics["train/value_loss"]
    )
    params = reader.load_params(waved_run)
    np.testing.assert_array_equal(
        params["params"]["critic"]["out"]["kernel"][2:4],
        np.asarray(alone.params["params"]["critic"]["out"]["kernel"]),
    )


@pytest.mark.slow
def test_a_waved_run_stopped_mid_wave_resumes_bit_identically(waved_run, tmp_path):
    from conftest import FAULT_FIGURES

    from jaxcart.train import main

    out = tmp_path / "stopped"
    memory = str(memory_for(WAVED_CONFIG, 2))
    env = {**TRAIN_ENV, "JAXCART_MEMORY_BYTES": memory}
    command = [sys.executable, "-m", "jaxcart.train", *WAVED, "--out", str(out)]
    proc = subprocess.Popen(
        [*command, "--checkpoint-every", "0.01"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )

    deadline = time.monotonic() + 120
    while not (out / "waves" / "wave-00000.npz").exists() and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    text, _ = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("finished before SIGINT")
    assert proc.returncode == 130 and "Traceback" not in text, text
    FAULT_FIGURES["waved runs stopped mid-run"] += 1
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JAXCART_MEMORY_BYTES", memory)
        assert main(["--resume", str(out), "--quiet"]) == 0
    assert_same_run_dirs(waved_run, out)
    FAULT_FIGURES["interrupted runs verified bit-identical"] += 1
