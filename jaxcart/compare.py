"""``python -m jaxcart.compare RUN_DIR [RUN_DIR ...] [--baseline RUN_DIR] [--score S] [--out DIR]``:
is configuration B better than A, and how sure is that?

Statistics of Agarwal et al. (2021), "Deep RL at the Edge of the Statistical Precipice"
(:mod:`jaxcart.analysis.stats`), over any run directories: jaxcart's, a sweep's combinations (a
sweep directory stands for all of them), or ``python -m jaxcart.sb3``'s.
The command reads its options, calls :func:`compare_runs` and prints; the runs are read and
scored in :mod:`jaxcart.results.scores`, the statistics are :mod:`jaxcart.analysis.summary`'s
and the figure :mod:`jaxcart.results.figure`'s.

- ``--score``: the number that stands for a seed: ``eval`` (its mean greedy Gymnasium return,
  the default), ``auc`` (the mean of its ``rollout/ep_rew_mean`` over the run) or
  ``return-at:STEPS`` (its ``rollout/ep_rew_mean`` at STEPS env steps). When every seed of
  every run scores the same (all 500), the output says the score cannot tell them apart.
- Per run: IQM, median over seeds, mean and optimality gap with 95% percentile bootstrap
  intervals; the solve rate with its Wilson interval.
- Against the baseline: the IQM difference and ``P(X > Y)``, each with its interval; with
  more than two runs, the all-pairs ``P(X > Y)`` matrix; the number of comparisons read at
  once (``--adjust bonferroni`` widens the intervals to hold together).
- ``--arm NAME=DIR,DIR`` (repeated): the same arms on several configurations, aggregated with
  rliable's stratified bootstrap.

Writes ``compare.json``, ``compare.png`` and ``curves.csv`` into ``--out`` (default a new
``compare-<time>`` directory beside the first run, e.g. in ``runs/``; never into a run
directory) and prints a table. Bootstrap
resamples come from a fixed seed (``--seed``), so the same runs give the same output.
"""

from __future__ import annotations

import argparse
import os
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxcart import cli

cli.import_jax()  # before results.scores, which imports JAX: JAX reads JAX_* then

from jaxcart.analysis import stats, summary  # noqa: E402
from jaxcart.analysis.summary import Score  # noqa: E402
from jaxcart.core import solved  # noqa: E402
from jaxcart.results import scores as runs  # noqa: E402
from jaxcart.results.scores import CompareError, Comparison  # noqa: E402
from jaxcart.rundir import files, layout  # noqa: E402

ESTIMATE_NAMES = {"iqm": "IQM", "median": "median", "mean": "mean", "optimality_gap": "opt. gap"}
NAME_WIDTH = 24  # longer run names are listed under the table and numbered in it


def _against(st: dict) -> list[str]:
    """The IQM difference and ``P(X > Y)`` cells of a run or an arm (``baseline``: none)."""
    diff, better = st["difference_iqm"], st["probability_of_improvement"]
    return [diff.format(1) if diff else "baseline", better.format(2) if better else "baseline"]


def _row(name: str, entry: runs.Entry, st: dict) -> list:
    """One run's row of :func:`table`."""
    n, solved = len(entry.scores), st["solved"]
    steps = summary.first_reached(entry.run, entry.run.env_steps)
    rate, reached = "n/a", ["n/a", "n/a"]
    if solved is not None:
        rate = f"{entry.solved}/{n} [{solved.ci_low:.1%}, {solved.ci_high:.1%}]"
    if steps is not None:
        median = float(np.median(steps))
        steps_to = f"{median:,.0f}" if np.isfinite(median) else "never"
        reached = [f"{int(np.isfinite(steps).sum())}/{n}", steps_to]
    return [name, n, *(st[k].format(1) for k in ESTIMATE_NAMES), rate, *_against(st), *reached]


