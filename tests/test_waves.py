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
from helpers import TINY, TRAIN_ENV, WAIT_S, assert_same_run_dirs, tiny_args

from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import ConfigError, PPOConfig, preset
from jaxcart.engine.loop import compiled_chunk, initial_state, train
from jaxcart.run.waves import PROCESS_RESERVE_BYTES, USABLE_FRACTION, bytes_per_run, plan_waves
from jaxcart.rundir import reader


def memory_for(config: PPOConfig, runs: int, episodes: int = 2) -> int:
    """The available memory at which ``runs`` runs of ``config`` just fit in one wave."""
    return (
        int(PROCESS_RESERVE_BYTES + runs * bytes_per_run(config, episodes) / USABLE_FRACTION) + 10
    )


@pytest.mark.slow
@pytest.mark.parametrize("name, runs", [("fast", 2), ("sb3", 2), ("purejaxrl", 4)])
def test_estimate_is_above_xlas_own_memory_analysis(name, runs):
    """Measured once, checked always: the estimate per run covers the compiled program's
    arguments, outputs and temporaries as XLA counts them."""
    config = preset(name, total_timesteps=preset(name).batch_size * 4)
    state = initial_state(config, runs, 0)
    runners, configs = jax.device_put(state.runners), jax.device_put(state.config)
    exe, _ = compiled_chunk(EnvParams(), state.chunk_size, runners, configs)
    m = exe.memory_analysis()
    measured = (m.temp_size_in_bytes + m.argument_size_in_bytes + m.output_size_in_bytes) / runs
    assert bytes_per_run(config) >= measured


def test_plan_sizes_waves_for_throughput_capped_by_memory():
    """A million runs of TINY on 2 CPU devices: waves of 32 runs per device, not as many as
    memory holds; fewer when memory is short; balanced;
    --wave-size overrides; and the plan says how long it will take."""
    plan = plan_waves(TINY, 1_000_000, 2, eval_episodes=2, available=10**12)
    assert plan.wave_size == 64 and plan.num_waves == 15_625 and plan.bytes_per_run
    assert "32 runs per cpu device" in plan.why and plan.wave_seconds > 0
    waves = list(plan.waves())
    assert waves[0] == range(0, 64) and waves[-1].stop == 1_000_000
    text = plan.describe("seeds")
    assert text.startswith("1,000,000 seeds in 15,625 waves of 64 (estimated ")
    assert "GB per wave of" in text and "per wave," in text and "in all;" in text
    assert text.endswith("GB of metrics on disk)")
    short = plan_waves(TINY, 1_000_000, 2, eval_episodes=2, available=memory_for(TINY, 51))
    assert short.wave_size == 50 and "as many as fit in memory" in short.why
    balanced = plan_waves(TINY, 66, 2, eval_episodes=2, available=10**12)
    assert balanced.num_waves == 2 and balanced.wave_size == 34  # not 64 + 2
    assert plan_waves(TINY, 3, 2, available=10**12).num_waves == 1
    forced = plan_waves(TINY, 256, 2, available=10**12, wave_size=64)
    assert forced.num_waves == 4 and forced.wave_size == 64 and "--wave-size" in forced.why
    with pytest.raises(ConfigError, match="--wave-size 1,000 needs about"):
        plan_waves(TINY, 5000, 2, available=memory_for(TINY, 51), wave_size=1000)


def test_planning_a_huge_run_is_refused_in_one_line():
    with pytest.raises(ConfigError, match="more than the 2,147,483,647 this trainer counts") as exc:
        plan_waves(preset("sb3", total_timesteps=10**15), 1, 2, available=24 << 30)
    assert "\n" not in str(exc.value)
    # long but countable: its metrics are streamed to disk, so its memory is a short run's,
    # and the plan says how long it takes and how much disk its metrics need
    long = plan_waves(preset("sb3", total_timesteps=10**12), 1, 2, available=24 << 30)
    short = plan_waves(preset("sb3", total_timesteps=10**7), 1, 2, available=24 << 30)
    assert long.bytes_per_run == short.bytes_per_run < 200e6
    assert "days in all" in long.describe() and "GB of metrics on disk" in long.describe()
    assert "on disk" not in plan_waves(preset("sb3"), 64, 2, available=24 << 30).describe()


@pytest.mark.parametrize(
    "num_seeds, wave_size", [(8, 2), pytest.param(4096, 1024, marks=pytest.mark.slow)]
)
def test_a_waved_run_stopped_mid_wave_resumes_in_process(num_seeds, wave_size, tmp_path):
    """8 seeds in waves of 2, and 4,096 in waves of 1,024 (--wave-size): stopped in wave 2
    after a chunk, resumed from its checkpoint, it ends bit-identical to the same plan run
    without a stop."""
    from jaxcart.engine.signals import StopRequest
    from jaxcart.run import lifecycle
    from jaxcart.run.spec import Hooks, RunOptions, RunSpec

    config = PPOConfig(**{**TINY.to_dict(), "total_timesteps": 1024})  # 8 iterations
    options = RunOptions(eval_episodes=2, compile_cache=False, chunk_size=2, wave_size=wave_size)
    spec = RunSpec(config, num_seeds=num_seeds, seed=1)
    whole = lifecycle.run_new(spec, tmp_path / "whole", options)
    assert whole.run.plan.num_waves == 4
    stop, waves = StopRequest(), []

    def on_chunk(progress) -> None:
        if len(waves) == 2 and progress.iteration == 4:
            stop.request(signal.SIGINT)

    hooks = Hooks(on_chunk=on_chunk, on_wave=lambda w, n, runs: waves.append(w))
    part = lifecycle.run_new(spec, tmp_path / "part", options, hooks, stop)
    assert part.stopped and part.stopped_at == (1, 4)
    resumed = lifecycle.resume_run(tmp_path / "part", options)
    assert resumed.run.resume_wave == 1 and resumed.run.resumed_from == 4
    assert_same_run_dirs(tmp_path / "whole", tmp_path / "part")


@pytest.mark.slow
def test_evaluation_json_bound_scales_with_the_declared_seeds(tmp_path):
    """A 100,000-seed evaluation.json (~24 MB, over the 16 MiB bound of other JSON) reads;
    one larger than its config.json declares is refused."""
    from jaxcart.rundir.files import RunDirError

    config = PPOConfig().to_dict()  # a config.json as a run writes it, with its seeds declared
    declared = {"config": config, "num_seeds": 100_000, "eval_episodes": 20}
    (tmp_path / "config.json").write_text(json.dumps(declared))
    seed = {
        "seed_index": 0,
        "gymnasium_returns": [500.0] * 20,
        "gymnasium_mean": 500.0,
        "solved": True,
        "jaxcart_returns": [500.0] * 20,
    }
    text = json.dumps({"seeds": [seed] * 100_000})
    assert len(text) > 16 << 20
    (tmp_path / "evaluation.json").write_text(text)
    assert len(reader.read_evaluation(tmp_path)["seeds"]) == 100_000
    (tmp_path / "config.json").write_text(json.dumps({**declared, "num_seeds": 10}))
    with pytest.raises(RunDirError, match="larger than any"):
        reader.read_evaluation(tmp_path)


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

    deadline = time.monotonic() + WAIT_S
    while not (out / "waves" / "wave-00000.npz").exists() and proc.poll() is None:
        assert time.monotonic() < deadline, f"no first wave in {WAIT_S:.0f} s"
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
