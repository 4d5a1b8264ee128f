"""CartPole-v1 environment throughput: steps per second with random actions and autoreset on.

Contenders, each at every number of parallel environments N in ``--sizes``:

- ``jaxcart``: ``jit(scan(vmap(jaxcart.env.step)))`` with actions drawn by ``jax.random``
  inside the scan; the env axis is sharded over all JAX devices (one per CPU core) when N is
  divisible by the device count (see :func:`jaxcart_random_rollout`).
- ``gymnax``: gymnax 1.x ``CartPole-v1`` (its ``step`` autoresets), run the same way.
- ``gymnasium-vector``: Gymnasium's NumPy ``CartPoleVectorEnv``
  (``make_vec(..., vectorization_mode="vector_entry_point")``), actions from ``rng.integers``.
- ``gymnasium-sync``: ``SyncVectorEnv`` of ``gym.make("CartPole-v1")`` (a Python loop over
  N envs); skipped above ``--sync-max-envs``.
- ``envpool``: ``envpool.make("CartPole-v1", env_type="gymnasium", num_envs=N)`` (C++ threads).

Random actions are generated inside the timed region for every contender. Compilation (JAX)
or construction and reset (the others) is timed on its own and excluded from throughput. Each
measurement runs enough steps to take about ``--seconds``; the figure is the median of
``--repeats`` measurements.

    python benchmarks/env_throughput.py                    # the full run (several minutes)
    python benchmarks/env_throughput.py --quick            # smoke test, seconds
    python benchmarks/env_throughput.py --sizes 1,256 --repeats 3 --only jaxcart,gymnax

Writes ``env_throughput.json``, ``.md`` and ``.png`` to ``--out`` (default
``benchmarks/results``, or ``benchmarks/results/quick`` with ``--quick``). Install the
peers with ``bash benchmarks/setup_venvs.sh`` and run with ``benchmarks/.venv-bench/bin/python``;
a contender that is not installed is reported as unavailable.
"""

from __future__ import annotations

from jaxcart import devices

devices.use_all_host_cores()

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchlib  # noqa: E402
from env_throughput_contenders import (  # noqa: E402
    CONTENDERS,
    LABELS,
    MAX_SCAN_LENGTH,
    STEPS_PER_CALL,
    Runner,
    Unavailable,
    make_runner,
)

DEFAULT_SIZES = (1, 16, 256, 4096, 65536)
QUICK_SIZES = (1, 16, 256)
STEM = "env_throughput"


