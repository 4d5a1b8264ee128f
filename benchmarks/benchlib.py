"""Shared helpers of the benchmark scripts: machine details, the exact command, Markdown.

Imports nothing heavy (no JAX, no torch), so the scripts can use it in every virtualenv,
the rejax one included, and before JAX's device count is set.
"""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent
RESULTS_DIR = REPO_ROOT / "benchmarks" / "results"

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
    "matplotlib",
)


def command_line() -> str:
    """The command that is running, as it could be typed again from the repository root."""
    exe = sys.executable
    try:
        exe = os.path.relpath(exe, Path.cwd())
    except ValueError:
        pass
    return shlex.join([exe, *sys.argv])


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


def git_revision() -> str:
    """``HEAD`` of the repository, with ``+dirty`` when the work tree has changes."""
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
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


def write_json(path: Path, data: dict) -> None:
    """Writes ``data`` as indented JSON, creating the folder."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=str) + "\n")
