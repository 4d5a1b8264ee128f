"""Two processes talking over 127.0.0.1 with jax.distributed train the same seeds as one
process with two devices: same per-device batch, so bit-identical results."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from helpers import assert_same_run_dirs, tiny_args

from jaxcart.distributed import launch_local

ARGS = [*tiny_args(2048, num_seeds=4), "--no-compile-cache", "--seed", "21"]


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "jaxcart.train", *args]


@pytest.mark.slow
def test_two_processes_match_one_process(tmp_path):
    single = tmp_path / "single"
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    done = subprocess.run(
        _cmd(*ARGS, "--out", str(single)), env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr

    multi = tmp_path / "multi"
    procs = launch_local(
        [*ARGS, "--out", str(multi)],
        wait=False,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    outputs = [p.communicate(timeout=300)[0] for p in procs]
    for p, text in zip(procs, outputs):
        assert p.returncode == 0, text
    assert "2 cpu device(s)" in outputs[0] and "solved" in outputs[0]
    assert outputs[1].strip() == "" or "jaxcart PPO" not in outputs[1]  # only process 0 reports

    assert_same_run_dirs(single, multi)
    assert sorted(p.name for p in multi.iterdir()) == sorted(p.name for p in single.iterdir())


def test_distributed_needs_out_and_even_split(tmp_path, capsys):
    from jaxcart.train import main

    assert main(["--distributed"]) == 2
    assert "--distributed needs --out" in capsys.readouterr().err
    assert main(["--process-id", "1", "--out", str(tmp_path / "x")]) == 2
    assert "need --distributed" in capsys.readouterr().err
