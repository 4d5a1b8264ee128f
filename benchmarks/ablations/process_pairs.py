"""Whole training processes of two source trees, before and after a change, interleaved.

Each round runs ``python -m jaxcart.train ARGS --quiet --no-compile-cache --out DIR`` once
from each tree (``PYTHONPATH`` set to the tree, a fresh process each time, the order
alternating between rounds so that neither side always runs second), and records the
process's wall time and the compile, train and evaluation seconds its ``evaluation.json``
reports. The report gives every round and the medians: a busy machine slows both sides of a
round alike, so the per-round ratio is the figure to read.

    python -m benchmarks.ablations.process_pairs --before OLD_TREE --after . --pairs 3 \\
        --args "--num-seeds 64"
    python -m benchmarks.ablations.process_pairs --before OLD_TREE --after . --pairs 3 \\
        --args "--preset fast --num-seeds 64" --stem process_pairs_fast

``--after-args`` gives the after side other arguments (one tree, two commands: what an option
costs), for example ``--before . --after . --args "--num-seeds 64" --after-args "--num-seeds 64
--eval-every 10 --keep-best"``.

Writes ``STEM.json`` and ``.md`` to ``--out`` (default ``benchmarks/results/scratch``).
"""

from __future__ import annotations

import json
import os
import shlex
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from benchmarks import lib

TIMINGS = ("compile_seconds", "train_seconds", "eval_seconds")
COLUMNS = ("wall_seconds", "cpu_seconds", *TIMINGS)


def one_process(tree: Path, args: list[str], workdir: Path) -> dict:
    """Runs one training process from ``tree``; its wall seconds and reported timings."""
    out = Path(tempfile.mkdtemp(dir=workdir)) / "run"
    cmd, env = lib.tree_train_command(tree, args)
    start = time.perf_counter()
    process = subprocess.Popen([*cmd, "--out", str(out)], env=env, cwd=tree)
    # CPU seconds (user + system) of the process: on a shared, oversubscribed machine they
    # move far less than wall seconds, which include the time spent waiting for a core
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        raise subprocess.CalledProcessError(os.waitstatus_to_exitcode(status), cmd)
    report = json.loads((out / "evaluation.json").read_text())
    return {
        "wall_seconds": wall,
        "cpu_seconds": usage.ru_utime + usage.ru_stime,
        **{k: report[k] for k in TIMINGS},
        "load": lib.load_average(),
    }


def measure(
    before: Path, after: Path, args: list[str], pairs: int, after_args: list[str] | None = None
) -> dict[str, list[dict]]:
    """``pairs`` rounds of one process per tree, alternating which goes first; the after side
    runs ``after_args`` when given, else ``args``."""
    rows: dict[str, list[dict]] = {"before": [], "after": []}
    sides = {"before": (before, args), "after": (after, args if after_args is None else after_args)}
    with tempfile.TemporaryDirectory() as workdir:
        for i in range(pairs):
            order = ("before", "after") if i % 2 == 0 else ("after", "before")
            for side in order:
                tree, side_args = sides[side]
                rows[side].append(one_process(tree, side_args, Path(workdir)))
                print(f"round {i + 1} {side}: {rows[side][-1]}", flush=True)
    return rows


def medians(rows: list[dict]) -> dict[str, float]:
    return {k: statistics.median(r[k] for r in rows) for k in COLUMNS}


def markdown(report: dict) -> str:
    rows = report["rows"]
    lines = [
        f"# Whole processes before and after: `python -m jaxcart.train {report['args']}`"
        + (f", after: `{report['after_args']}`" if report.get("after_args") else ""),
        "",
        f"{report['pairs']} interleaved rounds; seconds (wall and CPU of the process; compile, "
        "train and evaluation as its `evaluation.json` reports them, wall).",
        "",
        "| round | side | wall | CPU | compile | train | eval | CPU after/before |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for i, (b, a) in enumerate(zip(rows["before"], rows["after"])):
        for side, r in (("before", b), ("after", a)):
            ratio = f"{a['cpu_seconds'] / b['cpu_seconds']:.3f}" if side == "after" else ""
            cells = [r[k] for k in COLUMNS]
            lines.append(
                f"| {i + 1} | {side} | " + " | ".join(f"{c:.1f}" for c in cells) + f" | {ratio} |"
            )
    for side in ("before", "after"):
        m = report["medians"][side]
        cells = [m[k] for k in COLUMNS]
        lines.append(f"| median | {side} | " + " | ".join(f"{c:.1f}" for c in cells) + " | |")
    lines += [
        "",
        f"Median per-round ratio after/before: CPU {report['cpu_ratio']:.3f}, train (wall) "
        f"{report['train_ratio']:.3f}, process wall {report['wall_ratio']:.3f}.",
        "",
        f"Before (BEFORE_TREE): {report['before']}; after: {report['after']}"
        + (", with `--after-args`" if report.get("after_args") else "")
        + ". Load average "
        "(1, 5, 15 min) at the end of each process: "
        + "; ".join(f"{s} {[r['load'] for r in rows[s]]}" for s in ("before", "after"))
        + ".",
        "",
        f"Command: `{report['command']}`",
        "",
    ]
    return "\n".join(lines + lib.machine_markdown(report["machine"]))


def main(argv: list[str] | None = None) -> int:
    parser = lib.arg_parser(__doc__)
    lib.add_tree_options(parser)
    parser.add_argument("--args", default="--num-seeds 64", help="jaxcart.train arguments")
    parser.add_argument(
        "--after-args", help="the after side's jaxcart.train arguments (default: --args)"
    )
    parser.add_argument("--pairs", type=int, default=3)
    parser.add_argument("--stem", default="process_pairs")
    lib.add_out_option(parser)
    args = parser.parse_args(argv)
    args.out = lib.output_dir(args.out)
    after_args = shlex.split(args.after_args) if args.after_args is not None else None
    rows = measure(args.before, args.after, shlex.split(args.args), args.pairs, after_args)
    per_round = list(zip(rows["before"], rows["after"]))
    label = args.before_label or str(args.before)
    report = {
        "command": lib.command_line(),
        "machine": lib.machine_info(),
        "args": args.args,
        "after_args": args.after_args,
        "pairs": args.pairs,
        "before": label,
        "after": str(args.after),
        "rows": rows,
        "medians": {side: medians(r) for side, r in rows.items()},
        "cpu_ratio": statistics.median(a["cpu_seconds"] / b["cpu_seconds"] for b, a in per_round),
        "train_ratio": statistics.median(
            a["train_seconds"] / b["train_seconds"] for b, a in per_round
        ),
        "wall_ratio": statistics.median(
            a["wall_seconds"] / b["wall_seconds"] for b, a in per_round
        ),
    }
    lib.write_report(args.out, args.stem, report, markdown(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
