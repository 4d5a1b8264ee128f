"""``python -m jaxcart.plot RUN_DIR [RUN_DIR ...]``: learning curves of jaxcart runs as a PNG.

Panels: episode return (``rollout/ep_rew_mean``) against env steps per seed and against wall
time (``time/elapsed``, seconds of training with compilation excluded), then one panel per key
PPO metric (``train/approx_kl``, ``train/clip_fraction``, ``train/entropy_loss``,
``train/value_loss``, ``train/explained_variance``) against env steps, and a summary of each
run's Gymnasium evaluation; below them, one panel per metric of the run's own (``PPOConfig.metrics``).

Each curve is the mean across seeds; the shaded band is a 95% percentile bootstrap confidence
interval of that mean (:func:`jaxcart.analysis.stats.curve_band`: whole seeds resampled, a fixed seed
so the figure is deterministic), clipped to the metric's range (:data:`METRIC_BOUNDS`: returns
in [0, 500], clip fraction in [0, 1], KL and value loss >= 0, explained variance <= 1, ...).
NaN entries (``ep_rew_mean`` is NaN until a seed's first episode ends) are left out, so the
curve starts when the first seed has a value and the band when two seeds do; a single-seed
run has no band.

The y axes fit the mean curves (with a margin), not the bands, which run past the axes where
they are wider; step axes are labelled ``250k``, ``1.25M``.

Several run directories overlay in one figure, with a legend below the panels. Each run has
its own colour (colour-blind safe) and line style, later runs drawn over earlier ones, thinner
or broken, so that equal curves (the same settings run twice) both stay visible. A sweep
directory (``sweep.json`` and ``combo-000/``, ``combo-001/``, ...) stands for its combinations,
each labelled by its hyperparameter values (``learning_rate=0.001,clip_coef=0.2``). One run is
drawn into ``RUN_DIR/curves.png`` by default (a sweep directory is one run directory), several
into ``comparison.png`` in the current directory, or ``comparison-2.png``, ... when that exists
(never overwritten); the command prints the full path it wrote. From Python,
:func:`plot_runs` returns the matplotlib ``Figure``.

Uses matplotlib's object API (no pyplot), so it never changes the caller's backend.
"""

from __future__ import annotations

import argparse
import io
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jaxcart import cli
from jaxcart.analysis import figures, stats
from jaxcart.core.solved import DEFAULT_ENV, GYMNAX_ENVS, return_bounds
from jaxcart.rundir import files, layout

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn, JAX when runs are read
    from matplotlib.figure import Figure

    from jaxcart.rundir.reader import RunCurves

RETURN_METRIC = "rollout/ep_rew_mean"
EVAL_METRIC = "eval/mean_return"
"""The periodic greedy evaluation (``--eval-every``), drawn as dots over the return curve."""
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
COMPARISON = layout.PLOT_COMPARISON_FILE
"""Where several runs are drawn by default (or comparison-2.png, ... if it exists)."""
SUMMARY_FONTSIZES = (8.5, 8.0, 7.5, 7.0, 6.5)
"""The summary panel's font sizes, tried largest first until every run's block fits."""


def _plot_metric(
    ax, x: np.ndarray, values: np.ndarray, style: figures.Style, name: str
) -> np.ndarray:
    """Draws the mean across seeds and its bootstrap band (:func:`stats.curve_band`, clipped
    to :data:`METRIC_BOUNDS`); returns the mean ``[iterations]``."""
    bounds = METRIC_BOUNDS.get(name, (-math.inf, math.inf))
    mean, low, high = stats.curve_band(values, "mean", bounds=bounds)
    figures.band(ax, x, mean, low, high, alpha=0.18, **style.line())
    return mean