def timed(runner: Runner, calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        runner.call()
    return time.perf_counter() - start


def measure(runner: Runner, repeats: int, seconds: float) -> dict:
    """Warm-up call, then calibrates calls per measurement to take about ``seconds``;
    returns per-repeat seconds and steps/s and their median."""
    runner.call()
    calls, elapsed = 1, timed(runner, 1)
    while elapsed < seconds / 4 and calls < 2**24:
        calls *= 2
        elapsed = timed(runner, calls)
    calls = max(1, round(calls * seconds / max(elapsed, 1e-9)))
    times = [timed(runner, calls) for _ in range(repeats)]
    steps = calls * runner.steps_per_call
    rates = [steps / t for t in times]
    return {
        "steps_per_measurement": steps,
        "seconds": times,
        "steps_per_second": rates,
        "median_steps_per_second": statistics.median(rates),
    }


def run_one(name: str, num_envs: int, args) -> dict:
    row = {"contender": name, "num_envs": num_envs}
    if name == "gymnasium-sync" and num_envs > args.sync_max_envs:
        row.update(status="skipped", reason=f"N > --sync-max-envs {args.sync_max_envs}")
        return row
    try:
        runner = make_runner(name, num_envs)
    except Unavailable as e:
        row.update(status="unavailable", reason=str(e))
        return row
    except Exception as e:  # a peer that fails to build is reported, not fatal
        traceback.print_exc()
        row.update(status="unavailable", reason=f"{type(e).__name__}: {e}")
        return row
    try:
        row.update(status="ok", setup_seconds=runner.setup_seconds, **runner.notes)
        row.update(measure(runner, args.repeats, args.seconds))
    finally:
        runner.close()
    return row


def result(rows: list[dict], name: str, n: int) -> dict | None:
    for r in rows:
        if r["contender"] == name and r["num_envs"] == n:
            return r
    return None


def rate(rows: list[dict], name: str, n: int) -> float | None:
    r = result(rows, name, n)
    return r["median_steps_per_second"] if r and r["status"] == "ok" else None


def cell(rows: list[dict], name: str, n: int) -> str:
    r = result(rows, name, n)
    if r is None:
        return "-"
    if r["status"] == "ok":
        return benchlib.format_rate(r["median_steps_per_second"])
    return r["status"]


def throughput_tables(report: dict) -> tuple[list[str], list[list], list[list], list[list]]:
    """Headers, then the rows of the throughput, speed-up and setup-time tables."""
    rows, sizes, names = report["results"], report["settings"]["sizes"], report["contenders"]
    headers = ["contender"] + [f"N={n:,}" for n in sizes]
    throughput = [[LABELS[c]] + [cell(rows, c, n) for n in sizes] for c in names]
    ratio_rows = []
    for c in names:
        if c == "jaxcart":
            continue
        line = [f"jaxcart / {c}"]
        for n in sizes:
            a, b = rate(rows, "jaxcart", n), rate(rows, c, n)
            line.append(benchlib.format_ratio(a / b if a and b else None))
        ratio_rows.append(line)
    setup_rows = []
    for c in names:
        line = [LABELS[c]]
        for n in sizes:
            r = result(rows, c, n)
            ok = r is not None and r["status"] == "ok"
            line.append(f"{r['setup_seconds']:.2f}" if ok else "-")
        setup_rows.append(line)
    return headers, throughput, ratio_rows, setup_rows


def how_each_runs(report: dict) -> list[str]:
    """The Markdown notes on how the contenders run."""
    s = report["settings"]
    return [
        "How each contender runs:",
        "",
        "- gymnax: `jit(scan(vmap(step)))`, per-env PRNG keys split every step into an action "
        "key (`jax.random.bernoulli`) and a reset key (gymnax's own API takes a key per env).",
        "- jaxcart: `jit(shard_map(scan(step_batch)))`: one key per step for the whole batch, "
        "actions from `jax.random.bits` (one 32-bit word per 32 envs), reset states from "
        "jaxcart's counter hash (`jaxcart.env.hash_uniform`).",
        f"- Both: {s['steps_per_call']:,} env steps per compiled call (scan length at most "
        f"{s['max_scan_length']}); env axis split over the "
        f"{len(report['machine']['jax_devices'])} JAX device(s) when N divides evenly.",
        "- Gymnasium and EnvPool: one `step(rng.integers(0, 2, N))` per call; "
        f"SyncVectorEnv skipped for N > {s['sync_max_envs']:,}. They reset a finished "
        "episode on the env's next step (a step that only resets, counted like the others; "
        "about 1 in 23 with random actions), jaxcart and gymnax on the same step.",
        "",
    ]


def markdown(report: dict) -> str:
    rows, sizes = report["results"], report["settings"]["sizes"]
    headers, throughput, ratio_rows, setup_rows = throughput_tables(report)
    notes = []
    for r in rows:
        if r["status"] != "ok" and (r["status"] == "unavailable" or r["num_envs"] == sizes[-1]):
            notes.append(f"- {r['contender']} N={r['num_envs']:,}: {r['status']}: {r['reason']}")
    s = report["settings"]
    out = [
        "# CartPole-v1 environment throughput",
        "",
        "Env steps per second (all N envs together), uniformly random actions generated inside "
        "the timed loop, autoreset on. Median of "
        f"{s['repeats']} measurements of about {s['seconds']} s each; compile/setup excluded.",
        "",
        benchlib.markdown_table(headers, throughput),
        "",
        "Speed-up of jaxcart over each peer (higher = jaxcart faster):",
        "",
        benchlib.markdown_table(["ratio"] + headers[1:], ratio_rows),
        "",
        "Compile time (JAX contenders) or construction + reset time (others), seconds, "
        "excluded from the throughput above:",
        "",
        benchlib.markdown_table(["contender"] + headers[1:], setup_rows),
        "",
    ]
    if notes:
        out += ["Not measured:", "", *sorted(set(notes)), ""]
    out += how_each_runs(report)
    out += benchlib.provenance_markdown(report)
    return "\n".join(out)


def plot(report: dict, path: Path) -> None:
    rows = report["results"]
    fig, ax = benchlib.pyplot().subplots(figsize=(7, 4.5))
    for c in report["contenders"]:
        pts = [
            (r["num_envs"], r["median_steps_per_second"])
            for r in rows
            if r["contender"] == c and r["status"] == "ok"
        ]
        if pts:
            xs, ys = zip(*pts)
            ax.plot(xs, ys, marker="o", label=LABELS[c], lw=2.5 if c == "jaxcart" else 1.5)
    title = benchlib.machine_title("CartPole-v1 random-action throughput", report["machine"])
    labels = ("parallel environments N", "env steps / s (median)", title)
    benchlib.finish_loglog(fig, ax, path, labels, legend={"fontsize": 8})


def parse_sizes(text: str) -> list[int]:
    return benchlib.parse_ints(text, "sizes must be positive")


def parse_names(text: str) -> list[str]:
    names = benchlib.split_list(text)
    unknown = [n for n in names if n not in CONTENDERS]
    if unknown:
        raise argparse.ArgumentTypeError(
            f"unknown contender(s) {', '.join(unknown)}; choose from {', '.join(CONTENDERS)}"
        )
    return names


def build_parser() -> argparse.ArgumentParser:
    parser = benchlib.arg_parser(__doc__)
    parser.add_argument(
        "--sizes",
        type=parse_sizes,
        default=None,
        help="numbers of envs N (default 1,16,256,4096,65536)",
    )
    parser.add_argument(
        "--repeats",
        type=int,
        default=None,
        help="measurements per point, median reported (default 5)",
    )
    parser.add_argument(
        "--seconds", type=float, default=None, help="target seconds per measurement (default 1.0)"
    )
    parser.add_argument(
        "--only", type=parse_names, default=list(CONTENDERS), help="comma-separated contenders"
    )
    parser.add_argument(
        "--sync-max-envs", type=int, default=4096, help="largest N for SyncVectorEnv"
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke test: N=1,16,256, 2 repeats of 0.1 s"
    )
    benchlib.add_output_options(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.from_json:
        benchlib.rerender(args.from_json, STEM, markdown, plot)
        return 0
    quick = args.quick
    args.sizes = args.sizes or list(QUICK_SIZES if quick else DEFAULT_SIZES)
    args.repeats = args.repeats or (2 if quick else 5)
    args.seconds = args.seconds or (0.1 if quick else 1.0)
    out = benchlib.output_dir(args.out, quick)
    names = [c for c in CONTENDERS if c in args.only]

    jax_devices = [str(d) for d in jax.devices()]
    settings = {
        "sizes": args.sizes,
        "repeats": args.repeats,
        "seconds": args.seconds,
        "sync_max_envs": args.sync_max_envs,
        "steps_per_call": STEPS_PER_CALL,
        "max_scan_length": MAX_SCAN_LENGTH,
        "quick": quick,
    }
    report = benchlib.new_report("env_throughput", settings, names, jax_devices)
    print(f"JAX devices: {', '.join(jax_devices)}")
    for n in args.sizes:
        for name in names:
            row = run_one(name, n, args)
            report["results"].append(row)
            if row["status"] == "ok":
                print(
                    f"N={n:>6,}  {name:<17} {row['median_steps_per_second']:>16,.0f} steps/s "
                    f"(setup {row['setup_seconds']:.2f} s)",
                    flush=True,
                )
            else:
                print(f"N={n:>6,}  {name:<17} {row['status']}: {row['reason']}", flush=True)
    benchlib.save_report(report, out, STEM, markdown, plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
