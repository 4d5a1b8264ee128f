"""``python -m jaxcart.plot RUN_DIR [RUN_DIR ...]``: learning curves of jaxcart runs as a PNG.

Panels: episode return (``rollout/ep_rew_mean``) against env steps per seed and against wall
time (``time/elapsed``, seconds of training with compilation excluded), then one panel per key
PPO metric (``train/approx_kl``, ``train/clip_fraction``, ``train/entropy_loss``,
``train/value_loss``, ``train/explained_variance``) against env steps, and a summary of each
run's Gymnasium evaluation.

Each curve is the mean across seeds; the shaded band is a 95% Student-t confidence interval
for that mean across seeds (``mean ± t(0.975, n - 1) · sd / sqrt(n)``, ``sd`` with ``ddof=1``),
computed per iteration from the ``n`` seeds with a finite value there. NaN entries
(``ep_rew_mean`` is NaN until a seed's first episode ends) are left out, so the curve starts
when the first seed has a value and the band when two seeds do; a single-seed run has no band.
Several run directories overlay in one figure, with a legend.

Uses matplotlib's object API (no pyplot), so it never changes the caller's backend.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jaxcart import cli, rundir

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn
    from matplotlib.figure import Figure

RETURN_METRIC = "rollout/ep_rew_mean"
ELAPSED_METRIC = "time/elapsed"
KEY_METRICS = (
    ("train/approx_kl", "approx KL"),
    ("train/clip_fraction", "clip fraction"),
    ("train/entropy_loss", "entropy loss (= -entropy)"),
    ("train/value_loss", "value loss"),
    ("train/explained_variance", "explained variance"),
)
FORMATS = ("png", "svg", "pdf")
CONFIDENCE = 0.95


@dataclass(frozen=True)
class Run:
    """One run directory's curves: metric leaves ``[iterations, num_seeds]``."""

    path: Path
    label: str
    metrics: dict[str, np.ndarray]
    env_steps: np.ndarray  # [iterations], env steps per seed
    elapsed: np.ndarray | None  # [iterations] seconds of training, None if not recorded
    num_seeds: int
    evaluation: dict | None  # evaluation.json, None if missing


def load_run(run_dir: str | os.PathLike, label: str | None = None) -> Run:
    """Reads a run directory's config, metrics and evaluation.

    Raises:
        rundir.RunDirError: ``run_dir`` is not a jaxcart run directory, or its
            ``metrics.csv`` is missing or unreadable.
    """
    path = Path(run_dir)
    info = rundir.read_run_config(path)
    metrics_path = path / rundir.METRICS_FILE
    if not metrics_path.is_file():
        raise rundir.RunDirError(
            f"{path} has no {rundir.METRICS_FILE}: the run did not finish training"
        )
    try:
        metrics = rundir.read_metrics_csv(metrics_path)
    except (OSError, KeyError, ValueError, TypeError) as exc:
        if isinstance(exc, rundir.RunDirError):
            raise
        raise rundir.RunDirError(f"{metrics_path} is corrupted: {exc}") from None
    if "env_steps" not in metrics:
        raise rundir.RunDirError(f"{metrics_path} has no env_steps column")
    env_steps = _first_finite(metrics["env_steps"])
    if ELAPSED_METRIC in metrics:
        elapsed = _first_finite(metrics[ELAPSED_METRIC])
    elif "time/fps" in metrics:
        # Older runs: SB3's fps is env steps per seed / seconds since the start.
        elapsed = env_steps / _first_finite(metrics["time/fps"])
    else:
        elapsed = None
    evaluation = None
    eval_path = path / rundir.EVALUATION_FILE
    if eval_path.is_file():
        try:
            evaluation = json.loads(eval_path.read_text())
        except (OSError, json.JSONDecodeError):
            evaluation = None
    num_seeds = next(iter(metrics.values())).shape[1]
    return Run(
        path=path,
        label=label if label is not None else default_label(path),
        metrics=metrics,
        env_steps=env_steps,
        elapsed=elapsed,
        num_seeds=int(info.get("num_seeds", num_seeds)),
        evaluation=evaluation,
    )


def default_label(path: Path) -> str:
    """The run directory's name (``runs/sb3-x/`` and ``.`` resolve to a real name)."""
    return path.resolve().name or str(path)


def _first_finite(values: np.ndarray) -> np.ndarray:
    """``[iterations, S] -> [iterations]``: the first finite value across seeds (these columns
    are the same for every seed)."""
    values = np.asarray(values, float)
    finite = np.isfinite(values)
    first = np.argmax(finite, axis=1)
    out = values[np.arange(values.shape[0]), first]
    return np.where(finite.any(axis=1), out, np.nan)


