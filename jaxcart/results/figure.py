"""Every figure jaxcart draws, and the helpers they are drawn with (matplotlib's object API,
never pyplot, so the caller's backend is never changed).

- :func:`draw_figure`: ``python -m jaxcart.plot``'s learning curves (its module docstring says
  what each panel shows).
- :func:`draw_comparison`: ``compare.png``, the figure of a
  :class:`~jaxcart.results.scores.Comparison`. Top row: each run's IQM, median over seeds, mean
  and optimality gap with their intervals, each written out; IQM, median and mean share one
  score axis (the envs' range of returns: [0, 500] on CartPole-v1, [-500, 0] on Acrobot-v1),
  and no panel spans less than a tenth of it (:data:`MIN_SPAN`), so that a small difference
  looks small; the optimality gap is the shortfall from the env's solved return. Middle: the
  IQM difference and ``P(X > Y)`` against the baseline, and the performance profile (fraction
  of seeds scoring at least tau, the fraction at the solved return marked: 500 on CartPole-v1).
  Bottom: sample efficiency (IQM across seeds of ``rollout/ep_rew_mean``), the fraction of
  seeds whose training had produced an episode at the solved return by env steps, and the
  all-pairs ``P(X > Y)`` matrix. Wall time is left out: it depends on the machine and its load
  (``python -m jaxcart.plot`` draws it).
- :func:`draw_robustness`: ``robustness.png``, ``python -m jaxcart.evaluate --sweep``'s return
  against a physics value.
- Helpers: :func:`run_styles` (a colour from Okabe and Ito's colour-blind-safe palette and a
  line style per run), :func:`metric_bounds` (a metric's range on an env),
  :func:`curve_limits` (y limits that fit the mean curves, not their bands),
  :func:`return_axis` (an env's range of returns and its solved threshold), :func:`step_axis`
  (``250k``, ``1.25M``), :func:`wrap_to_width` and :func:`wrap_to_axes` (monospace text
  wrapped to a laid-out panel), :func:`band` (a curve with its confidence band),
  :func:`no_data` and :func:`save` (one file, written atomically).

Importing this module imports neither matplotlib nor JAX (``python -m jaxcart.plot --help``
stays fast); both come in when a figure is drawn from runs read.
"""

from __future__ import annotations

import io
import math
import textwrap
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from jaxcart.analysis import stats
from jaxcart.analysis.summary import RETURN_METRIC, first_reached
from jaxcart.core.solved import SOLVED_BY, return_bounds, solved_return
from jaxcart.rundir import files

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn, JAX when runs are read
    from pathlib import Path

    from matplotlib.figure import Figure

    from jaxcart.results.scores import Comparison
    from jaxcart.rundir.reader import RunCurves

PALETTE = ("#0072B2", "#E69F00", "#009E73", "#D55E00", "#56B4E9", "#CC79A7", "#000000")
"""Okabe and Ito's colour-blind-safe colours (their yellow is left out: too faint on white)."""
LINE_STYLES = (
    ("-", 2.2),
    ((0, (5, 2.5)), 1.7),
    ((0, (1, 1.5)), 1.9),
    ((0, (6, 2.5, 1.5, 2.5)), 1.3),
)
"""Solid, dashed, dotted and dash-dot, each with its width: with 7 colours and 4 styles the
first 28 runs all differ, and a thinner or broken line drawn over an equal curve leaves it seen."""
Y_MARGIN = 0.08
"""Room above and below the mean curves, as a fraction of their range."""


def run_styles(count: int) -> list[dict]:
    """How each of ``count`` runs is drawn in every panel and the legend: ``Axes.plot``'s
    ``color``, ``ls``, ``lw`` and ``zorder``. Colour and line style both change from one run
    to the next, and later runs draw on top (dashed or dotted over solid, so that equal
    curves both show)."""
    styles = []
    for i in range(count):
        linestyle, width = LINE_STYLES[i % len(LINE_STYLES)]
        color = PALETTE[i % len(PALETTE)]
        styles.append({"color": color, "ls": linestyle, "lw": width, "zorder": 2.0 + i / 1000})
    return styles


