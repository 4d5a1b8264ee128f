"""Shared helpers of the benchmark scripts: machine details, the exact command, command-line
lists, JSON + Markdown reports and the finishing of their plots.

Imports nothing heavy (no JAX, no torch), so the scripts can use it in every virtualenv,
the rejax one included, and before JAX's device count is set.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.metadata
import json
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
# The committed figures; a run writes here only when asked (``--out benchmarks/results``).
RESULTS_DIR = REPO_ROOT / "benchmarks" / "results"
# Where a run writes by default, ignored by git, so that trying a benchmark cannot overwrite a
# committed figure.
SCRATCH_DIR = RESULTS_DIR / "scratch"

PACKAGES = (
    "jaxcart",
    "jax",
    "jaxlib",
    "flax",
    "optax",
    "numpy",
    "gymnasium",
    "gymnax",
    "envpool",
    "torch",
    "stable-baselines3",
    "rejax",
    "sbx-rl",
    "matplotlib",
)


def command_line() -> str:
    """The command that is running, as it could be typed again from the repository root:
    ``python -m benchmarks.GROUP.NAME ...`` when it was started with ``-m``. Another source
    tree given as ``--before PATH`` (a path of this machine only) reads ``BEFORE_TREE``; this
    tree (``.``) stays as it is."""
    exe = sys.executable
    try:
        exe = os.path.relpath(exe, Path.cwd())
    except ValueError:
        pass
    args = [
        "BEFORE_TREE" if previous == "--before" and arg != "." else arg
        for previous, arg in zip(["", *sys.argv[1:]], sys.argv[1:])
    ]
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is None:  # started as a file (or interactively): argv[0] says what ran
        return shlex.join([exe, sys.argv[0], *args])
    return shlex.join([exe, "-m", spec.name.removesuffix(".__main__"), *args])


def module_command(module: str, python: str | os.PathLike = sys.executable) -> list[str]:
    """``[python, "-m", module]``: how a benchmark starts a worker or a contender in a fresh
    process. Run it with ``cwd=REPO_ROOT``: ``benchmarks`` is not installed, so it imports only
    from the repository root, in the peers' virtualenvs too."""
    return [str(python), "-m", module]


def package_versions(names: tuple[str, ...] = PACKAGES) -> dict[str, str]:
    """Installed version of each distribution, or ``"not installed"``."""
    versions = {}
    for name in names:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def cpu_model() -> str:
    """``model name`` from /proc/cpuinfo (the platform's processor string elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def memory_gib() -> float | None:
    """Total memory from /proc/meminfo, GiB."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return None


def load_average() -> list[float] | None:
    """1, 5 and 15-minute load averages (a busy machine shows here)."""
    try:
        return [float(v) for v in Path("/proc/loadavg").read_text().split()[:3]]
    except OSError:
        return None


def _git(*args: str) -> str:
    """Output of ``git ARGS`` run in the repository, stripped."""
    return subprocess.run(
        ["git", *args], cwd=REPO_ROOT, capture_output=True, text=True, check=True
    ).stdout.strip()


def git_revision() -> str:
    """``HEAD`` of the repository, with ``+dirty`` when the work tree has changes."""
    try:
        rev = _git("rev-parse", "--short", "HEAD")
        dirty = _git("status", "--porcelain", "--untracked-files=no")
        return rev + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def machine_info(jax_devices: list[str] | None = None) -> dict:
    """What produced a figure: CPU, cores, memory, load, OS, Python, packages, JAX devices."""
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None
    return {
        "cpu_model": cpu_model(),
        "logical_cpus": os.cpu_count(),
        "cpus_available": affinity,
        "memory_gib": memory_gib(),
        "load_average": load_average(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "jax_devices": jax_devices,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "packages": package_versions(),
        "git": git_revision(),
        "date_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M:%S"),
    }


def machine_markdown(info: dict) -> list[str]:
    """Markdown bullet lines describing the machine."""
    pkgs = ", ".join(f"{k} {v}" for k, v in info["packages"].items() if v != "not installed")
    lines = [
        f"- CPU: {info['cpu_model']}, {info['logical_cpus']} logical CPU(s) "
        f"({info['cpus_available']} available to this process), {info['memory_gib']} GiB",
        f"- load average at start (1, 5, 15 min): {info['load_average']}",
        f"- {info['platform']}, Python {info['python']}",
    ]
    if info.get("jax_devices"):
        lines.append(f"- JAX devices: {', '.join(info['jax_devices'])}")
    if info.get("xla_flags"):
        lines.append(f"- XLA_FLAGS: `{info['xla_flags']}`")
    lines += [
        f"- packages: {pkgs}",
        f"- jaxcart git revision: {info['git']}; run at {info['date_utc']} UTC",
    ]
    return lines


