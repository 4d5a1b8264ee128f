"""``python -m jaxcart.plot RUN_DIR [RUN_DIR ...]``: learning curves of jaxcart runs as a PNG.

Panels: episode return (``rollout/ep_rew_mean``) against env steps per seed and against wall
time (``time/elapsed``, seconds of training with compilation excluded), then one panel per key
PPO metric (``train/approx_kl``, ``train/clip_fraction``, ``train/entropy_loss``,
``train/value_loss``, ``train/explained_variance``) against env steps, and a summary of each
run's Gymnasium evaluation; below them, one panel per metric of the run's own
(``PPOConfig.metrics``).

Each curve is the mean across seeds; the shaded band is a 95% percentile bootstrap confidence
interval of that mean (:func:`jaxcart.analysis.stats.curve_band`: whole seeds resampled, a
fixed seed so the figure is deterministic), clipped to the metric's range
(:func:`jaxcart.results.figure.metric_bounds`: returns within the env's, e.g. [0, 500] on
CartPole-v1, clip fraction in [0, 1], KL and value loss >= 0, explained variance <= 1, ...).
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

The figure is :func:`jaxcart.results.figure.draw_figure`'s, in matplotlib's object API (no
pyplot), so it never changes the caller's backend.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from jaxcart import cli
from jaxcart.results import figure as figures
from jaxcart.results.figure import draw_figure
from jaxcart.rundir import layout

if TYPE_CHECKING:  # matplotlib is imported when a figure is drawn, JAX when runs are read
    from matplotlib.figure import Figure

    from jaxcart.rundir.reader import RunCurves

FORMATS = ("png", "svg", "pdf")
COMPARISON = layout.PLOT_COMPARISON_FILE
"""Where several runs are drawn by default (or comparison-2.png, ... if it exists)."""


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
        ValueError: bad ``labels``/``out``, or an evaluation's directory.
    """

    runs = _load_runs(run_dirs, labels)
    out = None if out is None else _checked(Path(out))
    fig = draw_figure(runs)
    if out is not None:
        figures.save(fig, out, dpi)
    return fig


def _load_runs(
    run_dirs: Sequence[str | os.PathLike], labels: Sequence[str] | None
) -> list[RunCurves]:
    """:func:`jaxcart.rundir.reader.load_runs`, with one label per run directory or none.

    Raises:
        ValueError: no run directory, another number of labels, or an evaluation's directory
            (no learning curves).
    """
    if not run_dirs:
        raise ValueError("give at least one run directory")
    if labels is not None and len(labels) != len(run_dirs):
        raise ValueError(
            f"got {len(labels)} label(s) (--label) for {len(run_dirs)} run directories; "
            "give one per run directory or none"
        )
    from jaxcart.rundir.reader import load_runs

    runs = load_runs([Path(p) for p in run_dirs], labels)
    for run in runs:
        if not run.metrics:
            raise ValueError(
                f"{run.path} is an evaluation (python -m jaxcart.evaluate --out): no learning "
                "curves to plot; python -m jaxcart.compare reads it"
            )
    return runs


def default_out(runs: list[RunCurves]) -> Path:
    """Where a plot goes without ``--out``: one run directory's own ``RUN_DIR/curves.png``
    (redrawn in place; a sweep directory is one, :func:`~jaxcart.results.scores.named_dir`),
    otherwise the first of ``comparison.png``, ``comparison-2.png``, ... in the current
    directory that does not exist yet, so that an earlier comparison is never overwritten."""
    from jaxcart.results.scores import named_dir

    run_dirs = list(dict.fromkeys(named_dir(run) for run in runs))
    if len(run_dirs) == 1:
        return run_dirs[0] / layout.CURVES_FILE
    out, number = Path(COMPARISON), 2
    while out.exists():
        out, number = Path(f"{Path(COMPARISON).stem}-{number}.png"), number + 1
    return out


def _checked(out: Path) -> Path:
    """``out``, refused (ValueError) unless it is a .png, .svg or .pdf in a directory."""
    if out.suffix.lower().lstrip(".") not in FORMATS:
        raise ValueError(f"output {out} must end in one of .{', .'.join(FORMATS)}")
    if not out.parent.is_dir():
        raise ValueError(f"cannot write {out}: directory {out.parent} does not exist")
    return out


@dataclasses.dataclass(frozen=True)
class PlotOptions:
    """The command's options, each declared once (:func:`jaxcart.cli.option`): its type and
    default here, its help the docstring below it."""

    out: Path | None = cli.option(type=Path)
    """image to write (.png, .svg, .pdf), replaced if it exists; default RUN_DIR/curves.png for
    one run or sweep directory (redrawn in place), and for several comparison.png in the
    current directory, or comparison-2.png, comparison-3.png, ... if that exists: an earlier
    comparison is never overwritten"""
    label: tuple[str, ...] | None = cli.option(action="append")
    """legend label; repeat once per RUN_DIR, in order (default: directory names, and a sweep
    combination's hyperparameter values, which a sweep's label prefixes)"""
    dpi: int = cli.option(100, type=cli.bounded_count(cli.MAX_DPI))
    """PNG resolution, at most 1000 (15x11 in figure)"""


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
    cli.add_options(parser, PlotOptions, "")
    return parser


@cli.command(ValueError)
def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)
    runs = _load_runs(args.run_dirs, args.label or None)  # no --label: the default names
    out = _checked(default_out(runs) if args.out is None else args.out)
    figures.save(draw_figure(runs), out, args.dpi)  # an OSError: cli.command's one line
    notes = unfinished_notes(runs)
    if args.out is None and out.parent == Path() and out.name != COMPARISON:
        notes.append(f"{COMPARISON} exists and is kept: drew into {out} (--out FILE to choose)")
    for line in notes:
        print(f"note: {line}", file=sys.stderr)
    print(out.absolute())  # the full path: several runs' figure goes to the current folder
    return 0


def unfinished_notes(runs: list[RunCurves]) -> list[str]:
    """One line per unfinished run or sweep: what was drawn, and what is missing."""
    lines = []
    for path in dict.fromkeys(run.path for run in runs if run.note):
        mine = [run for run in runs if run.path == path]
        what = "curves drawn"
        if mine[0].combination:
            what = f"a sweep: its {len(mine)} combinations drawn"
        lines.append(
            f"{path}: {what} {mine[0].note}; no Gymnasium evaluation until it finishes "
            f"(python -m jaxcart.train --resume {path})"
        )
    return lines


if __name__ == "__main__":
    cli.command_main(main)
