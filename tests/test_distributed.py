"""Two processes talking over 127.0.0.1 with jax.distributed train the same seeds as one
process with two devices: same per-device batch, so bit-identical results."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest
from helpers import WAIT_S, assert_same_run_dirs, tiny_args

from jaxcart.engine.distributed import launch_local

ARGS = [*tiny_args(2048, num_seeds=4), "--no-compile-cache", "--seed", "21"]


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "jaxcart.train", *args]


@pytest.mark.slow
@pytest.mark.parametrize("extra", [[], ["--eval-every", "2", "--keep-best"]], ids=["", "best"])
def test_two_processes_match_one_process(tmp_path, extra):
    single = tmp_path / "single"
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
    args = [*ARGS, *extra]  # with the periodic evaluation, the best policies are gathered too
    done = subprocess.run(
        _cmd(*args, "--out", str(single)), env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr

    multi = tmp_path / "multi"
    procs = launch_local(
        [*args, "--out", str(multi)],
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
    if extra:
        assert (multi / "params_best.npz").is_file()


def test_distributed_needs_out_and_even_split(tmp_path, capsys):
    from jaxcart.train import main

    assert main(["--distributed"]) == 2
    assert "--distributed needs --out" in capsys.readouterr().err
    assert main(["--process-id", "1", "--out", str(tmp_path / "x")]) == 2
    assert "need --distributed" in capsys.readouterr().err


def test_launch_local_waits_and_returns_exit_codes(tmp_path):
    # bad input: each process exits 2 before joining jax.distributed
    codes = launch_local(
        ["--num-seeds", "0", "--out", str(tmp_path / "x")],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    assert codes == [2, 2]
    with pytest.raises(ValueError, match="wait=False"):
        launch_local(["--out", str(tmp_path / "y")], stdout=subprocess.PIPE)
    assert not (tmp_path / "y").exists()


@pytest.mark.slow
def test_launch_local_forwards_sigterm_to_its_processes(tmp_path):
    """SIGTERM to the launching process reaches both trainings: they checkpoint and stop
    together (exit 128 + SIGTERM), and the launcher carries on with its own handler back."""
    out = tmp_path / "dist"
    args = [*tiny_args(10**7, num_seeds=2), "--no-compile-cache", "--out", str(out)]
    before = signal.getsignal(signal.SIGTERM)
    returned = threading.Event()

    def signal_when_training_started() -> None:
        deadline = time.monotonic() + WAIT_S
        while not (out / "checkpoint.npz").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)
        if not returned.is_set():  # 10^7 steps take minutes: still running
            os.kill(os.getpid(), signal.SIGTERM)

    watcher = threading.Thread(target=signal_when_training_started, daemon=True)
    watcher.start()
    try:
        codes = launch_local(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    finally:
        returned.set()
    assert codes == [128 + signal.SIGTERM] * 2
    assert signal.getsignal(signal.SIGTERM) is before
    assert not (out / "params.npz").exists() and (out / "checkpoint.npz").exists()
