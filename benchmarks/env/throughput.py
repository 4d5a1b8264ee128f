"""CartPole-v1 environment throughput: steps per second with random actions and autoreset on.

Contenders, each at every number of parallel environments N in ``--sizes``:

- ``jaxcart``: ``jaxcart.core.cartpole.step_batch`` in the harness's ``jit(shard_map(scan(...)))``.
- ``gymnax``: gymnax 1.x ``CartPole-v1`` (its ``step`` autoresets), ``vmap(env.step)`` in the
  same rollout code.
- ``gymnasium-vector``: Gymnasium's NumPy ``CartPoleVectorEnv``
  (``make_vec(..., vectorization_mode="vector_entry_point")``).
- ``gymnasium-sync``: ``SyncVectorEnv`` of ``gym.make("CartPole-v1")`` (a Python loop over
  N envs); skipped above ``--sync-max-envs``.
- ``envpool``: ``envpool.make("CartPole-v1", env_type="gymnasium", num_envs=N)`` (C++ threads).

Fair by construction (``contenders.py``): every contender gets the same random
actions (one random bit per env and step, generated inside the timed region) and has every
output consumed (a checksum of observations, rewards, terminations and truncations); the two
JAX envs run through one rollout function and differ only in their ``step``. Each setting of
``--cores`` runs in its own worker process: ``1`` pins the process to one core (CPU affinity)
with one JAX device and one EnvPool thread; ``all`` gives it every core, one JAX device per
core (the env axis split over them when N divides evenly) and as many EnvPool threads.
Gymnasium's envs are single-threaded either way. Compilation (JAX) or construction and reset
(the others) is timed on its own and excluded from throughput. Each measurement runs enough
steps to take about ``--seconds``; the figure is the median of ``--repeats`` measurements.

    python -m benchmarks.env.throughput              # the full run (several minutes)
    python -m benchmarks.env.throughput --quick      # smoke test, seconds
    python -m benchmarks.env.throughput --sizes 1,256 --repeats 3 --only jaxcart,gymnax

Writes ``env_throughput.json``, ``.md`` and ``.png`` to ``--out`` (default
``benchmarks/results/scratch``, not committed; ``--out benchmarks/results`` replaces the committed
figures). Install the
peers with ``bash benchmarks/setup_venvs.sh`` and run with ``benchmarks/.venv-bench/bin/python``;
a contender that is not installed is reported as unavailable.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

from benchmarks import lib

# (contenders imports JAX, so only the worker process imports it.)
CONTENDERS = ("jaxcart", "gymnax", "gymnasium-vector", "gymnasium-sync", "envpool")
LABELS = {
    "jaxcart": "jaxcart (step_batch)",
    "gymnax": "gymnax (vmap(step))",
    "gymnasium-vector": "Gymnasium CartPoleVectorEnv (NumPy)",
    "gymnasium-sync": "Gymnasium SyncVectorEnv",
    "envpool": "EnvPool (C++)",
}
CORE_SETTINGS = ("1", "all")

DEFAULT_SIZES = (1, 16, 256, 4096, 65536)
QUICK_SIZES = (1, 16, 256)
STEM = "env_throughput"


def timed(runner, calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        runner.call()
    return time.perf_counter() - start


def measure(runner, repeats: int, seconds: float) -> dict:
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


def run_one(name: str, num_envs: int, args, cores: int) -> dict:
    from benchmarks.env.contenders import Unavailable, make_runner

    row = {"contender": name, "num_envs": num_envs}
    if name == "gymnasium-sync" and num_envs > args.sync_max_envs:
        row.update(status="skipped", reason=f"N > --sync-max-envs {args.sync_max_envs}")
        return row
    try:
        runner = make_runner(name, num_envs, cores)
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


def result(rows: list[dict], name: str, n: int, cores: str) -> dict | None:
    for r in rows:
        if r["contender"] == name and r["num_envs"] == n and r["cores"] == cores:
            return r
    return None


def rate(rows: list[dict], name: str, n: int, cores: str) -> float | None:
    r = result(rows, name, n, cores)
    return r["median_steps_per_second"] if r and r["status"] == "ok" else None


def cell(rows: list[dict], name: str, n: int, cores: str) -> str:
    r = result(rows, name, n, cores)
    if r is None:
        return "-"
    if r["status"] == "ok":
        return lib.format_rate(r["median_steps_per_second"])
    return r["status"]


def throughput_tables(report: dict, cores: str) -> tuple[list[str], list, list, list]:
    """Headers, then the rows of the throughput, speed-up and setup-time tables of one
    ``--cores`` setting."""
    rows, sizes, names = report["results"], report["settings"]["sizes"], report["contenders"]
    headers = ["contender"] + [f"N={n:,}" for n in sizes]
    throughput = [[LABELS[c]] + [cell(rows, c, n, cores) for n in sizes] for c in names]
    ratio_rows = []
    for c in names:
        if c == "jaxcart":
            continue
        line = [f"jaxcart / {c}"]
        for n in sizes:
            a, b = rate(rows, "jaxcart", n, cores), rate(rows, c, n, cores)
            line.append(lib.format_ratio(a / b if a and b else None))
        ratio_rows.append(line)
    setup_rows = []
    for c in names:
        line = [LABELS[c]]
        for n in sizes:
            r = result(rows, c, n, cores)
            ok = r is not None and r["status"] == "ok"
            line.append(f"{r['setup_seconds']:.2f}" if ok else "-")
        setup_rows.append(line)
    return headers, throughput, ratio_rows, setup_rows


def how_each_runs(report: dict) -> list[str]:
    """The Markdown notes on how the contenders run."""
    s = report["settings"]
    return [
        "How each contender runs (the same harness code for all, `benchmarks/env/contenders.py`):",
        "",
        "- Actions: one random bit per env and step, generated inside the timed loop "
        "(JAX: one `jax.random.bits` word per 32 envs, unpacked; host: `rng.integers` bytes, "
        "`np.unpackbits`). Outputs: every step's observations, rewards, terminations and "
        "truncations are summed into a checksum the harness keeps.",
        "- jaxcart and gymnax: one rollout function, `jit(shard_map(scan(step)))`, "
        f"{s['steps_per_call']:,} env steps per compiled call (scan length at most "
        f"{s['max_scan_length']}). Per step one key, split into the action key and the env "
        "key; jaxcart's `step_batch` takes that one key for the batch (its API), gymnax's "
        "`vmap(step)` takes a key per env (its API), made with one `jax.random.split`.",
        "- Gymnasium and EnvPool: one `step(actions)` per call; SyncVectorEnv skipped for "
        f"N > {s['sync_max_envs']:,}. They reset a finished episode on the env's next step "
        "(a step that only resets, counted like the others; about 1 in 23 with random "
        "actions), jaxcart and gymnax on the same step.",
        "- Cores: `1` = the worker process pinned to one core (CPU affinity), one JAX device, "
        "one EnvPool thread. `all` = every core: one JAX device per core with the env axis "
        "split over them when N divides evenly, EnvPool with one thread per core. Gymnasium's "
        "envs are single-threaded in both.",
        "",
    ]


def markdown(report: dict) -> str:
    rows, sizes = report["results"], report["settings"]["sizes"]
    notes = []
    for r in rows:
        if r["status"] != "ok" and (r["status"] == "unavailable" or r["num_envs"] == sizes[-1]):
            notes.append(f"- {r['contender']} N={r['num_envs']:,}: {r['status']}: {r['reason']}")
    s = report["settings"]
    out = [
        "# CartPole-v1 environment throughput",
        "",
        "Env steps per second (all N envs together), uniformly random actions generated inside "
        "the timed loop, every output consumed, autoreset on. Median of "
        f"{s['repeats']} measurements of about {s['seconds']} s each; compile/setup excluded.",
        "",
    ]
    for cores in s["cores"]:
        headers, throughput, ratio_rows, setup_rows = throughput_tables(report, cores)
        cpus = report.get("worker_cpus", {}).get(cores)
        title = "one core" if cores == "1" else f"all cores ({cpus or '?'})"
        out += [
            f"## {title}",
            "",
            lib.markdown_table(headers, throughput),
            "",
            "Speed-up of jaxcart over each peer (higher = jaxcart faster):",
            "",
            lib.markdown_table(["ratio"] + headers[1:], ratio_rows),
            "",
            "Compile time (JAX contenders) or construction + reset time (others), seconds, "
            "excluded from the throughput above:",
            "",
            lib.markdown_table(["contender"] + headers[1:], setup_rows),
            "",
        ]
    if notes:
        out += ["Not measured:", "", *sorted(set(notes)), ""]
    out += how_each_runs(report)
    out += lib.provenance_markdown(report)
    return "\n".join(out)


def plot(report: dict, path: Path) -> None:
    rows = report["results"]
    fig, ax = lib.pyplot().subplots(figsize=(7, 4.5))
    for cores in report["settings"]["cores"]:
        style = "-" if cores == "1" else "--"
        for i, c in enumerate(report["contenders"]):
            pts = [
                (r["num_envs"], r["median_steps_per_second"])
                for r in rows
                if r["contender"] == c and r["status"] == "ok" and r["cores"] == cores
            ]
            if pts:
                xs, ys = zip(*pts)
                where = "1 core" if cores == "1" else "all cores"
                width = 2.5 if c == "jaxcart" else 1.5
                ax.plot(
                    xs,
                    ys,
                    style,
                    marker="o",
                    color=f"C{i}",
                    lw=width,
                    label=f"{LABELS[c]}, {where}",
                )
    title = lib.machine_title("CartPole-v1 random-action throughput", report["machine"])
    labels = ("parallel environments N", "env steps / s (median)", title)
    lib.finish_loglog(fig, ax, path, labels, legend={"fontsize": 7})


def parse_sizes(text: str) -> list[int]:
    return lib.parse_ints(text, "sizes must be positive")


def parse_names(text: str) -> list[str]:
    names = lib.split_list(text)
    unknown = [n for n in names if n not in CONTENDERS]
    if unknown:
        raise argparse.ArgumentTypeError(
            f"unknown contender(s) {', '.join(unknown)}; choose from {', '.join(CONTENDERS)}"
        )
    return names


def parse_cores(text: str) -> list[str]:
    settings = lib.split_list(text)
    unknown = [c for c in settings if c not in CORE_SETTINGS]
    if unknown or not settings:
        raise argparse.ArgumentTypeError("--cores takes a comma-separated list of 1 and all")
    return settings


def build_parser() -> argparse.ArgumentParser:
    parser = lib.arg_parser(__doc__)
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
        "--cores", type=parse_cores, default=list(CORE_SETTINGS), help="1, all or 1,all"
    )
    parser.add_argument(
        "--sync-max-envs", type=int, default=4096, help="largest N for SyncVectorEnv"
    )
    parser.add_argument(
        "--quick", action="store_true", help="smoke test: N=1,16,256, 2 repeats of 0.1 s"
    )
    parser.add_argument("--worker", choices=CORE_SETTINGS, help=argparse.SUPPRESS)
    parser.add_argument("--worker-out", type=Path, help=argparse.SUPPRESS)
    lib.add_output_options(parser)
    return parser


def worker_main(args: argparse.Namespace) -> int:
    """One ``--cores`` setting in this process: sets the cores and JAX devices, then measures
    every contender at every size; writes the rows to ``--worker-out``."""
    if args.worker == "1":
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
        cores = 1
    else:
        from jaxcart.engine import devices

        devices.use_all_host_cores()
        cores = len(os.sched_getaffinity(0))
    import jax

    jax_devices = [str(d) for d in jax.devices()]
    print(f"cores={args.worker}: {cores} core(s), JAX devices: {', '.join(jax_devices)}")
    rows = []
    for n in args.sizes:
        for name in args.only:
            row = run_one(name, n, args, cores)
            row["cores"] = args.worker
            rows.append(row)
            if row["status"] == "ok":
                print(
                    f"cores={args.worker:<3} N={n:>6,}  {name:<17} "
                    f"{row['median_steps_per_second']:>16,.0f} steps/s "
                    f"(setup {row['setup_seconds']:.2f} s)",
                    flush=True,
                )
            else:
                print(
                    f"cores={args.worker:<3} N={n:>6,}  {name:<17} {row['status']}: "
                    f"{row['reason']}",
                    flush=True,
                )
    data = {"rows": rows, "cpus": cores, "jax_devices": jax_devices}
    args.worker_out.write_text(json.dumps(data))
    return 0


def run_worker(cores: str, args: argparse.Namespace, argv: list[str]) -> dict:
    """Runs :func:`worker_main` for ``cores`` in a fresh process (its own devices and pinning)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.json"
        command = [*lib.module_command("benchmarks.env.throughput"), *argv]
        command += ["--worker", cores, "--worker-out", str(out)]
        subprocess.run(command, check=True, cwd=lib.REPO_ROOT)
        return json.loads(out.read_text())


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser().parse_args(argv)
    if args.from_json:
        lib.rerender(args.from_json, STEM, markdown, plot)
        return 0
    quick = args.quick
    args.sizes = args.sizes or list(QUICK_SIZES if quick else DEFAULT_SIZES)
    args.repeats = args.repeats or (2 if quick else 5)
    args.seconds = args.seconds or (0.1 if quick else 1.0)
    args.only = [c for c in CONTENDERS if c in args.only]
    if args.worker:
        return worker_main(args)
    from benchmarks.env.contenders import MAX_SCAN_LENGTH, STEPS_PER_CALL

    out = lib.output_dir(args.out)
    settings = {
        "sizes": args.sizes,
        "repeats": args.repeats,
        "seconds": args.seconds,
        "cores": args.cores,
        "sync_max_envs": args.sync_max_envs,
        "steps_per_call": STEPS_PER_CALL,
        "max_scan_length": MAX_SCAN_LENGTH,
        "quick": quick,
    }
    workers = {cores: run_worker(cores, args, argv) for cores in args.cores}
    jax_devices = workers[args.cores[-1]]["jax_devices"]
    report = lib.new_report("env_throughput", settings, args.only, jax_devices)
    report["worker_cpus"] = {cores: w["cpus"] for cores, w in workers.items()}
    report["results"] = [row for w in workers.values() for row in w["rows"]]
    lib.save_report(report, out, STEM, markdown, plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
