"""How often a two-process run stopped by SIGTERM ends with every process exiting cleanly.

Each trial trains the run of ``tests/test_distributed.py::test_launch_local_forwards_sigterm_to_its_processes``
with each process's stderr kept: ``launch_local`` of a 10^7-step, 2-seed tiny run on
127.0.0.1, then SIGTERM sent to both processes ``--after`` seconds after the first
checkpoint (the test signals the launcher, which forwards it to them), then the exit
codes. ``[143, 143]`` is the stop the docs promise; ``-6`` is a process that
jax.distributed aborted (its last stderr lines are printed).

    python -m benchmarks.ablations.distributed_sigterm --trials 10
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TINY = ["--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64", "--update-epochs", "2"]


def trial(out: Path, after: float) -> tuple[list[int], list[str]]:
    """One SIGTERMed two-process run in ``out``: the exit codes and each process's stderr."""
    from jaxcart.engine.distributed import launch_local

    args = [*TINY, "--total-timesteps", str(10**7), "--num-seeds", "2", "--no-compile-cache"]
    procs = launch_local(
        [*args, "--out", str(out)],
        wait=False,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 600
    while not (out / "checkpoint.npz").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(after)
    for p in procs:
        p.send_signal(signal.SIGTERM)
    errors = [p.communicate(timeout=600)[1] for p in procs]
    return [p.returncode for p in procs], errors


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=10)
    parser.add_argument("--after", type=float, default=1.0, help="seconds after a checkpoint")
    opts = parser.parse_args(argv)
    clean = 0
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(opts.trials):
            codes, errors = trial(Path(tmp) / f"run-{k}", opts.after)
            clean += codes == [128 + signal.SIGTERM] * 2
            print(f"trial {k}: exit codes {codes}", flush=True)
            for i, (code, text) in enumerate(zip(codes, errors)):
                if code < 0:
                    lines = [line for line in text.splitlines() if line.startswith(("E", "F"))]
                    print(f"  process {i}: " + "\n  ".join(lines[-2:]), flush=True)
    print(
        f"{clean}/{opts.trials} trials ended [143, 143] ({os.uname().machine}, {sys.version.split()[0]})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
