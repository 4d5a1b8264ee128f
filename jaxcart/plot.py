"""``python -m jaxcart.plot RUN_DIR [RUN_DIR ...]``: learning curves of jaxcart runs as a PNG.

Panels: episode return (``rollout/ep_rew_mean``) against env steps per seed and against wall
time (``time/elapsed``, seconds of training with compilation excluded), then one panel per key
PPO metric (``train/approx_kl``, ``train/clip_fraction``, ``train/entropy_loss``,
``train/value_loss``, ``train/explained_variance``) against env steps, and a summary of each
run's Gymnasium evaluation.

Each curve is the mean across seeds; the shaded band is a 95% percentile bootstrap confidence
interval of that mean (:func:`jaxcart.analysis.stats.curve_band`: whole seeds resampled, a fixed seed
so the figure is deterministic), clipped to the metric's range (:data:`METRIC_BOUNDS`: returns
in [0, 500], clip fraction in [0, 1], KL and value loss >= 0, explained variance <= 1, ...).
NaN entries (``ep_rew_mean`` is NaN until a seed's first episode ends) are left out, so the
curve starts when the first seed has a value and the band when two seeds do; a single-seed
run has no band.

Several run directories overlay in one figure, with a legend. A sweep directory (``sweep.json``
and ``combo-000/``, ``combo-001/``, ...) stands for its combinations, each labelled by its
hyperparameter values (``learning_rate=0.001,clip_coef=0.2``). One run is drawn into
``RUN_DIR/curves.png`` by default, several into ``comparison.png`` in the current directory.

Uses matplotlib's object API (no pyplot), so it never changes the caller's backend.
"""

from __future__ import annotations

import argparse
import io
import math
import os
import sys
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jaxcart import cli
from jaxcart.analysis import stats
from jaxcart.rundir import files, layout
from jaxcart.rundir.runs import (
    ELAPSED_METRIC,
    RunCurves,
    load_runs,
)

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn
    from matplotlib.figure import Figure

RETURN_METRIC = "rollout/ep_rew_mean"
KEY_METRICS = (
    ("train/approx_kl", "approx KL"),
    ("train/clip_fraction", "clip fraction"),
    ("train/entropy_loss", "entropy loss (= -entropy)"),
    ("train/value_loss", "value loss"),
    ("train/explained_variance", "explained variance"),
)
METRIC_BOUNDS: dict[str, tuple[float, float]] = {
    "rollout/ep_rew_mean": (0.0, 500.0),  # CartPole-v1 pays 1 per step, at most 500 steps
    "rollout/ep_rew_max": (0.0, 500.0),
    "rollout/ep_len_mean": (0.0, 500.0),
    "train/approx_kl": (0.0, math.inf),  # (r - 1) - log r >= 0
    "train/clip_fraction": (0.0, 1.0),
    "train/entropy_loss": (-math.log(2.0), 0.0),  # -entropy of two actions
    "train/value_loss": (0.0, math.inf),
    "train/explained_variance": (-math.inf, 1.0),
}
"""Each metric's range; confidence bands are clipped to it."""
FORMATS = ("png", "svg", "pdf")
CONFIDENCE = stats.CONFIDENCE