def table(comparison: Comparison) -> str:
    """The terminal table: one row per run, split so that it fits 100 columns; names longer
    than :data:`NAME_WIDTH` are numbered in it and listed under it."""
    reference = f"{comparison.arms[0]} same config" if comparison.arms else "baseline"
    reached = comparison.reached
    counts = [len(entry.scores) for entry in comparison.entries]
    ci = f"{100 * comparison.confidence:.3g}% CI"  # wider with --adjust bonferroni
    if stats.interval_label(counts) != f"{stats.CONFIDENCE:.0%} CI":  # too few seeds for one
        ci = stats.interval_label(counts)
    estimates = [
        f"{name} [{stats.interval_label(counts, k)}]" for k, name in ESTIMATE_NAMES.items()
    ]
    header = ["run", "seeds", *estimates, "solved [95% CI]", f"IQM - {reference} [{ci}]"]
    header += [f"P(> {reference}) [{ci}]", f"reached {reached}", f"steps to {reached}"]
    names = [entry.name for entry in comparison.entries]
    numbered = max(map(len, names)) > NAME_WIDTH
    shown = [f"[{i}]" for i in range(len(names))] if numbered else names
    rows = [_row(*row) for row in zip(shown, comparison.entries, comparison.runs)]
    text = cli.format_table(rows, header, width=cli.TABLE_WIDTH)
    if numbered:
        text += "\n" + cli.wrap("runs: " + "; ".join(f"[{i}] {n}" for i, n in enumerate(names)))
    return text


def matrix_text(comparison: Comparison) -> str | None:
    """``P(row > column)`` for every pair of runs, None with two runs or fewer."""
    matrix = comparison.matrix
    if matrix is None:
        return None
    names = [e.name for e in comparison.entries]
    rows = [[name, *(f"{v:.2f}" for v in row)] for name, row in zip(names, matrix)]
    text = cli.format_table(rows, ["", *(f"[{i}]" for i in range(len(names)))], cli.TABLE_WIDTH)
    columns = cli.wrap("columns: " + ", ".join(f"[{i}] {name}" for i, name in enumerate(names)))
    return f"P(row > column) over seed pairs (point values):\n{text}\n{columns}"


def arms_text(comparison: Comparison) -> str | None:
    """The arms aggregated over their configurations, None without ``--arm``."""
    arms, arm_stats = comparison.arms, comparison.arm_stats
    if arms is None or arm_stats is None:
        return None
    k = len(comparison.entries) // len(arms)
    rows = [[name, k, st["iqm"].format(1), *_against(st)] for name, st in zip(arms, arm_stats)]
    ci = f"{100 * comparison.confidence:.3g}% CI"
    header = ["arm", "configs", "IQM [95% CI]", f"IQM - {arms[0]} [{ci}]", f"P(>) [{ci}]"]
    return (
        f"Arms over {k} configuration(s) (stratified bootstrap: seeds resampled within each "
        "configuration; P(>) is the mean over configurations):\n"
        + cli.format_table(rows, header, cli.TABLE_WIDTH)
    )


def saturation_text(comparison: Comparison) -> str:
    """One line: whether the score can tell the runs apart at all."""
    if not comparison.saturated:
        return "saturated: no (the scores differ between seeds or runs)"
    value = comparison.entries[0].scores[0]
    hint = "compare with --score auc (or return-at:STEPS)"
    if comparison.score.name != "eval":
        hint = "try another --score"
    return (
        f"saturated: every seed of every run scores {value:g} by {comparison.score.label}: "
        f"the score cannot tell the runs apart; {hint}"
    )


def solved_text(comparison: Comparison) -> str:
    """What solved, opt. gap and reached mean for the compared runs' envs: each env's rule
    and its solved return (:data:`jaxcart.core.solved.SOLVED_BY`), which the opt. gap and
    reached measure against."""
    env_ids = set(comparison.env_ids)  # the envs judged by their mean first:
    env_ids = sorted(env_ids, key=lambda env_id: (solved.SOLVED_BY[env_id][0] != "mean", env_id))
    reached = solved.reached_label(env_ids)
    after = (
        f"reached {reached}: {runs.reached_definition(env_ids)}; steps to {reached}: the "
        "median over seeds of the env steps when that first happened (never: not in half the "
        "seeds)"
    )
    rule, threshold = solved.SOLVED_BY[env_ids[0]]
    if len(env_ids) == 1 and rule == "every":
        return f"solved: every greedy episode scored {threshold:g} (Wilson interval); {after}"
    rules = ", ".join(
        f"{env_id} >= {t:g}" if rule == "mean" else f"{env_id}: every episode {t:g}"
        for env_id, (rule, t) in zip(env_ids, map(solved.SOLVED_BY.get, env_ids))
    )
    return (
        f"solved: the mean greedy return reaches the env's reward_threshold ({rules}) (Wilson "
        f"interval); opt. gap: the mean over seeds of how far the score falls short of that "
        f"return; {after}"
    )