def mean_and_band(
    values: np.ndarray, confidence: float = CONFIDENCE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NaN-aware mean across seeds and its Student-t confidence interval.

    Args:
        values: ``[iterations, num_seeds]``, NaN where a seed has no value.

    Returns:
        ``(mean, low, high)``, each ``[iterations]``. ``mean`` is NaN where no seed has a value;
        ``low``/``high`` are NaN where fewer than two seeds do.
    """
    from scipy import stats

    values = np.asarray(values, float)
    finite = np.isfinite(values)
    n = finite.sum(axis=1)
    filled = np.where(finite, values, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, filled.sum(axis=1) / n, np.nan)
        sq = np.where(finite, (values - mean[:, None]) ** 2, 0.0).sum(axis=1)
        sd = np.sqrt(sq / (n - 1))
        t = stats.t.ppf(0.5 + confidence / 2, np.maximum(n - 1, 1))
        half = np.where(n > 1, t * sd / np.sqrt(n), np.nan)
    return mean, mean - half, mean + half


def _plot_metric(ax, x: np.ndarray, values: np.ndarray, colour, label: str | None) -> None:
    mean, low, high = mean_and_band(values)
    ax.plot(x, mean, color=colour, lw=1.6, label=label)
    if np.isfinite(low).any():
        ax.fill_between(x, low, high, color=colour, alpha=0.2, lw=0)


def _no_data(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _summary_lines(run: Run) -> list[str]:
    """One or two lines per run for the summary panel."""
    ret = run.metrics.get(RETURN_METRIC)
    final = ""
    if ret is not None and np.isfinite(ret[-1]).any():
        final = f"final ep_rew_mean {np.nanmean(ret[-1]):.1f}"
    steps = f"{int(run.env_steps[-1]):,} steps/seed" if np.isfinite(run.env_steps[-1]) else ""
    line = ", ".join(p for p in (f"{run.num_seeds} seed(s)", steps, final) if p)
    ev = run.evaluation
    if ev and ev.get("seeds"):
        seeds = ev["seeds"]
        solved = sum(bool(s.get("solved")) for s in seeds)
        mean = np.mean([s.get("gymnasium_mean", np.nan) for s in seeds])
        eval_line = (
            f"Gymnasium: solved {solved}/{len(seeds)}, mean return {mean:.1f}\n"
            f"  ({ev.get('episodes', '?')} greedy episodes per seed)"
        )
    else:
        eval_line = "no evaluation.json"
    return [run.label, "  " + line, "  " + eval_line]


def plot_runs(
    run_dirs: Sequence[str | os.PathLike],
    out: str | os.PathLike | None = None,
    labels: Sequence[str] | None = None,
    dpi: int = 100,
) -> Path:
    """Plots the learning curves of one or several run directories into one image.

    Args:
        run_dirs: jaxcart run directories (what ``python -m jaxcart.train --out`` wrote).
        out: the image to write (``.png``, ``.svg`` or ``.pdf``); default
            ``<run_dirs[0]>/curves.png``, or ``comparison.png`` there for several runs.
        labels: legend labels, one per run (default: each run directory's name).
        dpi: resolution of a PNG (the figure is 15 x 11 inches).

    Returns:
        The path written.

    Raises:
        rundir.RunDirError: a path is not a usable run directory.
        ValueError: bad ``labels``/``out``.
    """

    run_dirs = [Path(p) for p in run_dirs]
    if not run_dirs:
        raise ValueError("give at least one run directory")
    if labels is not None and len(labels) != len(run_dirs):
        raise ValueError(f"got {len(labels)} label(s) for {len(run_dirs)} run directories")
    runs = [load_run(p, labels[i] if labels else None) for i, p in enumerate(run_dirs)]
    if labels is None:
        _disambiguate(runs)
    if out is None:
        out = run_dirs[0] / ("curves.png" if len(runs) == 1 else "comparison.png")
    out = Path(out)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValueError(f"output {out} must end in one of .{', .'.join(FORMATS)}")
    if not out.parent.is_dir():
        raise ValueError(f"cannot write {out}: directory {out.parent} does not exist")

    fig = draw_figure(runs)

    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi)
    rundir.atomic_write_bytes(out, buf.getvalue())
    return out


def draw_figure(runs: list[Run]) -> Figure:
    """The whole figure: return vs steps and vs wall time, the key metrics, the summary."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 11), layout="constrained")
    grid = fig.add_gridspec(3, 6)
    ax_steps = fig.add_subplot(grid[0, 0:3])
    ax_time = fig.add_subplot(grid[0, 3:6])
    metric_axes = [
        fig.add_subplot(grid[1 + k // 3, 2 * (k % 3) : 2 * (k % 3) + 2]) for k in range(5)
    ]
    colours = [f"C{i % 10}" for i in range(len(runs))]
    _draw_curves(runs, colours, ax_steps, ax_time, metric_axes)
    _draw_summary(fig.add_subplot(grid[2, 4:6]), runs, colours)
    num = "one run" if len(runs) == 1 else f"{len(runs)} runs"
    fig.suptitle(
        f"jaxcart PPO on CartPole-v1, {num}: mean across seeds, "
        f"shaded {CONFIDENCE:.0%} Student-t confidence interval",
        fontsize=13,
    )
    return fig


def _draw_curves(runs: list[Run], colours: list[str], ax_steps, ax_time, metric_axes) -> None:

    for run, colour in zip(runs, colours):
        seeds = f"{run.num_seeds} seeds" if run.num_seeds > 1 else "1 seed, no band"
        label = f"{run.label} ({seeds})"
        ret = run.metrics.get(RETURN_METRIC)
        if ret is not None:
            _plot_metric(ax_steps, run.env_steps, ret, colour, label)
            if run.elapsed is not None:
                _plot_metric(ax_time, run.elapsed, ret, colour, label)
        for ax, (name, _) in zip(metric_axes, KEY_METRICS):
            if name in run.metrics:
                _plot_metric(ax, run.env_steps, run.metrics[name], colour, label)

    ax_steps.set(
        title="episode return vs env steps",
        xlabel="env steps per seed",
        ylabel="rollout/ep_rew_mean",
    )
    ax_time.set(
        title="episode return vs wall time",
        xlabel="training wall time [s] (compile excluded)",
        ylabel="rollout/ep_rew_mean",
    )
    if not ax_steps.lines:
        _no_data(ax_steps, f"{RETURN_METRIC} not recorded")
    if not ax_time.lines:
        _no_data(ax_time, f"{RETURN_METRIC} or {ELAPSED_METRIC} not recorded")
    for ax in (ax_steps, ax_time):
        ax.axhline(500, color="0.6", lw=0.8, ls="--")  # CartPole-v1's maximum return
        ax.set_ylim(0, 520)
        ax.grid(alpha=0.3)
    for ax, (name, title) in zip(metric_axes, KEY_METRICS):
        ax.set(title=title, xlabel="env steps per seed", ylabel=name)
        ax.grid(alpha=0.3)
        if not ax.lines:
            _no_data(ax, f"{name} not recorded")
    ax_steps.legend(loc="lower right", fontsize=9)


def _draw_summary(ax_summary, runs: list[Run], colours: list[str]) -> None:
    ax_summary.axis("off")
    offset = 0.0  # points below the panel's top, so each run's block sits under the last
    for run, colour in zip(runs, colours):
        text = "\n".join(_summary_lines(run))
        ax_summary.annotate(
            text,
            xy=(0.0, 1.0),
            xycoords="axes fraction",
            xytext=(0.0, -offset),
            textcoords="offset points",
            va="top",
            ha="left",
            family="monospace",
            fontsize=8.5,
            color=colour,
        )
        offset += 8.5 * 1.25 * (text.count("\n") + 1) + 4


def _disambiguate(runs: list[Run]) -> None:
    """Runs that share a directory name are labelled ``parent/name`` instead."""
    names = [r.label for r in runs]
    for i, run in enumerate(runs):
        if names.count(run.label) > 1:
            resolved = run.path.resolve()
            runs[i] = dataclasses.replace(run, label=f"{resolved.parent.name}/{resolved.name}")


def build_parser() -> argparse.ArgumentParser:
    """The CLI."""
    parser = cli.Parser(
        prog="python -m jaxcart.plot",
        description="Learning curves of jaxcart runs: episode return vs env steps and vs wall "
        "time, and PPO's key metrics, as the mean across seeds with a 95%% Student-t "
        "confidence band. Several run directories overlay.",
    )
    parser.add_argument("run_dirs", nargs="+", type=Path, metavar="RUN_DIR")
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="image to write (.png, .svg, .pdf); default RUN_DIR/curves.png, or "
        "comparison.png in the first RUN_DIR for several",
    )
    parser.add_argument(
        "--label",
        action="append",
        default=None,
        help="legend label; repeat once per RUN_DIR, in order (default: directory names)",
    )
    parser.add_argument("--dpi", type=int, default=100, help="PNG resolution (15x11 in figure)")
    return parser


def _plot_command(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if args.label is not None and len(args.label) != len(args.run_dirs):
        raise cli.UsageError(
            f"got {len(args.label)} --label(s) for {len(args.run_dirs)} RUN_DIR(s); "
            "give one per run directory or none"
        )
    if args.dpi <= 0:
        raise cli.UsageError(f"--dpi must be positive, got {args.dpi}")
    try:
        out = plot_runs(args.run_dirs, args.out, args.label, dpi=args.dpi)
    except OSError as exc:
        raise cli.UsageError(f"cannot write the plot: {exc.strerror or exc}") from None
    print(out)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input)."""
    return cli.run_command(lambda: _plot_command(argv), also=(ValueError,))


if __name__ == "__main__":
    raise SystemExit(main())