def _summary_lines(run: RunCurves) -> list[str]:
    """Three lines per run for the summary panel (which wraps them to its width): the label,
    seeds, steps and final return, and the Gymnasium evaluation."""
    ret = run.metrics.get(RETURN_METRIC)
    final = ""
    if ret is not None and np.isfinite(ret[-1]).any():
        final = f"final ep_rew_mean {np.nanmean(ret[-1]):.1f}"
    steps = f"{int(run.env_steps[-1]):,} steps/seed" if np.isfinite(run.env_steps[-1]) else ""
    line = ", ".join(p for p in (f"{run.num_seeds} seed(s)", steps, final) if p)
    from jaxcart.results.scores import read_evaluation

    means, solved = read_evaluation(run, required=False)  # the final policies'
    if run.note:
        eval_line = f"not evaluated: {run.note}"
    elif means is not None:
        eval_line = (
            f"Gymnasium: solved {solved}/{means.size}, mean return {means.mean():.1f} "
            f"({run.evaluation.get('episodes', '?')} greedy episodes per seed)"
        )
    else:
        eval_line = "no evaluation.json"
    return [run.label, "  " + line, "  " + eval_line]


def plot_runs(
    run_dirs: Sequence[str | os.PathLike],
    out: str | os.PathLike | None = None,
    labels: Sequence[str] | None = None,
    dpi: int = 100,
) -> Figure:
    """Plots the learning curves of one or several run directories as one figure, which a
    notebook shows inline; with ``out``, also writes it there.

    Args:
        run_dirs: jaxcart run directories (what ``python -m jaxcart.train --out`` wrote); a
            sweep directory stands for its combinations.
        out: the image to write (``.png``, ``.svg`` or ``.pdf``), replaced if it exists;
            ``None`` writes nothing (the command line's default place is
            :func:`default_out`: ``RUN_DIR/curves.png`` for one run directory).
        labels: legend labels, one per entry of ``run_dirs`` (default: each run directory's
            name, or a combination's hyperparameter values; a sweep's label prefixes them).
        dpi: resolution of a PNG (the figure is 15 x 11 inches).

    Returns:
        The matplotlib ``Figure`` (``fig.savefig(...)`` writes it anywhere else).

    Raises:
        files.RunDirError: a path is not a usable run directory.
        ValueError: bad ``labels``/``out``.
    """

    runs = _load_runs(run_dirs, labels)
    if out is None:
        return draw_figure(runs)
    return draw_runs(runs, out, dpi)[1]


def _load_runs(
    run_dirs: Sequence[str | os.PathLike], labels: Sequence[str] | None
) -> list[RunCurves]:
    """:func:`jaxcart.rundir.reader.load_runs`, with one label per run directory or none.

    Raises:
        ValueError: no run directory, or another number of labels.
    """
    if not run_dirs:
        raise ValueError("give at least one run directory")
    if labels is not None and len(labels) != len(run_dirs):
        raise ValueError(
            f"got {len(labels)} label(s) (--label) for {len(run_dirs)} run directories; "
            "give one per run directory or none"
        )
    from jaxcart.rundir.reader import load_runs

    return load_runs([Path(p) for p in run_dirs], labels)


def default_out(run_dirs: Sequence[str | os.PathLike]) -> Path:
    """Where a plot goes without ``--out``: one run directory's own ``RUN_DIR/curves.png``
    (redrawn in place; a sweep directory is one), otherwise the first of ``comparison.png``,
    ``comparison-2.png``, ... in the current directory that does not exist yet, so that an
    earlier comparison is never overwritten."""
    if len(run_dirs) == 1:
        return Path(run_dirs[0]) / layout.CURVES_FILE
    out, number = Path(COMPARISON), 2
    while out.exists():
        out, number = Path(f"{Path(COMPARISON).stem}-{number}.png"), number + 1
    return out