def report_text(comparison: Comparison) -> str:
    """Heading, table, matrix, arms and notes, as printed."""
    reps, seed, score = comparison.reps, comparison.seed, comparison.score
    definition = score.definition(comparison.env_ids)
    baseline = comparison.entries[comparison.baseline].name
    if comparison.arms:
        baseline = f"arm {comparison.arms[0]} (each run against its configuration's run)"
    heading = (
        f"Comparing {len(comparison.entries)} run(s); score = {score.label}: "
        f"{definition}; {stats.CONFIDENCE:.0%} percentile bootstrap CIs ({reps} "
        f"resamples, seed {seed}); baseline {baseline}"
    )
    texts = [solved_text(comparison), saturation_text(comparison), comparison.reading_note()]
    lines = [cli.wrap(heading), table(comparison), *map(cli.wrap, texts)]
    lines += [text for text in (matrix_text(comparison), arms_text(comparison)) if text]
    lines += [cli.wrap(f"note: {note}") for note in runs.comparison_notes(comparison.entries)]
    return "\n".join(lines)


@dataclass(frozen=True)
class CompareResult:
    comparison: Comparison
    json_path: Path
    figure_path: Path
    curves_path: Path


def compare_runs(
    run_dirs: Sequence[str | os.PathLike] = (),
    baseline: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    reps: int = stats.DEFAULT_REPS,
    seed: int = stats.DEFAULT_SEED,
    dpi: int = 100,
    score: Score | str = "eval",
    adjust: str = "none",
    arms: Sequence[tuple[str, Sequence[str | os.PathLike]]] | None = None,
    policy: str = "final",
) -> CompareResult:
    """Compares run directories; writes ``compare.json``, ``compare.png`` and ``curves.csv``.

    Args:
        run_dirs: run or sweep directories (a sweep stands for its combinations).
        baseline: the run the others are compared with (default the first); with ``arms``,
            the name of the baseline arm.
        out: output directory (default a new ``compare-<time>`` beside the first run
            directory, e.g. in ``runs/``).
        reps, seed: bootstrap resamples and their random seed.
        score: ``"eval"``, ``"auc"``, ``"return-at:STEPS"`` or a :class:`Score`.
        adjust: ``"none"`` or ``"bonferroni"``.
        arms: ``[(name, [run_dir per configuration]), ...]`` instead of ``run_dirs``.
        policy: whose Gymnasium evaluation scores ``eval`` and counts solved seeds: the
            ``final`` policies, or the ``best`` ones runs kept (``--keep-best``).

    Raises:
        RunDirError: an unusable run directory; CompareError: a comparison that cannot be made.
    """
    if isinstance(score, str):
        try:
            score = Score.parse(score, cli.score_steps)
        except ValueError as exc:
            raise CompareError(f"score {score!r}: {exc}") from None
    entries, index, arm_names = runs.load_entries(run_dirs, baseline, score, policy, arms)
    out = runs.prepare_out(None if out is None else Path(out), entries)
    comparison = runs.build_comparison(entries, index, score, reps, seed, adjust, arm_names)
    from jaxcart.results import figure  # matplotlib: only when drawn

    names = (layout.COMPARE_FILE, layout.COMPARE_FIGURE_FILE, layout.COMPARE_CURVES_FILE)
    paths = [out / name for name in names]  # compare.json last: written once the rest is
    figure.save(figure.draw_comparison(comparison), paths[1], dpi)
    files.atomic_write_bytes(paths[2], runs.curves_csv(comparison.entries))
    files.write_json(paths[0], comparison.to_dict())
    return CompareResult(comparison, *paths)