def mean_and_band(
    values: np.ndarray,
    bounds: tuple[float, float] = (-math.inf, math.inf),
    confidence: float = CONFIDENCE,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """NaN-aware mean across seeds and its percentile bootstrap confidence interval
    (:func:`jaxcart.analysis.stats.curve_band`, deterministic), clipped to ``bounds``.

    Args:
        values: ``[iterations, num_seeds]``, NaN where a seed has no value.

    Returns:
        ``(mean, low, high)``, each ``[iterations]``. ``mean`` is NaN where no seed has a value;
        ``low``/``high`` are NaN where fewer than two seeds do.
    """
    return stats.curve_band(values, "mean", confidence=confidence, bounds=bounds)


def _plot_metric(
    ax, x: np.ndarray, values: np.ndarray, colour, label: str | None, name: str
) -> None:
    mean, low, high = mean_and_band(values, METRIC_BOUNDS.get(name, (-math.inf, math.inf)))
    ax.plot(x, mean, color=colour, lw=1.6, label=label)
    if np.isfinite(low).any():
        ax.fill_between(x, low, high, color=colour, alpha=0.2, lw=0)


def _no_data(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _summary_lines(run: RunCurves) -> list[str]:
    """One or two lines per run for the summary panel."""
    ret = run.metrics.get(RETURN_METRIC)
    final = ""
    if ret is not None and np.isfinite(ret[-1]).any():
        final = f"final ep_rew_mean {np.nanmean(ret[-1]):.1f}"
    steps = f"{int(run.env_steps[-1]):,} steps/seed" if np.isfinite(run.env_steps[-1]) else ""
    line = ", ".join(p for p in (f"{run.num_seeds} seed(s)", steps, final) if p)
    ev = run.evaluation
    if run.note:
        eval_line = f"not evaluated: {run.note}"
    elif ev and ev.get("seeds"):
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
        run_dirs: jaxcart run directories (what ``python -m jaxcart.train --out`` wrote); a
            sweep directory stands for its combinations.
        out: the image to write (``.png``, ``.svg`` or ``.pdf``); default
            ``<run_dirs[0]>/curves.png`` for one run, ``comparison.png`` in the current
            directory for several (a sweep is several).
        labels: legend labels, one per entry of ``run_dirs`` (default: each run directory's
            name, or a combination's hyperparameter values; a sweep's label prefixes them).
        dpi: resolution of a PNG (the figure is 15 x 11 inches).

    Returns:
        The path written.

    Raises:
        files.RunDirError: a path is not a usable run directory.
        ValueError: bad ``labels``/``out``.
    """

    run_dirs = [Path(p) for p in run_dirs]
    if not run_dirs:
        raise ValueError("give at least one run directory")
    if labels is not None and len(labels) != len(run_dirs):
        raise ValueError(f"got {len(labels)} label(s) for {len(run_dirs)} run directories")
    return draw_runs(load_runs(run_dirs, labels), out, dpi)


def draw_runs(runs: list[RunCurves], out: str | os.PathLike | None = None, dpi: int = 100) -> Path:
    """Draws loaded runs (:func:`load_runs`) into ``out`` (see :func:`plot_runs`)."""
    if out is None:
        out = (
            runs[0].path / layout.CURVES_FILE
            if len(runs) == 1
            else Path(layout.PLOT_COMPARISON_FILE)
        )
    out = Path(out)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValueError(f"output {out} must end in one of .{', .'.join(FORMATS)}")
    if not out.parent.is_dir():
        raise ValueError(f"cannot write {out}: directory {out.parent} does not exist")

    fig = draw_figure(runs)

    buf = io.BytesIO()
    fig.savefig(buf, format=fmt, dpi=dpi)
    files.atomic_write_bytes(out, buf.getvalue())
    return out


def draw_figure(runs: list[RunCurves]) -> Figure:
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
        f"shaded {CONFIDENCE:.0%} bootstrap confidence interval",
        fontsize=13,
    )
    return fig


def _draw_curves(runs: list[RunCurves], colours: list[str], ax_steps, ax_time, metric_axes) -> None:

    for run, colour in zip(runs, colours):
        seeds = f"{run.num_seeds} seeds" if run.num_seeds > 1 else "1 seed, no band"
        label = f"{run.label} ({seeds})"
        ret = run.metrics.get(RETURN_METRIC)
        if ret is not None:
            _plot_metric(ax_steps, run.env_steps, ret, colour, label, RETURN_METRIC)
            if run.elapsed is not None:
                _plot_metric(ax_time, run.elapsed, ret, colour, label, RETURN_METRIC)
        for ax, (name, _) in zip(metric_axes, KEY_METRICS):
            if name in run.metrics:
                _plot_metric(ax, run.env_steps, run.metrics[name], colour, label, name)

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
    else:
        draw_notes(ax_time, wall_time_notes(runs))
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


def wall_time_notes(runs: list[RunCurves]) -> list[str]:
    """What the wall-time axis does not say: a run's seeds (and a sweep's combinations)
    train together in one program, so its wall time covers all of them."""
    notes = []
    counts = sorted({run.num_seeds for run in runs})
    if len(counts) > 1:
        notes.append(
            f"different seed counts ({', '.join(map(str, counts))}): each run's wall time "
            "is for all its seeds trained together"
        )
    if any(run.combination for run in runs):
        notes.append("a sweep's combinations train in one program: they share its wall time")
    return notes


def draw_notes(ax, notes: list[str], fontsize: float = 8.5, width: int = 60) -> None:
    """Notes in the top left corner of a panel, over a white background."""
    if notes:
        ax.text(
            0.02,
            0.98,
            "\n".join(textwrap.fill(note, width) for note in notes),
            transform=ax.transAxes,
            va="top",
            fontsize=fontsize,
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
        )


def _draw_summary(ax_summary, runs: list[RunCurves], colours: list[str]) -> None:
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


def build_parser() -> argparse.ArgumentParser:
    """The CLI."""
    parser = cli.Parser(
        prog="python -m jaxcart.plot",
        description="Learning curves of jaxcart runs: episode return vs env steps and vs wall "
        "time, and PPO's key metrics, as the mean across seeds with a 95% bootstrap "
        "confidence band clipped to each metric's range. Several run directories overlay; "
        "a sweep directory stands for its combinations. A run or sweep that did not finish "
        "is drawn so far from its checkpoint (and says so).",
    )
    parser.add_argument("run_dirs", nargs="+", type=Path, metavar="RUN_DIR")
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="image to write (.png, .svg, .pdf); default RUN_DIR/curves.png for one run, "
        "comparison.png in the current directory for several (or a sweep)",
    )
    parser.add_argument(
        "--label",
        action="append",
        default=None,
        help="legend label; repeat once per RUN_DIR, in order (default: directory names, "
        "and a sweep combination's hyperparameter values, which a sweep's label prefixes)",
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
    cli.check_dpi(args.dpi)
    runs = load_runs(args.run_dirs, args.label)
    try:
        out = draw_runs(runs, args.out, dpi=args.dpi)
    except OSError as exc:
        raise cli.UsageError(f"cannot write the plot: {exc.strerror or exc}") from None
    for line in unfinished_notes(runs):
        print(f"note: {line}", file=sys.stderr)
    print(out)
    return 0


def unfinished_notes(runs: list[RunCurves]) -> list[str]:
    """One line per unfinished run or sweep: what was drawn, and what is missing."""
    lines = []
    for path in dict.fromkeys(run.path for run in runs if run.note):
        mine = [run for run in runs if run.path == path]
        what = (
            f"a sweep: its {len(mine)} combinations drawn"
            if mine[0].combination
            else "curves drawn"
        )
        lines.append(
            f"{path}: {what} {mine[0].note}; no Gymnasium evaluation until it finishes "
            f"(python -m jaxcart.train --resume {path})"
        )
    return lines


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input)."""
    return cli.run_command(lambda: _plot_command(argv), also=(ValueError,))


if __name__ == "__main__":
    cli.command_main(main)