def markdown_table(headers: list[str], rows: list[list[str]], align: str | None = None) -> str:
    """A GitHub Markdown table; ``align`` is one of l/r per column (default: l then r)."""
    align = align or "l" + "r" * (len(headers) - 1)
    sep = ["---:" if a == "r" else "---" for a in align]
    out = ["| " + " | ".join(headers) + " |", "| " + " | ".join(sep) + " |"]
    out += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(out)


def format_rate(value: float | None) -> str:
    """Steps per second with thousands separators, ``-`` when missing."""
    if value is None:
        return "-"
    if value >= 100:
        return f"{value:,.0f}"
    return f"{value:,.1f}"


def format_ratio(value: float | None) -> str:
    """``12.3x``, ``0.45x``, or ``-``."""
    if value is None:
        return "-"
    if value >= 10:
        return f"{value:,.0f}x"
    if value >= 1:
        return f"{value:.1f}x"
    return f"{value:.2f}x"


def compile_and_time(fn: Callable, args: tuple, repeats: int = 5) -> tuple[float, float]:
    """``(compile seconds, median call seconds)`` of ``jax.jit(fn)(*args)``: compiled ahead of
    time (timed), one warm-up call, then ``repeats`` timed calls, each waited for."""
    import statistics
    import time

    import jax

    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_seconds = time.perf_counter() - start
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - start)
    return compile_seconds, statistics.median(times)


def interleaved_times(calls: dict[str, Callable[[], object]], rounds: int) -> dict[str, list]:
    """Wall seconds of every call, ``rounds`` times, interleaved (one of each per round, so a
    machine that slows down slows them all alike); each call's JAX results are waited for."""
    import time

    import jax

    times: dict[str, list] = {name: [] for name in calls}
    for _ in range(rounds):
        for name, call in calls.items():
            start = time.perf_counter()
            jax.block_until_ready(call())
            times[name].append(time.perf_counter() - start)
    return times


def write_report(out: Path, stem: str, report: dict, text: str) -> None:
    """``out/stem.json`` (the report) and ``out/stem.md`` (``text``), and prints ``text``."""
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / f"{stem}.json", report)
    (out / f"{stem}.md").write_text(text)
    print(text)
    print(f"wrote {display_path(out / stem)}.json and .md")


def write_json(path: Path, data: dict) -> None:
    """Writes ``data`` as indented JSON, creating the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=str) + "\n")


def write_markdown(path: Path, lines: list[str]) -> None:
    """Writes ``lines`` (and a final newline) to ``path`` and prints them."""
    text = "\n".join(lines)
    path.write_text(text + "\n")
    print(text)


def provenance_markdown(report: dict, extra: Iterable[str] = ()) -> list[str]:
    """The end of a report: the command, the machine (then ``extra`` bullet lines) and the
    load average at the end of the run."""
    return [
        f"Command: `{report['command']}`",
        "",
        "Machine:",
        "",
        *machine_markdown(report["machine"]),
        *extra,
        f"- load average at end: {report['load_average_end']}",
        "",
    ]


# Command line


def program_name() -> str | None:
    """``python -m benchmarks.GROUP.NAME`` when a benchmark module is running as the main one
    (argparse would show ``__main__.py``), else ``None`` (argparse's default)."""
    spec = getattr(sys.modules.get("__main__"), "__spec__", None)
    if spec is None or not spec.name.startswith("benchmarks."):
        return None
    return f"python -m {spec.name.removesuffix('.__main__')}"


def arg_parser(doc: str | None) -> argparse.ArgumentParser:
    """An argument parser whose ``--help`` shows the script's docstring as written."""
    return argparse.ArgumentParser(
        prog=program_name(), description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )


def split_list(text: str) -> list[str]:
    """``"a, b,,c"`` -> ``["a", "b", "c"]``."""
    return [v.strip() for v in text.split(",") if v.strip()]


def parse_ints(text: str, error: str = "expected positive integers") -> list[int]:
    """Comma-separated positive integers (an argparse ``type``); ``error`` starts the message
    for values that are not positive."""
    try:
        values = [int(v) for v in split_list(text)]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated integers, got {text!r}"
        ) from None
    if not values or any(v <= 0 for v in values):
        raise argparse.ArgumentTypeError(f"{error}, got {text!r}")
    return values