@dataclass(frozen=True)
class CompareOptions:
    """The command's options, each declared once (:func:`jaxcart.cli.option`): its type and
    default here, its help the docstring below it; :func:`compare_runs` takes them by name."""

    score: Score = cli.option(summary.EVAL, type=cli.score, metavar="SCORE")
    """each seed's score: eval (mean greedy Gymnasium return), auc (mean of
    rollout/ep_rew_mean over the run) or return-at:STEPS (rollout/ep_rew_mean at STEPS env
    steps, e.g. return-at:1e5) (default: eval)"""
    policy: str = cli.option("final", choices=list(layout.POLICY_FILES))
    """whose Gymnasium evaluation --score eval and the solved counts read: the final policies,
    or the best ones each run kept (--eval-every N --keep-best)"""
    baseline: str | None = cli.option(metavar="RUN_DIR")
    """the run the others are compared with, or with --arm the baseline arm's NAME (default:
    the first RUN_DIR, or the first arm)"""
    arm: tuple[str, ...] = cli.option((), action="append", metavar="NAME=DIR,DIR")
    """an arm's runs on several configurations, in the same order for every arm (repeat for
    each arm, instead of RUN_DIRs): e.g. --arm bootstrap=runs/sb3,runs/pjx --arm
    no-bootstrap=runs/sb3-nb,runs/pjx-nb aggregates the two arms over both settings with a
    stratified bootstrap"""
    adjust: str = cli.option("none", choices=summary.ADJUSTMENTS)
    """bonferroni: widen each difference and P(X > Y) interval so that all of them hold
    together at 95%"""
    out: Path | None = cli.option(type=cli.out_dir, metavar="DIR")
    """directory for compare.json, compare.png and curves.csv (default: a new compare-<time>
    beside the first RUN_DIR, e.g. runs/compare-<time>)"""
    reps: int = cli.option(stats.DEFAULT_REPS, type=cli.bounded_count(cli.MAX_REPS, 100))
    """bootstrap resamples, 100 to 100,000 (default 2000)"""
    seed: int = cli.option(stats.DEFAULT_SEED, type=cli.seed)
    """bootstrap seed"""
    dpi: int = cli.option(100, type=cli.bounded_count(cli.MAX_DPI))
    """PNG resolution"""


class _Formatter(cli.HelpFormatter):
    """Keeps the epilog's lines (one definition each), wrapping each on its own."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n".join(
            textwrap.fill(line, width, initial_indent=indent, subsequent_indent=indent + "    ")
            for line in text.splitlines()
        )


def build_parser() -> argparse.ArgumentParser:
    """The CLI."""
    epilog = "definitions:\n" + "\n".join(f"{k}: {v}" for k, v in summary.DEFINITIONS.items())
    parser = cli.Parser(
        prog="python -m jaxcart.compare",
        formatter_class=_Formatter,
        description="Compare runs over their seeds with the statistics of Agarwal et al. "
        "(2021): IQM, median over seeds, mean and optimality gap of a per-seed score with "
        "95% percentile bootstrap intervals, the solve rate with its Wilson interval, the IQM "
        "difference and the probability of improvement over a baseline, performance profiles "
        "and sample-efficiency curves. A sweep directory stands for its combinations. "
        "Example: python -m jaxcart.compare runs/a runs/b --score auc --out cmp",
        epilog=epilog,
    )
    parser.add_argument("run_dirs", nargs="*", type=Path, metavar="RUN_DIR")
    cli.add_options(parser, CompareOptions, "")
    return parser


@cli.command(CompareError)
def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)
    options = vars(args)  # compare_runs's parameters, by name
    options["arms"] = [runs.parse_arm(text) for text in options.pop("arm")]
    result = compare_runs(**options)
    print(report_text(result.comparison))
    paths = (result.json_path, result.figure_path, result.curves_path)
    print(f"wrote {', '.join(map(str, paths))}", flush=True)
    return 0


if __name__ == "__main__":
    cli.command_main(main)