def curve_limits(
    curves: Sequence[np.ndarray], bounds: tuple[float, float] = (-math.inf, math.inf)
) -> tuple[float, float] | None:
    """Axis limits that fit the mean curves (not their bands) with a margin
    (:data:`Y_MARGIN` of their range on each side), kept inside the metric's range unless a
    curve reaches its edge (then the margin keeps the line visible).

    Args:
        curves: each ``[iterations]``, NaN where there is no value.
        bounds: the metric's range (``jaxcart.plot.METRIC_BOUNDS``).

    Returns:
        ``(low, high)`` with ``low < high``, or None if no curve has a finite value.
    """
    finite = [c[np.isfinite(c)] for c in curves]
    values = np.concatenate(finite) if finite else np.empty(0)
    if values.size == 0:
        return None
    lo, hi = float(values.min()), float(values.max())
    # A flat curve gets a margin from its size (or an absolute one at zero).
    pad = (hi - lo) * Y_MARGIN if hi > lo else max(abs(hi) * Y_MARGIN, 1e-3)
    low = lo - pad if lo <= bounds[0] else max(lo - pad, bounds[0])
    high = hi + pad if hi >= bounds[1] else min(hi + pad, bounds[1])
    return low, high


def band(ax, x, point, low, high, color: str, alpha: float = 0.2, **line) -> None:
    """A curve ``point`` and, where it has finite values, its band ``[low, high]`` (each
    ``[len(x)]``) in ``color``; ``line``: ``Axes.plot``'s keywords (``lw``, ``label``)."""
    ax.plot(x, point, color=color, **line)
    if np.isfinite(low).any():
        ax.fill_between(x, low, high, color=color, alpha=alpha, lw=0)


def return_axis(ax, env_ids: Sequence[str]) -> None:
    """A y axis of episode returns: the env's whole range (from 0 when that is its least, so
    that panels of different runs compare) and its solved threshold dashed (left as it is
    for several envs)."""
    if len(set(env_ids)) == 1:
        low, high = return_bounds(env_ids[0])
        pad = 0.04 * (high - low)
        ax.axhline(SOLVED_BY[env_ids[0]][1], color="0.6", lw=0.8, ls="--")
        ax.set_ylim(low - pad if low < 0 else low, high + pad)


def save(fig: Figure, out: Path, dpi: int = 100) -> None:
    """Writes ``fig`` to ``out`` atomically, in the format its suffix names (png, svg, pdf)."""
    buf = io.BytesIO()
    fig.savefig(buf, format=out.suffix.lower().lstrip("."), dpi=dpi)
    files.atomic_write_bytes(out, buf.getvalue())


