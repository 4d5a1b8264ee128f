"""Does a long run's memory grow with its length? Two source trees, one long training each.

Starts ``python -m jaxcart.train ARGS --checkpoint-every 5 --out DIR`` from each tree in turn
(``PYTHONPATH`` set to the tree), samples the process's resident memory (``VmRSS``) and the
iteration its last checkpoint holds every second, and kills it (SIGKILL) after ``--seconds``:
the run is chosen long enough never to finish. Reports the RSS at the second and last
checkpoint seen, the iterations between them, and the growth per 1,000 iterations; a tree
that keeps every iteration's metrics in memory grows by about ``runs x columns x 4`` bytes
per iteration (plus its checkpoint's copy), one that streams them to disk does not.

    python -m benchmarks.ablations.metrics_memory --before OLD_TREE --after . --seconds 120

Writes ``metrics_memory.json`` and ``.md`` to ``--out`` (default ``benchmarks/results/scratch``).
"""

from __future__ import annotations

import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks import lib

DEFAULT_ARGS = (
    "--preset fast --num-seeds 64 --num-envs 1 --num-steps 8 --minibatch-size 8 "
    "--update-epochs 1 --total-timesteps 10000000 --eval-episodes 1"
)


def rss_bytes(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def checkpoint_iteration(out: Path) -> int | None:
    """The iteration the run's checkpoint holds (its metadata), None before the first."""
    from jaxcart.rundir import files

    try:
        return int(files.read_meta(out / "checkpoint.npz")["iteration"])
    except Exception:  # not written yet, or being replaced this instant
        return None


def one_run(tree: Path, args: list[str], seconds: float, workdir: Path) -> dict:
    out = Path(tempfile.mkdtemp(dir=workdir)) / "run"
    cmd, env = lib.tree_train_command(tree, args)
    cmd += ["--checkpoint-every", "5", "--out", str(out)]
    process = subprocess.Popen(cmd, env=env, cwd=tree)
    samples, start = [], time.monotonic()
    try:
        while time.monotonic() - start < seconds and process.poll() is None:
            time.sleep(1.0)
            rss, iteration = rss_bytes(process.pid), checkpoint_iteration(out)
            if rss is not None:
                samples.append({"t": time.monotonic() - start, "rss": rss, "iteration": iteration})
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    # from the second checkpoint on: the first comes before the program's buffers and
    # the allocator have settled
    seen = [s for s in samples if s["iteration"]]
    seen = [s for s in seen if s["iteration"] > seen[0]["iteration"]] if seen else []
    if len(seen) < 2 or seen[-1]["iteration"] == seen[0]["iteration"]:
        raise RuntimeError(f"{tree}: fewer than three checkpoints in {seconds} s: {samples[-3:]}")
    first = seen[0]
    last = max(seen, key=lambda s: (s["iteration"], s["t"]))
    iterations = last["iteration"] - first["iteration"]
    stream = out / "metrics.stream"
    return {
        "samples": samples,
        "first": first,
        "last": last,
        "peak_rss": max(s["rss"] for s in samples),
        "growth_per_1000_iterations": (last["rss"] - first["rss"]) / iterations * 1000,
        "checkpoint_bytes": (out / "checkpoint.npz").stat().st_size,
        "stream_bytes": stream.stat().st_size if stream.exists() else None,
    }


def markdown(report: dict) -> str:
    lines = [
        f"# Memory of a long run as it trains: `python -m jaxcart.train {report['args']}`",
        "",
        f"Each tree trained for {report['seconds']:.0f} s and was then killed; RSS sampled every "
        "second, iterations read from the checkpoint (every 5 s).",
        "",
        "| tree | iterations seen | RSS at second checkpoint MB | RSS at last MB | growth per "
        "1,000 iterations MB | peak RSS MB | checkpoint MB | metrics.stream MB |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for side in ("before", "after"):
        r = report["results"][side]
        stream = "-" if r["stream_bytes"] is None else f"{r['stream_bytes'] / 1e6:.1f}"
        lines.append(
            f"| {side} | {r['first']['iteration']:,} to {r['last']['iteration']:,} | "
            f"{r['first']['rss'] / 1e6:.0f} | {r['last']['rss'] / 1e6:.0f} | "
            f"{r['growth_per_1000_iterations'] / 1e6:.2f} | {r['peak_rss'] / 1e6:.0f} | "
            f"{r['checkpoint_bytes'] / 1e6:.1f} | {stream} |"
        )
    lines += [
        "",
        f"Before (BEFORE_TREE): {report['before_label']}; after: {report['after']}. Load "
        f"average at the end: {report.get('load_average_end')}.",
        "",
        f"Command: `{report['command']}`",
        "",
    ]
    return "\n".join(lines + lib.machine_markdown(report["machine"]))


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    lib.add_tree_options(parser)
    parser.add_argument("--args", default=DEFAULT_ARGS, help="jaxcart.train arguments")
    parser.add_argument("--seconds", type=float, default=120.0)
    lib.add_out_option(parser)
    args = parser.parse_args(argv)
    args.out = lib.output_dir(args.out)
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info(),
        "args": args.args,
        "seconds": args.seconds,
        "before_label": args.before_label or str(args.before),
        "after": str(args.after),
    }
    report["results"] = {}
    with tempfile.TemporaryDirectory() as workdir:
        for side, tree in (("before", args.before), ("after", args.after)):
            result = one_run(tree, shlex.split(args.args), args.seconds, Path(workdir))
            report["results"][side] = result
            print(f"{side}: {result['growth_per_1000_iterations'] / 1e6:.2f} MB per 1,000")
    report["load_average_end"] = lib.load_average()
    args.out.mkdir(parents=True, exist_ok=True)
    lib.write_json(args.out / "metrics_memory.json", report)
    text = markdown(report)
    (args.out / "metrics_memory.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
