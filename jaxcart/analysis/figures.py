"""Figure helpers for the plot commands (matplotlib's object API; no run directories).

- :func:`run_styles`: a colour from Okabe and Ito's colour-blind-safe palette and a line style
  for each overlaid run, both changing from one run to the next;
- :func:`curve_limits`: y-axis limits that fit the mean curves, not their confidence bands;
- :func:`step_axis`: few ticks labelled ``250k``, ``1.25M``;
- :func:`wrap_to_width` and :func:`wrap_to_axes`: text wrapped to the width of a laid-out
  panel, measured in the font it is drawn in;
- :func:`band`: a curve with its confidence band; :func:`no_data`: a panel's "not recorded".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

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


@dataclass(frozen=True)
class Style:
    """How one run is drawn: its colour and line style in every panel and the legend."""

    color: str
    linestyle: str | tuple
    width: float
    zorder: float  # later runs on top: dashed or dotted over solid, so equal curves both show

    def line(self) -> dict:
        """Keyword arguments of ``Axes.plot``."""
        return {"color": self.color, "ls": self.linestyle, "lw": self.width, "zorder": self.zorder}


def run_styles(count: int) -> list[Style]:
    """Colour and line style of each of ``count`` runs: both change from one run to the next."""
    return [
        Style(PALETTE[i % len(PALETTE)], *LINE_STYLES[i % len(LINE_STYLES)], 2.0 + i / 1000)
        for i in range(count)
    ]


def curve_limits(
    curves: Sequence[np.ndarray],
    bounds: tuple[float, float] = (-math.inf, math.inf),
    margin: float = Y_MARGIN,
) -> tuple[float, float] | None:
    """Axis limits that fit the mean curves (not their bands) with a margin, kept inside the
    metric's range unless a curve reaches its edge (then the margin keeps the line visible).

    Args:
        curves: each ``[iterations]``, NaN where there is no value.
        bounds: the metric's range (``jaxcart.plot.METRIC_BOUNDS``).
        margin: room on each side, as a fraction of the curves' range.

    Returns:
        ``(low, high)`` with ``low < high``, or None if no curve has a finite value.
    """
    finite = [c[np.isfinite(c)] for c in curves]
    values = np.concatenate(finite) if finite else np.empty(0)
    if values.size == 0:
        return None
    lo, hi = float(values.min()), float(values.max())
    # A flat curve gets a margin from its size (or an absolute one at zero).
    pad = (hi - lo) * margin if hi > lo else max(abs(hi) * margin, 1e-3)
    low = lo - pad if lo <= bounds[0] else max(lo - pad, bounds[0])
    high = hi + pad if hi >= bounds[1] else min(hi + pad, bounds[1])
    return low, high


def band(ax, x, point, low, high, color: str, alpha: float = 0.2, **line) -> None:
    """A curve ``point`` and, where it has finite values, its band ``[low, high]`` (each
    ``[len(x)]``) in ``color``; ``line``: ``Axes.plot``'s keywords (``lw``, ``label``)."""
    ax.plot(x, point, color=color, **line)
    if np.isfinite(low).any():
        ax.fill_between(x, low, high, color=color, alpha=alpha, lw=0)


def no_data(ax, text: str) -> None:
    """``text`` in grey in the middle of an empty panel."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def step_axis(axis) -> None:
    """Few ticks, labelled 0, 250k, 500k, 1.25M: readable at any number of env steps."""
    from matplotlib.ticker import EngFormatter, MaxNLocator

    axis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
    axis.set_major_formatter(EngFormatter(sep=""))


def wrap_to_width(text: str, width: float, measure: Callable[[str], float]) -> str:
    """Word-wraps each line of ``text`` so that ``measure(line) <= width``: a wrapped line
    keeps the line's indentation plus two spaces, and a word wider than a line is cut.

    Args:
        text: lines separated by ``\\n``.
        width: the widest line allowed, in ``measure``'s unit.
        measure: the width of a string (points of a font, or ``len`` for characters).
    """
    out = []
    for line in text.split("\n"):
        prefix = line[: len(line) - len(line.lstrip(" "))]
        more = prefix + "  "
        current = ""
        for word in line.split():
            trial = f"{current} {word}" if current else word
            if current and measure(prefix + trial) > width:
                out.append(prefix + current)
                prefix, trial = more, word
            while len(trial) > 1 and measure(prefix + trial) > width:
                cut = len(trial) - 1
                while cut > 1 and measure(prefix + trial[:cut]) > width:
                    cut -= 1
                out.append(prefix + trial[:cut])
                prefix, trial = more, trial[cut:]
            current = trial
        out.append(prefix + current)
    return "\n".join(out)


def text_measure(text, renderer) -> Callable[[str], float]:
    """The width in points of a string in ``text``'s font."""
    prop = text.get_fontproperties()
    return lambda s: (
        renderer.get_text_width_height_descent(s, prop, ismath=False)[0] * (72 / renderer.dpi)
    )


def wrap_to_axes(text, ax) -> None:
    """Wraps ``text`` to the width of the (laid out) axes it starts at the left edge of."""
    renderer = ax.figure.canvas.get_renderer()
    width = ax.get_window_extent(renderer).width * 72 / ax.figure.dpi
    text.set_text(wrap_to_width(text.get_text(), width, text_measure(text, renderer)))