def no_data(ax, text: str) -> None:
    """``text`` in grey in the middle of an empty panel."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _finish(ax, empty: str, legend: str | None = None, **labels) -> bool:
    """``labels`` (``Axes.set``'s: title, axis labels, limits), a grid, and ``empty`` written
    in the middle if no run was drawn, else a legend of the runs at ``legend`` (a ``loc``;
    none without); whether any run was drawn."""
    ax.set(**labels)
    ax.grid(alpha=0.3)
    if not ax.lines:
        no_data(ax, empty)
        return False
    if legend:
        ax.legend(fontsize=7, loc=legend)
    return True


def step_axis(axis) -> None:
    """Few ticks, labelled 0, 250k, 500k, 1.25M: readable at any number of env steps."""
    from matplotlib.ticker import EngFormatter, MaxNLocator

    axis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
    axis.set_major_formatter(EngFormatter(sep=""))


def wrap_to_width(text: str, width: int) -> str:
    """Word-wraps each line of ``text`` to ``width`` characters: a wrapped line keeps the
    line's indentation plus two spaces, and a word longer than a line is cut."""
    lines = []
    for line in text.split("\n"):
        indent = line[: len(line) - len(line.lstrip(" "))]
        columns = max(width, len(indent) + 3)  # room for a letter after the wrapped indent
        wrapped = textwrap.fill(
            line.lstrip(" "), columns, initial_indent=indent, subsequent_indent=indent + "  "
        )
        lines.append(wrapped or line)
    return "\n".join(lines)


def wrap_to_axes(text, ax) -> None:
    """Wraps ``text`` (in a monospace font, so that every character is as wide as a digit) to
    the width of the (laid out) axes it starts at the left edge of."""
    renderer = ax.figure.canvas.get_renderer()
    digit = renderer.get_text_width_height_descent("0", text.get_fontproperties(), ismath=False)
    columns = int(ax.get_window_extent(renderer).width // digit[0])
    text.set_text(wrap_to_width(text.get_text(), columns))


WALL_TIME_LABEL = "training wall time [s] (compile excluded)"
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
"""Each metric's range on CartPole-v1; confidence bands are clipped to it (a run's returns to
its env's, the entropy to its actions': :func:`metric_bounds`)."""
SUMMARY_FONTSIZES = (8.5, 8.0, 7.5, 7.0, 6.5)
"""The summary panel's font sizes, tried largest first until every run's block fits."""


def metric_bounds(name: str, env_id: str) -> tuple[float, float]:
    """The range of metric ``name`` on ``env_id``: a return within the env's
    (:func:`~jaxcart.core.solved.return_bounds`), the entropy loss within minus the log of
    the env's action count, any other metric within :data:`METRIC_BOUNDS` (or unbounded)."""
    from jaxcart.core.envs import ACTION_COUNTS

    if name == RETURN_METRIC:
        return return_bounds(env_id)
    if name == "train/entropy_loss" and env_id in ACTION_COUNTS:
        return -math.log(ACTION_COUNTS[env_id]), 0.0
    return METRIC_BOUNDS.get(name, (-math.inf, math.inf))


def _plot_metric(ax, x: np.ndarray, run: RunCurves, style: dict, name: str) -> np.ndarray:
    """Draws the mean across seeds of ``run``'s metric and its bootstrap band
    (:func:`stats.curve_band`, clipped to :func:`metric_bounds` on the run's env); returns
    the mean ``[iterations]``."""
    bounds = metric_bounds(name, run.env)
    mean, low, high = stats.curve_band(run.metrics[name], "mean", bounds=bounds)
    band(ax, x, mean, low, high, alpha=0.18, **style)
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
    from jaxcart.results.scores import read_evaluation  # JAX: only once runs are read

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
    styles = run_styles(len(runs))
    _draw_returns(runs, styles, ax_steps, ax_time)
    _draw_metrics(runs, styles, metric_axes, panels)
    _draw_legend(fig, runs, styles)
    num = "one run" if len(runs) == 1 else f"{len(runs)} runs"
    if all(run.num_seeds == 1 for run in runs):
        num += ", 1 seed" if len(runs) == 1 else ", 1 seed per run"
        what = "no confidence band (train several seeds for one)"
    else:
        ci = stats.interval_label([run.num_seeds for run in runs if run.num_seeds > 1], "mean")
        if ci == f"{stats.CONFIDENCE:.0%} CI":
            ci = f"{stats.CONFIDENCE:.0%} bootstrap confidence interval"
        what = f"mean across seeds, shaded {ci} (the axes fit the means; a band may run past them)"
    env_ids = sorted({run.env for run in runs})
    fig.suptitle(f"PPO on {', '.join(env_ids)}, {num}: {what}", fontsize=13)
    fig.draw_without_rendering()  # the layout: the panels' sizes are known from here on
    notes = wall_time_notes(runs)
    if ax_time.lines and notes:  # under the x label, off the data, wrapped to the panel
        caption = "\n".join(f"note: {note}" for note in notes)
        where = ("axes fraction", ax_time.xaxis.label)
        _text_below(ax_time, caption, (0.0, 0.0), where, 4.0, 8.5, "0.3").set_in_layout(True)
        fig.draw_without_rendering()  # again, with room for the caption
    _draw_summary(ax_summary, runs, styles)
    return fig


def _draw_returns(runs: list[RunCurves], styles: list[dict], ax_steps, ax_time) -> None:
    """The return against env steps (with ``--eval-every``'s greedy evaluations as dots)
    and against wall time."""
    from matplotlib.ticker import MaxNLocator

    from jaxcart.rundir.reader import ELAPSED_METRIC

    for run, style in zip(runs, styles):
        if RETURN_METRIC in run.metrics:
            _plot_metric(ax_steps, run.env_steps, run, style, RETURN_METRIC)
            if run.elapsed is not None:
                _plot_metric(ax_time, run.elapsed, run, style, RETURN_METRIC)
        evaluated = run.metrics.get(EVAL_METRIC, np.full((1, 1), np.nan))
        rows = np.isfinite(evaluated).any(axis=1)  # the iterations --eval-every evaluated at
        if rows.any():
            x, mean = run.env_steps[rows], np.nanmean(evaluated[rows], axis=1)
            ax_steps.plot(x, mean, "o", color=style["color"], ms=4, label=EVAL_METRIC)

    evaluated = any(line.get_label() == EVAL_METRIC for line in ax_steps.lines)
    dots = f" (dots: {EVAL_METRIC})" if evaluated else ""
    steps = {"title": f"episode return vs env steps{dots}", "xlabel": "env steps per seed"}
    _finish(ax_steps, f"{RETURN_METRIC} not recorded", **steps)
    wall = {"title": "episode return vs wall time", "xlabel": WALL_TIME_LABEL}
    _finish(ax_time, f"{RETURN_METRIC} or {ELAPSED_METRIC} not recorded", **wall)
    for ax in (ax_steps, ax_time):
        ax.set_ylabel(RETURN_METRIC)
        return_axis(ax, [run.env for run in runs])
    step_axis(ax_steps.xaxis)
    ax_time.xaxis.set_major_locator(MaxNLocator(nbins=6))


def _draw_metrics(
    runs: list[RunCurves], styles: list[dict], axes: list, panels: list[tuple[str, str]]
) -> None:
    """One panel per ``(metric, title)`` against env steps, for every run that records it;
    the y axis fits the means within the metric's range (the bands are clipped to the axes,
    not the axes to them)."""
    for ax, (name, title) in zip(axes, panels):
        means = [
            _plot_metric(ax, run.env_steps, run, style, name)
            for run, style in zip(runs, styles)
            if np.isfinite(run.metrics.get(name, np.nan)).any()
        ]
        lows, highs = zip(*(metric_bounds(name, run.env) for run in runs))
        limits = curve_limits(means, (min(lows), max(highs)))  # every run's range
        labels = {"title": title, "xlabel": "env steps per seed", "ylabel": name}
        _finish(ax, f"{name} not recorded", ylim=limits, **labels)
        step_axis(ax.xaxis)


def _draw_legend(fig, runs: list[RunCurves], styles: list[dict]) -> None:
    """One entry per run below the panels, outside the data, in as many columns as fit."""
    from matplotlib.lines import Line2D

    labels = [
        f"{run.label} ({f'{run.num_seeds} seeds' if run.num_seeds > 1 else '1 seed, no band'})"
        for run in runs
    ]
    handles = [Line2D([], [], **style) for style in styles]
    # About 0.6 em a character at 9 pt, plus the handle and gaps: the columns that fit 14 in.
    columns = int(14 * 72 / (max(map(len, labels)) * 9 * 0.6 + 60))
    look = {"fontsize": 9, "handlelength": 4, "frameon": False}
    ncols = max(1, min(len(labels), columns, 4))
    fig.legend(handles, labels, loc="outside lower center", ncols=ncols, **look)


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


def _text_below(ax, text: str, xy, xycoords, below: float, size: float, colour: str):
    """``text`` in monospace from ``xy`` down, ``below`` points under it, left-aligned and
    wrapped to the laid-out panel (:func:`wrap_to_axes`); left out of the layout."""
    offset = {"xytext": (0.0, -below), "textcoords": "offset points"}
    style = {"family": "monospace", "fontsize": size, "color": colour}
    text = ax.annotate(text, xy, xycoords=xycoords, va="top", ha="left", **offset, **style)
    text.set_in_layout(False)
    wrap_to_axes(text, ax)
    return text


def _draw_summary(ax, runs: list[RunCurves], styles: list[dict]) -> None:
    """Each run's block (:func:`_summary_lines`) in its colour, wrapped to the laid-out
    panel; smaller type for many runs, and at the smallest the runs that still do not fit
    are counted instead."""
    renderer, points = ax.figure.canvas.get_renderer(), 72 / ax.figure.dpi
    height = ax.get_window_extent(renderer).height * points
    blocks = ["\n".join(_summary_lines(run)) for run in runs]
    for size in SUMMARY_FONTSIZES:
        for text in list(ax.texts):  # the larger type's blocks, which overflowed
            text.remove()
        tops, top = [], 0.0
        for block, style in zip(blocks, styles):
            tops.append(top)
            text = _text_below(ax, block, (0.0, 1.0), "axes fraction", top, size, style["color"])
            top += text.get_window_extent(renderer).height * points + size / 2
        if top <= height:
            return
    # Even the smallest type overflows: drop the last runs, and say how many.
    keep = len(blocks) - 1
    while keep > 0 and tops[keep] + 2 * size > height:
        keep -= 1
    for text in list(ax.texts)[keep:]:
        text.remove()
    more = f"... and {len(blocks) - keep} more run(s): see the legend"
    _text_below(ax, more, (0.0, 1.0), "axes fraction", tops[keep], size, "0.3")


PROFILE_POINTS = 101
"""Taus of a performance profile, evenly spaced over the envs' returns."""
CURVE_POINTS = 100
"""Sample-efficiency curves are drawn at most at this many iterations (evenly spaced)."""
CURVE_REPS = 1000
"""Resamples per point of a drawn band (the reported numbers use ``--reps``)."""
MIN_SPAN = 0.1
"""The narrowest score range a panel shows, as a fraction of the envs' range of returns (50
points on CartPole-v1), so that a difference of a few points between runs looks as small as
it is, instead of filling the panel."""
LABEL_SIZE = 10
FRACTION = (-0.02, 1.02)
"""The axis limits of a fraction or a probability."""
ESTIMATE_TITLES = {
    "iqm": "IQM over seeds",
    "median": "median over seeds",
    "mean": "mean over seeds",
    "optimality_gap": "optimality gap: mean of {target} - score",
}


def _tick_label(name: str, width: int = 14) -> str:
    """A run name as a y tick label, wrapped (at hyphens first) so that long names leave the
    panels room: ``4x128-100k-seed271828`` -> ``4x128-100k-\\nseed271828``."""
    return textwrap.fill(name, width, break_on_hyphens=True) or name


Row = tuple[str, str, stats.Estimate]
"""A run's line in an interval panel: its colour, its name and an estimate."""


def _intervals(ax, rows: list[Row], title: str, xlabel: str, xlim: tuple[float, float]) -> None:
    """One point with its interval per ``(colour index, name, estimate)``, top to bottom, each
    written out as ``value [low, high]`` above its bar; the run names are the y labels (the
    panel's legend). The text starts at its point and runs towards the panel's middle, so
    that a value at either end (500, a gap of 0) stays inside the panel instead of spilling
    over the next one and squeezing the constrained layout."""
    n = len(rows)
    ax.set_xlim(*xlim)
    for k, (colour, _, e) in enumerate(rows):
        y = n - 1 - k
        ax.plot([e.ci_low, e.ci_high], [y, y], color=colour, lw=6, alpha=0.45)
        ax.plot([e.value], [y], "|", color=colour, ms=16, mew=2)
        right = e.value > (xlim[0] + xlim[1]) / 2
        text = e.format(1 if abs(e.value) >= 2 else 2)
        offset = {"xytext": (-4 if right else 4, 9), "textcoords": "offset points"}
        ax.annotate(text, (e.value, y), ha="right" if right else "left", fontsize=9, **offset)
    names = [_tick_label(name) for _, name, _ in reversed(rows)]
    ax.set_yticks(range(n), names, fontsize=LABEL_SIZE)
    ax.tick_params(axis="x", labelsize=LABEL_SIZE)
    ax.set(title=title, xlabel=xlabel, ylim=(-0.7, n - 0.3))
    ax.grid(axis="x", alpha=0.3)


def _score_range(comparison: Comparison) -> tuple[float, float]:
    """The least and greatest return of the compared runs' envs: where a score can lie."""
    bounds = [return_bounds(env_id) for env_id in comparison.env_ids]
    return min(low for low, _ in bounds), max(high for _, high in bounds)


def _limits(
    estimates: list[stats.Estimate], lower: float, upper: float, include: float, span: float
) -> tuple[float, float]:
    """An x range holding every interval and ``include``, at least :data:`MIN_SPAN` of
    ``span`` (the envs' range of returns) wide, within ``[lower, upper]`` (where the score
    cannot go), with a margin for the bars' ends."""
    least = MIN_SPAN * span
    low = min([include, *(e.ci_low for e in estimates)])
    high = max([include, *(e.ci_high for e in estimates)])
    grow = max(least - (high - low), 0.0) / 2
    low, high = low - grow, high + grow
    if low < lower:
        low, high = lower, max(high, lower + least)
    if high > upper:
        low, high = min(low, upper - least), upper
    margin = 0.04 * (high - low)
    return low - margin, high + margin


def _styled(comparison: Comparison) -> zip:
    """Each compared run's entry, with its style (:func:`run_styles`)."""
    return zip(comparison.entries, run_styles(len(comparison.entries)))


def _rows(comparison: Comparison, key: str) -> list[Row]:
    """``(colour, name, estimate)`` of each run that has an estimate of ``key``."""
    pairs = zip(_styled(comparison), comparison.runs)
    return [(s["color"], e.name, st[key]) for (e, s), st in pairs if st[key] is not None]


def _against_baseline(ax, comparison: Comparison, key: str) -> None:
    """``difference_iqm`` or ``probability_of_improvement`` of every run but the baseline."""
    rows = _rows(comparison, key)
    base = comparison.entries[comparison.baseline].name
    base = "its baseline arm's run" if comparison.arms else base
    if key == "difference_iqm":
        title, xlabel, zero = f"IQM difference from {base}", "IQM(run) - IQM(baseline)", 0.0
        low, high = _score_range(comparison)
        span = high - low  # a difference of two scores in [low, high]
        xlim = rows and _limits([e for _, _, e in rows], -span, span, 0.0, span)
    else:
        title, xlabel, zero = f"P(run > {base})", "P(X > Y) + 0.5 P(X = Y), seed pairs", 0.5
        xlim = FRACTION
    if not rows:
        _finish(ax, "one run: nothing to compare", title=title)
        return
    _intervals(ax, rows, title, xlabel, xlim)
    ax.axvline(zero, color="0.5", ls="--", lw=0.8, label="no difference")
    ax.legend(fontsize=8, loc="lower right")


def _profile_panel(ax, comparison: Comparison) -> None:
    score = comparison.score.label
    least, most = _score_range(comparison)
    targets = [solved_return(env_id) for env_id in comparison.env_ids]  # each a tau as well
    taus = np.union1d(np.linspace(least, most, PROFILE_POINTS), targets)
    for entry, style in _styled(comparison):
        profile, low, high = stats.performance_profile_band(
            entry.scores, taus, comparison.reps, seed=comparison.seed, at_least=True
        )
        band(ax, taus, profile, low, high, label=entry.name, **style)
        at = np.searchsorted(taus, solved_return(entry.run.env))  # its env's solved return
        ax.plot([taus[at]], [profile[at]], "o", color=style["color"], ms=6)
    title = f"performance profile ({score}); dot: fraction at {comparison.reached}"
    labels = {"xlabel": f"score ({score}) tau", "ylabel": "fraction of seeds scoring >= tau"}
    limits = {"xlim": (least, most + 0.02 * (most - least)), "ylim": FRACTION}
    _finish(ax, "", "lower left", title=title, **labels, **limits)


def _sample_efficiency_panel(ax, comparison: Comparison) -> None:
    for entry, style in _styled(comparison):
        values = entry.run.metrics.get(RETURN_METRIC)
        if values is None or not np.isfinite(values).any():
            continue
        points = np.unique(np.linspace(0, len(values) - 1, CURVE_POINTS).round().astype(int))
        bounds = return_bounds(entry.run.env)
        iqm, low, high = stats.curve_band(
            values[points], "iqm", CURVE_REPS, seed=comparison.seed, bounds=bounds
        )
        x = entry.run.env_steps[points]
        band(ax, x, iqm, low, high, label=entry.name, **style)
    title = "sample efficiency: IQM over seeds of the training return"
    labels = {"title": title, "xlabel": "env steps per seed", "ylabel": RETURN_METRIC}
    _finish(ax, f"{RETURN_METRIC} not recorded", "lower right", **labels)
    return_axis(ax, comparison.env_ids)


def _reached_panel(ax, comparison: Comparison) -> None:
    """Fraction of seeds in which a training episode had scored the env's solved return
    (500 on CartPole-v1), by env steps."""
    reached, reached_any = comparison.reached, False
    for entry, style in _styled(comparison):
        x = entry.run.env_steps
        first = first_reached(entry.run, x)
        if first is None:
            continue
        reached_any |= bool(np.isfinite(first).any())
        x = np.r_[0.0, x[np.isfinite(x)]]
        ax.step(x, stats.fraction_reached(first, x), where="post", label=entry.name, **style)
    title = f"a training episode at {reached} (rollout/ep_rew_max)"
    labels = {"title": title, "xlabel": "env steps per seed", "ylabel": "fraction of seeds"}
    if _finish(ax, "not recorded", "lower right", ylim=FRACTION, **labels) and not reached_any:
        no_data(ax, f"no seed's training reached {reached}")


def _matrix_panel(ax, comparison: Comparison) -> None:
    matrix = comparison.matrix
    ax.set_title("P(row > column) over seed pairs")
    if matrix is None:
        ax.set_axis_off()
        why = "arms: see the table" if comparison.arms else "two runs: see P(run > ...) above"
        return no_data(ax, why)
    names = [_tick_label(e.name) for e in comparison.entries]
    image = ax.imshow(matrix, vmin=0, vmax=1, cmap="RdBu")
    for (r, c), v in np.ndenumerate(matrix):
        colour = "white" if abs(v - 0.5) > 0.3 else "black"  # readable on the dark ends
        ax.text(c, r, f"{v:.2f}", ha="center", va="center", fontsize=7, color=colour)
    ax.set_xticks(range(len(names)), names, rotation=45, ha="right", fontsize=7)
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.figure.colorbar(image, ax=ax, label="P(row > column); 0.5: no difference")


def draw_comparison(comparison: Comparison) -> Figure:
    """The figure described in the module docstring."""
    from matplotlib.figure import Figure

    n = len(comparison.entries)
    fig = Figure(figsize=(18, 13 + 0.25 * n), layout="constrained")
    grid = fig.add_gridspec(3, 12, height_ratios=[0.6 + 0.12 * n, 1, 1])
    score = comparison.score
    location = [st[name] for st in comparison.runs for name in ("iqm", "median", "mean")]
    low, high = _score_range(comparison)
    shared = _limits(location, low, high, location[0].value, high - low)
    for k, (name, title) in enumerate(ESTIMATE_TITLES.items()):
        rows = _rows(comparison, name)
        # One score axis for IQM, median and mean, so that they read alike; the gap
        # (solved return - score) gets its own, as wide as theirs.
        xlim = shared
        if name == "optimality_gap":
            xlim = _limits([e for _, _, e in rows], 0.0, high - low, 0.0, high - low)
        ax = fig.add_subplot(grid[0, 3 * k : 3 * k + 3])
        _intervals(
            ax, rows, title.format(target=comparison.reached), f"score ({score.label})", xlim
        )
    _against_baseline(fig.add_subplot(grid[1, 0:4]), comparison, "difference_iqm")
    _against_baseline(fig.add_subplot(grid[1, 4:8]), comparison, "probability_of_improvement")
    _profile_panel(fig.add_subplot(grid[1, 8:12]), comparison)
    _sample_efficiency_panel(fig.add_subplot(grid[2, 0:4]), comparison)
    _reached_panel(fig.add_subplot(grid[2, 4:8]), comparison)
    _matrix_panel(fig.add_subplot(grid[2, 8:12]), comparison)
    env_ids = sorted(set(comparison.env_ids))
    title = (
        f"{', '.join(env_ids)}, {n} run(s); score = {score.label}: {score.definition(env_ids)}; "
        f"{stats.CONFIDENCE:.0%} percentile bootstrap intervals over seeds"
    )
    if comparison.saturated:
        title += (
            f"\nSATURATED: every seed of every run scores {comparison.entries[0].scores[0]:g}, "
            "so this score cannot tell the runs apart (try --score auc)"
        )
    fig.suptitle("\n".join(textwrap.fill(line, 160) for line in title.splitlines()), fontsize=12)
    return fig


def draw_robustness(
    field: str,
    values: Sequence[float],
    labels: Sequence[str],
    iqms: Sequence[Sequence[stats.Estimate]],
    env_ids: Sequence[str],
    statistic: str,
    episodes: int,
) -> Figure:
    """``robustness.png``: one curve per run (``labels``), the IQM over seeds of each seed's
    mean greedy return at each of ``values`` of the physics ``field`` (``env.length``) with
    its interval (``iqms``, per run and value) as a band; on a log axis when the values are
    positive and span a factor of 4 or more. ``env_ids``: the env each run trained on (the
    return axis is theirs, :func:`return_axis`); ``statistic`` and ``episodes`` go into the
    title."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullLocator

    fig = Figure(figsize=(9, 5.5), layout="constrained")
    ax = fig.add_subplot()
    for style, label, iqm in zip(run_styles(len(labels)), labels, iqms):
        point, low, high = np.array([[e.value, e.ci_low, e.ci_high] for e in iqm]).T
        band(ax, values, point, low, high, marker="o", label=label, **style)
    if min(values) > 0 and max(values) >= 4 * min(values):
        ax.set_xscale("log", base=2)
        ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xticks(values, [f"{v:g}" for v in values])
    xlabel = f"{field} of the physics evaluated on"
    _finish(ax, "", "lower left", xlabel=xlabel, ylabel="greedy return, IQM over seeds")
    return_axis(ax, env_ids)
    title = (
        f"Greedy return in Gymnasium's {env_ids[0]} ({episodes} episodes per seed) against "
        f"{field}: {statistic}; band: that interval"
    )
    ax.set_title(textwrap.fill(title, 95), fontsize=10)
    return fig