def add_tree_options(parser: argparse.ArgumentParser) -> None:
    """``--before TREE``, ``--after TREE`` and ``--before-label``: the two source trees a
    before/after benchmark runs ``python -m jaxcart.train`` from (:func:`tree_train_command`)."""
    parser.add_argument("--before", type=Path, required=True, help="source tree before")
    parser.add_argument("--after", type=Path, default=Path("."), help="source tree after")
    parser.add_argument(
        "--before-label",
        default=None,
        help="what the before tree is (e.g. 'git archive 21db35f'), written in its place",
    )


def tree_train_command(tree: Path, args: list[str]) -> tuple[list[str], dict[str, str]]:
    """``python -m jaxcart.train ARGS --quiet --no-compile-cache`` as run from the source tree
    ``tree`` (its ``jaxcart``, through ``PYTHONPATH``): the command and its environment."""
    env = {**os.environ, "PYTHONPATH": str(tree.resolve())}
    return [sys.executable, "-m", "jaxcart.train", *args, "--quiet", "--no-compile-cache"], env


def add_output_options(parser: argparse.ArgumentParser) -> None:
    """``--out`` and ``--from-json``, as every plotting benchmark takes them."""
    add_out_option(parser)
    parser.add_argument(
        "--from-json",
        type=Path,
        default=None,
        help="only re-render the Markdown and plot of an earlier run's JSON (next to it)",
    )


def add_out_option(parser: argparse.ArgumentParser) -> None:
    """``--out DIR``: where the report goes (default the ignored ``benchmarks/results/scratch``;
    ``--out benchmarks/results`` replaces the committed figures)."""
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output folder (default benchmarks/results/scratch, not committed; "
        "--out benchmarks/results replaces the committed results)",
    )


def output_dir(out: Path | None) -> Path:
    """``--out``, or the scratch folder :data:`SCRATCH_DIR`; says which on stdout."""
    out = out or SCRATCH_DIR
    print(f"writing results to {display_path(out)}", flush=True)
    return out


def display_path(path: Path) -> str:
    """``path`` relative to the current directory when it is inside it (shorter to read)."""
    try:
        return str(path.resolve().relative_to(Path.cwd()))
    except ValueError:
        return str(path)


# Reports: JSON, then Markdown and a plot rendered from it


def new_report(
    benchmark: str, settings: dict, contenders: list[str], jax_devices: list[str] | None = None
) -> dict:
    """The start of a report: what ran, the command, the machine and the settings."""
    return {
        "benchmark": benchmark,
        "command": command_line(),
        "machine": machine_info(jax_devices),
        "settings": settings,
        "contenders": contenders,
        "results": [],
    }


Render = Callable[[dict], str]
Plot = Callable[[dict, Path], None]


def write_outputs(report: dict, out: Path, stem: str, markdown: Render, plot: Plot) -> None:
    """Writes the Markdown and the plot of ``report`` to ``out`` and prints the Markdown."""
    text = markdown(report)
    (out / f"{stem}.md").write_text(text)
    plot(report, out / f"{stem}.png")
    print(text)
    print(f"wrote {display_path(out / stem)}.json, .md and .png")


def save_report(report: dict, out: Path, stem: str, markdown: Render, plot: Plot) -> None:
    """Ends a run: the load average now, then the JSON, Markdown and plot in ``out``."""
    report["load_average_end"] = load_average()
    write_json(out / f"{stem}.json", report)
    write_outputs(report, out, stem, markdown, plot)


def rerender(path: Path, stem: str, markdown: Render, plot: Plot) -> None:
    """``--from-json``: the Markdown and plot of a saved report, written next to it."""
    write_outputs(json.loads(path.read_text()), path.parent, stem, markdown, plot)


# Plots


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def machine_title(title: str, machine: dict) -> str:
    """``title`` with the CPU model and the cores used on a second line."""
    return f"{title}\n{machine['cpu_model']}, {machine['cpus_available']} cores"


def finish_loglog(
    fig,
    ax,
    path: Path,
    labels: tuple[str, str, str],
    xticks: list[int] | None = None,
    legend: dict | None = None,
) -> None:
    """Log-log axes, ``labels`` = (x label, y label, title), a grid, the legend (``legend``:
    its keyword arguments) when anything is labelled; saves ``fig`` to ``path`` and closes it.
    With ``xticks``, exactly those x ticks and no minor ticks (grid on the major ones)."""
    xlabel, ylabel, title = labels
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    if xticks is not None:
        ax.set_xticks(xticks, [str(x) for x in xticks])
        ax.minorticks_off()
    ax.grid(True, which="major" if xticks is not None else "both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**(legend or {}))
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    pyplot().close(fig)