def draw_runs(
    runs: list[RunCurves], out: str | os.PathLike | None = None, dpi: int = 100
) -> tuple[Path, Figure]:
    """Draws loaded runs (:func:`load_runs`) into ``out`` (see :func:`plot_runs`; default
    :func:`default_out`); returns the path written and the figure."""
    from jaxcart.results.scores import named_dir

    out = default_out(list(dict.fromkeys(named_dir(run) for run in runs))) if out is None else out
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
    return out, fig


def draw_figure(runs: list[RunCurves]) -> Figure:
    """The whole figure, laid out: return vs steps and vs wall time, the key metrics, the
    summary, and the legend below the panels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    # the key metrics, then the runs' own (PPOConfig.metrics), each once, three panels a row;
    # slot 5 (row 2, right) is the summary's
    custom = dict.fromkeys(name for run in runs for name in run.custom_metrics)
    panels = [*KEY_METRICS, *((name, name) for name in custom)]
    extra_rows = -(-len(custom) // 3)  # below the built-in ones
    fig = Figure(figsize=(15, 11 + 3.5 * extra_rows), layout="constrained")
    FigureCanvasAgg(fig)  # a renderer to measure text with, before the figure is saved
    grid = fig.add_gridspec(3 + extra_rows, 6)
    ax_steps = fig.add_subplot(grid[0, 0:3])
    ax_time = fig.add_subplot(grid[0, 3:6])
    slots = [k + (k >= 5) for k in range(len(panels))]
    metric_axes = [fig.add_subplot(grid[1 + j // 3, 2 * (j % 3) : 2 * (j % 3) + 2]) for j in slots]
    ax_summary = fig.add_subplot(grid[2, 4:6])
    ax_summary.axis("off")
    styles = figures.run_styles(len(runs))
    _draw_returns(runs, styles, ax_steps, ax_time)
    _draw_metrics(runs, styles, metric_axes, panels)
    _draw_legend(fig, runs, styles)
    num = "one run" if len(runs) == 1 else f"{len(runs)} runs"
    if all(run.num_seeds == 1 for run in runs):
        num += ", 1 seed" if len(runs) == 1 else ", 1 seed per run"
        what = "no confidence band (train several seeds for one)"
    else:
        band = stats.interval_label([run.num_seeds for run in runs if run.num_seeds > 1], "mean")
        if band == f"{stats.CONFIDENCE:.0%} CI":
            band = f"{stats.CONFIDENCE:.0%} bootstrap confidence interval"
        what = (
            f"mean across seeds, shaded {band} (the axes fit the means; a band may run past them)"
        )
    env_ids = sorted({run.env for run in runs})
    fig.suptitle(f"PPO on {', '.join(env_ids)}, {num}: {what}", fontsize=13)
    caption = _caption(ax_time, wall_time_notes(runs)) if ax_time.lines else None
    fig.draw_without_rendering()  # the layout: the panels' sizes are known from here on
    if caption is not None:
        figures.wrap_to_axes(caption, ax_time)
        caption.set_in_layout(True)
        fig.draw_without_rendering()  # again, with room for the wrapped caption
    _draw_summary(ax_summary, runs, styles)
    return fig


def _draw_returns(runs: list[RunCurves], styles: list[figures.Style], ax_steps, ax_time) -> None:
    """The return against env steps (with ``--eval-every``'s greedy evaluations as dots)
    and against wall time."""
    from matplotlib.ticker import MaxNLocator

    from jaxcart.rundir.reader import ELAPSED_METRIC

    env_ids = {run.env for run in runs}
    for run, style in zip(runs, styles):
        ret = run.metrics.get(RETURN_METRIC)
        if ret is not None:
            _plot_metric(ax_steps, run.env_steps, ret, style, RETURN_METRIC)
            if run.elapsed is not None:
                _plot_metric(ax_time, run.elapsed, ret, style, RETURN_METRIC)
        evaluated = run.metrics.get(EVAL_METRIC, np.full((1, 1), np.nan))
        rows = np.isfinite(evaluated).any(axis=1)  # the iterations --eval-every evaluated at
        if rows.any():
            mean = np.nanmean(evaluated[rows], axis=1)
            ax_steps.plot(
                run.env_steps[rows], mean, "o", color=style.color, ms=4, label=EVAL_METRIC
            )

    evaluated = any(line.get_label() == EVAL_METRIC for line in ax_steps.lines)
    ax_steps.set(
        title="episode return vs env steps" + (f" (dots: {EVAL_METRIC})" if evaluated else ""),
        xlabel="env steps per seed",
        ylabel="rollout/ep_rew_mean",
    )
    ax_time.set(
        title="episode return vs wall time",
        xlabel="training wall time [s] (compile excluded)",
        ylabel="rollout/ep_rew_mean",
    )
    if not ax_steps.lines:
        figures.no_data(ax_steps, f"{RETURN_METRIC} not recorded")
    if not ax_time.lines:
        figures.no_data(ax_time, f"{RETURN_METRIC} or {ELAPSED_METRIC} not recorded")
    for ax in (ax_steps, ax_time):
        if env_ids == {DEFAULT_ENV}:
            ax.axhline(500, color="0.6", lw=0.8, ls="--")  # CartPole-v1's maximum return
            ax.set_ylim(0, 520)  # the whole range of returns: panels of different runs compare
        elif len(env_ids) == 1:  # the env's range of returns, and its reward_threshold
            (env_id,) = env_ids
            low, high = return_bounds(env_id)
            ax.axhline(GYMNAX_ENVS[env_id], color="0.6", lw=0.8, ls="--")
            ax.set_ylim(low - 0.04 * (high - low), high + 0.04 * (high - low))
        ax.grid(alpha=0.3)
    figures.step_axis(ax_steps.xaxis)
    ax_time.xaxis.set_major_locator(MaxNLocator(nbins=6))


def _draw_metrics(
    runs: list[RunCurves],
    styles: list[figures.Style],
    axes: list,
    panels: list[tuple[str, str]],
) -> None:
    """One panel per ``(metric, title)`` against env steps, for every run that records it;
    the y axis fits the means within the metric's range (the bands are clipped to the axes,
    not the axes to them)."""
    from jaxcart.core.envs import ACTION_COUNTS

    for ax, (name, title) in zip(axes, panels):
        means = [
            _plot_metric(ax, run.env_steps, run.metrics[name], style, name)
            for run, style in zip(runs, styles)
            if name in run.metrics
        ]
        ax.set(title=title, xlabel="env steps per seed", ylabel=name)
        ax.grid(alpha=0.3)
        figures.step_axis(ax.xaxis)
        bounds = METRIC_BOUNDS.get(name, (-math.inf, math.inf))
        if name == "train/entropy_loss":  # -entropy of the most actions any run's env has
            bounds = (-math.log(max(ACTION_COUNTS[run.env] for run in runs)), 0.0)
        limits = figures.curve_limits(means, bounds)
        if limits is None:
            figures.no_data(ax, f"{name} not recorded")
        else:
            ax.set_ylim(limits)


def _draw_legend(fig, runs: list[RunCurves], styles: list[figures.Style]) -> None:
    """One entry per run below the panels, outside the data, in as many columns as fit."""
    from matplotlib.lines import Line2D

    labels = [
        f"{run.label} ({f'{run.num_seeds} seeds' if run.num_seeds > 1 else '1 seed, no band'})"
        for run in runs
    ]
    handles = [Line2D([], [], **style.line()) for style in styles]
    # About 0.6 em a character at 9 pt, plus the handle and gaps: the columns that fit 14 in.
    columns = int(14 * 72 / (max(map(len, labels)) * 9 * 0.6 + 60))
    fig.legend(
        handles,
        labels,
        loc="outside lower center",
        ncols=max(1, min(len(labels), columns, 4)),
        fontsize=9,
        handlelength=4,
        frameon=False,
    )


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


def _text_below(ax, text: str, xy, xycoords, below: float, **style):
    """``text`` from ``xy`` down, ``below`` points under it, left-aligned; left out of the
    layout (the panel is laid out already, or will be once the text is wrapped to it)."""
    offset = {"xytext": (0.0, -below), "textcoords": "offset points"}
    text = ax.annotate(text, xy, xycoords=xycoords, va="top", ha="left", **offset, **style)
    text.set_in_layout(False)
    return text


def _caption(ax, notes: list[str]):
    """Notes under a panel's x label, off the data; None without notes. Left out of the layout
    until :func:`figures.wrap_to_axes` has wrapped them (unwrapped, they would squeeze the
    panel)."""
    if not notes:
        return None
    text = "\n".join(f"note: {note}" for note in notes)
    where = ("axes fraction", ax.xaxis.label)
    return _text_below(ax, text, (0.0, 0.0), where, 4.0, fontsize=8.5, color="0.3")


def _draw_summary(ax, runs: list[RunCurves], styles: list[figures.Style]) -> None:
    """Each run's block (:func:`_summary_lines`) in its colour, wrapped to the laid-out
    panel; smaller type for many runs, and at the smallest the runs that still do not fit
    are counted instead."""
    renderer = ax.figure.canvas.get_renderer()
    to_points = 72 / ax.figure.dpi
    height = ax.get_window_extent(renderer).height * to_points
    blocks = ["\n".join(_summary_lines(run)) for run in runs]
    for size in SUMMARY_FONTSIZES:
        texts, tops, top = [], [], 0.0
        for block, style in zip(blocks, styles):
            texts.append(_summary_text(ax, block, style.color, size, top))
            tops.append(top)
            top += texts[-1].get_window_extent(renderer).height * to_points + size / 2
        if top <= height or size == SUMMARY_FONTSIZES[-1]:
            break
        for text in texts:
            text.remove()
    if top > height:  # even the smallest type overflows: drop the last runs, say how many
        keep = len(texts) - 1
        while keep > 0 and tops[keep] + 2 * size > height:
            keep -= 1
        for text in texts[keep:]:
            text.remove()
        more = f"... and {len(texts) - keep} more run(s): see the legend"
        _summary_text(ax, more, "0.3", size, tops[keep])


def _summary_text(ax, block: str, colour: str, size: float, top: float):
    """One block of the summary, ``top`` points below the panel's top, wrapped to its width."""
    style = {"family": "monospace", "fontsize": size, "color": colour}
    text = _text_below(ax, block, (0.0, 1.0), "axes fraction", top, **style)
    figures.wrap_to_axes(text, ax)
    return text


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
        help="image to write (.png, .svg, .pdf), replaced if it exists; default "
        "RUN_DIR/curves.png for one run or sweep directory (redrawn in place), and for several "
        "comparison.png in the current directory, or comparison-2.png, comparison-3.png, ... "
        "if that exists: an earlier comparison is never overwritten",
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
    cli.check_dpi(args.dpi)
    runs = _load_runs(args.run_dirs, args.label)
    for run in runs:
        if not run.metrics:
            raise cli.UsageError(
                f"{run.path} is an evaluation (python -m jaxcart.evaluate --out): no learning "
                "curves to plot; python -m jaxcart.compare reads it"
            )
    try:
        out, _ = draw_runs(runs, args.out, dpi=args.dpi)
    except OSError as exc:
        raise cli.UsageError(f"cannot write the plot: {exc.strerror or exc}") from None
    for line in unfinished_notes(runs):
        print(f"note: {line}", file=sys.stderr)
    if args.out is None and out.parent == Path() and out.name != COMPARISON:
        print(
            f"note: {COMPARISON} exists and is kept: drew into {out} (--out FILE to choose)",
            file=sys.stderr,
        )
    print(out.absolute())  # the full path: several runs' figure goes to the current folder
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
