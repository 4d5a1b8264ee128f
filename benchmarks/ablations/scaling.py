"""Seeds per second on 1 CPU device, 2 host devices (one process) and 2 processes
(jax.distributed over 127.0.0.1, one device each): the same CLI command each time.

    python -m benchmarks.ablations.scaling --seeds 16 --out benchmarks/results

Each configuration runs ``python -m jaxcart.train`` in fresh processes (compile cache off) and
reads the training time (compile excluded) from the run's ``evaluation.json``; seeds/s is
seeds x (env steps per seed / 81,920) / train seconds, i.e. SB3-sized runs per second. Writes
``scaling.json`` and ``scaling.md`` to ``--out`` (default ``benchmarks/results/scratch``, not
committed).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import lib
from jaxcart.engine.distributed import launch_local

KINDS = ("1 device", "2 host devices", "2 processes")


def env_for(devices: int) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    return {
        **env,
        "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}",
        "JAX_PLATFORMS": "cpu",
    }


def run(kind: str, args: list[str], out: Path) -> dict:
    cmd = [sys.executable, "-m", "jaxcart.train", *args, "--out", str(out)]
    start = time.perf_counter()
    if kind == "2 processes":
        procs = launch_local(
            [*args, "--out", str(out)],
            wait=False,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        texts = [p.communicate()[0] for p in procs]
        if any(p.returncode for p in procs):
            raise RuntimeError("\n".join(texts))
    else:
        devices = 1 if kind == "1 device" else 2
        done = subprocess.run(cmd, env=env_for(devices), capture_output=True, text=True)
        if done.returncode:
            raise RuntimeError(done.stdout + done.stderr)
    wall = time.perf_counter() - start
    ev = json.loads((out / "evaluation.json").read_text())
    return {
        "train_seconds": ev["train_seconds"],
        "compile_seconds": ev["compile_seconds"],
        "process_wall_seconds": wall,
        "solved": ev["solved_seeds"],
    }


def measure(kind: str, args: list[str], repeats: int, tmp: Path, seeds: int, steps: int) -> dict:
    """``repeats`` runs of one configuration (``steps``: env steps per seed): the median
    training time, seeds/s and SB3-sized runs/s, and every run."""
    results = [run(kind, args, tmp / f"{kind.replace(' ', '-')}-{i}") for i in range(repeats)]
    train = sorted(r["train_seconds"] for r in results)[len(results) // 2]
    return {
        "median_train_seconds": train,
        "seeds_per_second": seeds / train,
        "sb3_runs_per_second": seeds * steps / 81_920 / train,
        "runs": results,
    }


def markdown_lines(report: dict, repeats: int) -> list[str]:
    """The Markdown summary of ``scaling.json``."""
    rows = report["results"]
    base = rows["1 device"]["seeds_per_second"]
    lines = [
        f"# Scaling: {report['seeds']} seeds of the `{report['preset']}` preset",
        "",
        f"Command: `{report['command']}` (median of {repeats} runs each; training time, "
        "compile excluded).",
        "",
        "| configuration | train s | seeds/s | speed-up |",
        "|---|---:|---:|---:|",
    ]
    for kind, row in rows.items():
        lines.append(
            f"| {kind} | {row['median_train_seconds']:.2f} | {row['seeds_per_second']:.2f} | "
            f"{row['seeds_per_second'] / base:.2f}x |"
        )
    return [*lines, "", *lib.machine_markdown(report["machine"])]


def main() -> None:
    parser = lib.arg_parser(__doc__)
    parser.add_argument("--seeds", type=int, default=16)
    parser.add_argument("--preset", default="sb3")
    parser.add_argument("--repeats", type=int, default=3)
    lib.add_out_option(parser)
    a = parser.parse_args()
    a.out = lib.output_dir(a.out)
    from jaxcart.core.config import preset

    config = preset(a.preset)
    args = ["--preset", a.preset, "--num-seeds", str(a.seeds), "--quiet", "--no-compile-cache"]
    args += ["--eval-episodes", "2"]
    steps, rows = config.env_steps_per_seed, {}
    with tempfile.TemporaryDirectory() as tmp:
        for kind in KINDS:
            rows[kind] = measure(kind, args, a.repeats, Path(tmp), a.seeds, steps)
            print(kind, json.dumps(rows[kind]), flush=True)
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info(),
        "preset": a.preset,
        "seeds": a.seeds,
        "results": rows,
    }
    lib.write_json(a.out / "scaling.json", report)
    lib.write_markdown(a.out / "scaling.md", markdown_lines(report, a.repeats))


if __name__ == "__main__":
    main()
