"""``python -m jaxcart.compare RUN_DIR [RUN_DIR ...] [--baseline RUN_DIR] [--out DIR]``: is
configuration B better than A, and how sure is that?

Statistics of Agarwal et al. (2021), "Deep RL at the Edge of the Statistical Precipice"
(:mod:`jaxcart.analysis.stats`), over any run directories: jaxcart's, a sweep's combinations (a sweep
directory stands for all of them, each named by its hyperparameter values, e.g.
``learning_rate=0.001,clip_coef=0.2``), or ``benchmarks/sb3_reference_run.py``'s.

- A seed's **score** is its mean greedy Gymnasium return (``evaluation.json``).
- Per run, across seeds: mean, median, IQM (25% trimmed mean) and optimality gap (mean of
  ``max(500 - score, 0)``), each with a 95% percentile bootstrap confidence interval.
- Against the baseline (``--baseline``, default the first run): the probability of
  improvement ``P(X > Y) + 0.5 P(X = Y)`` over all seed pairs, with its interval.
- Performance profile: the fraction of seeds scoring above tau, tau in [0, 500].
- Sample efficiency: IQM across seeds of ``rollout/ep_rew_mean`` (the mean return of the last
  100 training episodes) against env steps; and when each seed's training first reached 500
  (the first iteration in which a training episode scored 500, ``rollout/ep_rew_max``, as in
  the sweep table), in env steps and in wall time, as the fraction of seeds there by then.
  ``ep_rew_mean`` itself rarely reaches 500 within a short run (its 100-episode window still
  holds earlier episodes); Stable-Baselines3's log has no ``ep_rew_max``, so its runs are left
  out of the steps-to-500 panels (a note says so) rather than held to another definition.

Writes ``compare.json`` and ``compare.png`` into ``--out`` (default a new ``compare-<time>``
directory here; never into a run directory) and prints a table. Bootstrap resamples come
from a fixed seed (``--seed``), so the same runs give the same output.
"""

from __future__ import annotations

import argparse
import io
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jaxcart import cli, plot
from jaxcart.analysis import stats
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.runs import RunCurves, load_runs

if TYPE_CHECKING:  # matplotlib is imported when the figure is drawn
    from matplotlib.figure import Figure

SCORE_DEFINITION = (
    "each seed's mean greedy return in gymnasium.make('CartPole-v1') (evaluation.json)"
)
REACHED_METRIC = "rollout/ep_rew_max"
REACHED_DEFINITION = "first iteration in which a training episode scored 500 (rollout/ep_rew_max)"
TAUS = np.linspace(0.0, stats.MAX_RETURN, 101)
CURVE_POINTS = 100
"""Sample-efficiency curves are drawn at most at this many iterations (evenly spaced)."""
CURVE_REPS = 1000
"""Resamples per point of a drawn band (the reported numbers use ``--reps``)."""
ESTIMATE_NAMES = {"iqm": "IQM", "mean": "mean", "median": "median", "optimality_gap": "opt. gap"}


@dataclass(frozen=True)
class Entry:
    """One compared run: its curves (:class:`jaxcart.rundir.runs.RunCurves`) and per-seed scores."""

    run: RunCurves
    scores: np.ndarray  # [num_seeds]
    solved: int  # seeds solved by evaluate's definition (every greedy episode scored 500)
    episodes: int | None  # greedy episodes per seed

    @property
    def name(self) -> str:
        return self.run.label

    @property
    def train_return(self) -> np.ndarray | None:
        """``rollout/ep_rew_mean`` ``[iterations, num_seeds]``, None if not recorded."""
        return self.run.metrics.get(plot.RETURN_METRIC)

    def first_reached(self, x: np.ndarray | None) -> np.ndarray | None:
        """``x`` (env steps or seconds, ``[iterations]``) where a training episode of each
        seed first scored 500, ``[num_seeds]`` (``inf``: never); None without the data."""
        best = self.run.metrics.get(REACHED_METRIC)
        if x is None or best is None or not np.isfinite(best).any():
            return None
        return stats.first_at_least(best, x, stats.MAX_RETURN)


def read_scores(run: RunCurves) -> tuple[np.ndarray, int, int | None]:
    """``(scores [num_seeds], solved seeds, episodes)`` from a run's ``evaluation.json``.

    Raises:
        RunDirError: missing, unreadable or without per-seed Gymnasium means.
    """
    path = run.path / layout.EVALUATION_FILE
    if not os.path.lexists(path):
        raise RunDirError(
            f"{run.path} has no {layout.EVALUATION_FILE}: compare needs each seed's greedy "
            "evaluation, which training writes when it finishes"
        )
    try:
        seeds = reader.read_evaluation(run.path, run.num_seeds)["seeds"]
        scores = np.array([float(s["gymnasium_mean"]) for s in seeds])
        solved = sum(bool(s.get("solved")) for s in seeds)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        detail = f"no {exc} entry" if isinstance(exc, KeyError) else str(exc)
        raise RunDirError(f"{path} is corrupted: {detail}") from None
    if scores.size == 0 or not np.isfinite(scores).all():
        raise RunDirError(f"{path} holds no finite per-seed gymnasium_mean")
    episodes = (run.evaluation or {}).get("episodes")
    return scores, solved, int(episodes) if isinstance(episodes, int) else None


def load_entries(
    run_dirs: Sequence[str | os.PathLike], baseline: str | os.PathLike | None = None
) -> tuple[list[Entry], int]:
    """The runs to compare (sweeps expanded) and the baseline's index among them.

    The baseline is the first run unless ``baseline`` names one (a run directory that is not
    among ``run_dirs`` is added in front).

    Raises:
        RunDirError: an unusable run directory; cli.UsageError: a run given twice, or a
            sweep as the baseline.
    """
    runs = load_runs(run_dirs)
    index = 0
    if baseline is not None:
        if layout.is_sweep(baseline):
            raise cli.UsageError(
                f"--baseline {baseline} is a sweep; name one of its combinations, "
                f"e.g. {layout.combo_dir(baseline, 0)}"
            )
        resolved = [r.path.resolve() for r in runs]
        if Path(baseline).resolve() in resolved:
            index = resolved.index(Path(baseline).resolve())
        else:
            runs = load_runs([baseline, *run_dirs])
    seen: set[Path] = set()
    for run in runs:
        if run.path.resolve() in seen:
            raise cli.UsageError(f"{run.path} is given twice")
        seen.add(run.path.resolve())
    return [Entry(run, *read_scores(run)) for run in runs], index


@dataclass
class RunSummary:
    """One run's estimates (``compare.json``'s ``runs`` entries)."""

    entry: Entry
    estimates: dict[str, stats.Estimate]  # ESTIMATE_NAMES -> estimate
    improvement: stats.Estimate | None  # P(this run > baseline); None for the baseline
    steps_to_500: np.ndarray | None  # [num_seeds] env steps, inf never
    seconds_to_500: np.ndarray | None  # [num_seeds] training wall time, inf never

    def to_dict(self) -> dict:
        def seeds(x: np.ndarray | None) -> list | None:
            return None if x is None else [float(v) if np.isfinite(v) else None for v in x]

        entry = self.entry
        return {
            "name": entry.name,
            "path": str(entry.run.path),
            "num_seeds": len(entry.scores),
            "scores": entry.scores.tolist(),
            **{name: self.estimates[name].to_dict() for name in stats.ESTIMATORS},
            "probability_of_improvement": self.improvement and self.improvement.to_dict(),
            "solved_seeds": entry.solved,
            "evaluation_episodes": entry.episodes,
            "steps_to_500": seeds(self.steps_to_500),
            "seconds_to_500": seeds(self.seconds_to_500),
        }


@dataclass
class Comparison:
    """Every run's summary, the baseline and what the reader should know."""

    runs: list[RunSummary]
    baseline: int
    reps: int
    seed: int
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "baseline": self.runs[self.baseline].entry.name,
            "score": SCORE_DEFINITION,
            "reached_500": REACHED_DEFINITION,
            "confidence": stats.CONFIDENCE,
            "bootstrap": {"method": "percentile", "reps": self.reps, "seed": self.seed},
            "notes": self.notes,
            "runs": [r.to_dict() for r in self.runs],
        }


def build_comparison(
    entries: list[Entry],
    baseline: int = 0,
    reps: int = stats.DEFAULT_REPS,
    seed: int = stats.DEFAULT_SEED,
) -> Comparison:
    """Estimates with bootstrap intervals for every run, and each run against ``baseline``."""
    base = entries[baseline].scores
    runs = []
    for i, entry in enumerate(entries):
        improvement = None
        if i != baseline:
            improvement = stats.probability_of_improvement_ci(entry.scores, base, reps, seed=seed)
        runs.append(
            RunSummary(
                entry,
                stats.bootstrap_cis(entry.scores, stats.ESTIMATORS, reps, seed=seed),
                improvement,
                entry.first_reached(entry.run.env_steps),
                entry.first_reached(entry.run.elapsed),
            )
        )
    return Comparison(runs, baseline, reps, seed, comparison_notes(entries))


def comparison_notes(entries: list[Entry]) -> list[str]:
    """What the numbers do not say by themselves: unequal or single seeds, and the rest."""
    notes = []
    counts = {e.name: len(e.scores) for e in entries}
    groups: dict[int, list[str]] = {}
    for name, count in counts.items():
        groups.setdefault(count, []).append(name)
    if len(groups) > 1:
        listed = "; ".join(
            f"{count} for {names[0] if len(names) == 1 else f'{len(names)} runs'}"
            for count, names in sorted(groups.items(), reverse=True)
        )
        notes.append(
            f"seed counts differ ({listed}): each run's estimates use its own seeds, and fewer "
            "seeds give wider intervals"
        )
    for name, count in counts.items():
        if count == 1:
            notes.append(
                f"{name} has a single seed: its confidence intervals are degenerate (one value) "
                "and say nothing about seed-to-seed variation; train more seeds (--num-seeds)"
            )
    episodes = sorted({e.episodes for e in entries if e.episodes is not None})
    if len(episodes) > 1:
        notes.append(
            f"greedy evaluation episodes per seed differ ({', '.join(map(str, episodes))}); "
            "scores from fewer episodes are noisier"
        )
    if len(entries) == 1:
        notes.append("one run only: nothing to compare it with (no probability of improvement)")
    for e in entries:
        if e.train_return is None or not np.isfinite(e.train_return).any():
            notes.append(f"{e.name} has no {plot.RETURN_METRIC}: no sample-efficiency curve")
        if e.first_reached(e.run.env_steps) is None:
            notes.append(
                f"{e.name} did not record {REACHED_METRIC} (Stable-Baselines3 logs none): "
                "left out of steps to 500"
            )
    notes += [f"wall time: {n}" for n in plot.wall_time_notes([e.run for e in entries])]
    return notes


def _median_steps(steps: np.ndarray | None) -> str:
    if steps is None:
        return "n/a"
    median = float(np.median(steps))
    return f"{median:,.0f}" if np.isfinite(median) else "never"


def table(comparison: Comparison) -> str:
    """The terminal table: one row per run."""
    header = [
        "run",
        "seeds",
        *(f"{label} [95% CI]" for label in ESTIMATE_NAMES.values()),
        "P(> baseline) [95% CI]",
        "eval solved",
        "reached 500",
        "median steps to a 500 episode",
    ]
    rows = []
    for summary in comparison.runs:
        entry, n = summary.entry, len(summary.entry.scores)
        reached = "n/a"
        if summary.steps_to_500 is not None:
            reached = f"{int(np.isfinite(summary.steps_to_500).sum())}/{n}"
        rows.append(
            [
                entry.name,
                n,
                *(summary.estimates[name].format(1) for name in ESTIMATE_NAMES),
                summary.improvement.format(2) if summary.improvement else "baseline",
                f"{entry.solved}/{n}",
                reached,
                _median_steps(summary.steps_to_500),
            ]
        )
    return cli.format_table(rows, header)


def report_text(comparison: Comparison) -> str:
    """Heading, table and notes, as printed."""
    reps, seed = comparison.reps, comparison.seed
    lines = [
        f"Comparing {len(comparison.runs)} run(s); score = {SCORE_DEFINITION}; "
        f"{stats.CONFIDENCE:.0%} percentile bootstrap CIs ({reps} resamples, seed {seed}); "
        f"baseline {comparison.runs[comparison.baseline].entry.name}",
        table(comparison),
        f"eval solved: every greedy episode scored 500; reached 500: {REACHED_DEFINITION}",
    ]
    lines += [f"note: {note}" for note in comparison.notes]
    return "\n".join(lines)


def _interval_panel(ax, comparison: Comparison, name: str, title: str) -> None:
    """One estimate of every run as a point with its interval, runs top to bottom."""
    n = len(comparison.runs)
    for i, summary in enumerate(comparison.runs):
        e = summary.estimates[name]
        y = n - 1 - i
        ax.plot([e.ci_low, e.ci_high], [y, y], color=f"C{i % 10}", lw=6, alpha=0.45)
        ax.plot([e.value], [y], "|", color=f"C{i % 10}", ms=16, mew=2)
    ax.set(title=title, ylim=(-0.7, n - 0.3))
    ax.set_yticks([])
    ax.grid(axis="x", alpha=0.3)


def _improvement_panel(ax, comparison: Comparison) -> None:
    others = [(i, s) for i, s in enumerate(comparison.runs) if s.improvement is not None]
    base = comparison.runs[comparison.baseline].entry.name
    ax.set(title=f"probability of improvement over {base}", xlim=(-0.02, 1.02))
    if not others:
        _no_data(ax, "one run: nothing to compare")
        return
    for k, (i, summary) in enumerate(others):
        e, y = summary.improvement, len(others) - 1 - k
        ax.plot([e.ci_low, e.ci_high], [y, y], color=f"C{i % 10}", lw=6, alpha=0.45)
        ax.plot([e.value], [y], "|", color=f"C{i % 10}", ms=16, mew=2)
    ax.axvline(0.5, color="0.5", ls="--", lw=0.8)
    ax.set_yticks(range(len(others)), [s.entry.name for _, s in reversed(others)], fontsize=8)
    ax.set_ylim(-0.7, len(others) - 0.3)
    ax.set_xlabel("P(run > baseline) + 0.5 P(run = baseline), over seed pairs")
    ax.grid(axis="x", alpha=0.3)


def _profile_panel(ax, comparison: Comparison) -> None:
    for i, summary in enumerate(comparison.runs):
        profile, low, high = stats.performance_profile_band(
            summary.entry.scores, TAUS, comparison.reps, seed=comparison.seed
        )
        ax.plot(TAUS, profile, color=f"C{i % 10}", lw=1.6, label=summary.entry.name)
        ax.fill_between(TAUS, low, high, color=f"C{i % 10}", alpha=0.2, lw=0)
    ax.set(
        title="performance profile",
        xlabel="greedy Gymnasium return tau",
        ylabel="fraction of seeds scoring > tau",
        xlim=(0, stats.MAX_RETURN),
        ylim=(-0.02, 1.02),
    )
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left")


def _no_data(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, color="0.4")


def _sample_efficiency_panel(ax, entries: list[Entry], seed: int) -> None:
    drawn = False
    for i, entry in enumerate(entries):
        values = entry.train_return
        if values is None or not np.isfinite(values).any():
            continue
        drawn = True
        points = np.unique(np.linspace(0, len(values) - 1, CURVE_POINTS).round().astype(int))
        iqm, low, high = stats.curve_band(
            values[points], "iqm", CURVE_REPS, seed=seed, bounds=(0.0, stats.MAX_RETURN)
        )
        x = entry.run.env_steps[points]
        ax.plot(x, iqm, color=f"C{i % 10}", lw=1.6)
        ax.fill_between(x, low, high, color=f"C{i % 10}", alpha=0.2, lw=0)
    ax.set(
        title="sample efficiency: IQM across seeds of the training return",
        xlabel="env steps per seed",
        ylabel=plot.RETURN_METRIC,
        ylim=(0, 520),
    )
    ax.axhline(stats.MAX_RETURN, color="0.6", lw=0.8, ls="--")
    ax.grid(alpha=0.3)
    if not drawn:
        _no_data(ax, f"{plot.RETURN_METRIC} not recorded")


def _solved_panel(ax, comparison: Comparison, wall_time: bool) -> None:
    """Fraction of seeds in which a training episode had scored 500, by env step or second."""
    for i, summary in enumerate(comparison.runs):
        run = summary.entry.run
        x = run.elapsed if wall_time else run.env_steps
        first = summary.seconds_to_500 if wall_time else summary.steps_to_500
        if x is None or first is None:
            continue
        ok = np.isfinite(x)
        x = np.r_[0.0, x[ok]]
        ax.step(x, stats.fraction_reached(first, x), where="post", color=f"C{i % 10}", lw=1.6)
    what = "training wall time [s] (compile excluded)" if wall_time else "env steps per seed"
    ax.set(
        title=f"a training episode at 500, by {'wall time' if wall_time else 'env steps'}",
        xlabel=what,
        ylabel="fraction of seeds",
        ylim=(-0.02, 1.02),
    )
    ax.grid(alpha=0.3)
    if not ax.lines:
        _no_data(ax, "not recorded")
        return
    notes = plot.wall_time_notes([s.entry.run for s in comparison.runs]) if wall_time else []
    if not any(
        np.isfinite(s.steps_to_500).any() for s in comparison.runs if s.steps_to_500 is not None
    ):
        notes.append("no seed's training reached 500")
    plot.draw_notes(ax, notes, fontsize=7.5, width=45)


def draw_comparison(comparison: Comparison) -> Figure:
    """The figure: aggregate intervals, probability of improvement, performance profile,
    sample efficiency and the fraction of seeds solved by env steps and by wall time."""
    from matplotlib.figure import Figure

    n = len(comparison.runs)
    fig = Figure(figsize=(18, 13 + 0.25 * n), layout="constrained")
    grid = fig.add_gridspec(3, 4, height_ratios=[0.6 + 0.12 * n, 1, 1])
    for k, (name, label) in enumerate(ESTIMATE_NAMES.items()):
        ax = fig.add_subplot(grid[0, k])
        _interval_panel(ax, comparison, name, label)
        if k == 0:
            names = [s.entry.name for s in reversed(comparison.runs)]
            ax.set_yticks(range(n), names, fontsize=8)
    _improvement_panel(fig.add_subplot(grid[1, 0:2]), comparison)
    _profile_panel(fig.add_subplot(grid[1, 2:4]), comparison)
    entries = [s.entry for s in comparison.runs]
    _sample_efficiency_panel(fig.add_subplot(grid[2, 0:2]), entries, comparison.seed)
    _solved_panel(fig.add_subplot(grid[2, 2]), comparison, wall_time=False)
    _solved_panel(fig.add_subplot(grid[2, 3]), comparison, wall_time=True)
    fig.suptitle(
        f"CartPole-v1, {n} run(s): per-seed score = mean greedy Gymnasium return; "
        f"{stats.CONFIDENCE:.0%} percentile bootstrap intervals",
        fontsize=13,
    )
    return fig


def prepare_out(out: Path | None, entries: list[Entry]) -> Path:
    """Creates the output directory; refuses one inside a compared run (or its sweep)."""
    out = layout.default_compare_dir() if out is None else Path(out)
    target = out.resolve()
    for entry in entries:
        owner = entry.run.path.resolve()
        if entry.run.combination:  # a combination's sweep directory is a run directory too
            owner = owner.parent
        if target == owner or owner in target.parents:
            raise cli.UsageError(
                f"--out {out} is inside the run directory {owner}; write the comparison elsewhere"
            )
    if out.exists() and not out.is_dir():
        raise cli.UsageError(f"--out {out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    return out


@dataclass(frozen=True)
class CompareResult:
    comparison: Comparison
    json_path: Path
    figure_path: Path


def compare_runs(
    run_dirs: Sequence[str | os.PathLike],
    baseline: str | os.PathLike | None = None,
    out: str | os.PathLike | None = None,
    reps: int = stats.DEFAULT_REPS,
    seed: int = stats.DEFAULT_SEED,
    dpi: int = 100,
) -> CompareResult:
    """Compares run directories and writes ``compare.json`` and ``compare.png`` into ``out``.

    Args:
        run_dirs: run or sweep directories (a sweep stands for its combinations).
        baseline: the run the others are compared with (default the first).
        out: output directory (default ``compare-<time>`` in the current directory).
        reps, seed: bootstrap resamples and their random seed.

    Raises:
        RunDirError: an unusable run directory; cli.UsageError: bad arguments.
    """
    entries, index = load_entries(run_dirs, baseline)
    out = prepare_out(None if out is None else Path(out), entries)
    comparison = build_comparison(entries, index, reps, seed)
    json_path, figure_path = out / layout.COMPARE_FILE, out / layout.COMPARE_FIGURE_FILE
    buf = io.BytesIO()
    draw_comparison(comparison).savefig(buf, format="png", dpi=dpi)
    files.atomic_write_bytes(figure_path, buf.getvalue())
    files.write_json(json_path, comparison.to_dict())
    return CompareResult(comparison, json_path, figure_path)


def build_parser() -> argparse.ArgumentParser:
    """The CLI."""
    parser = cli.Parser(
        prog="python -m jaxcart.compare",
        description="Compare runs over their seeds with the statistics of Agarwal et al. "
        "(2021): IQM, mean, median and optimality gap of each seed's greedy Gymnasium return "
        "with 95%% percentile bootstrap intervals, the probability of improvement over a "
        "baseline, performance profiles and sample-efficiency curves. A sweep directory "
        "stands for its combinations.",
    )
    parser.add_argument("run_dirs", nargs="+", type=Path, metavar="RUN_DIR")
    parser.add_argument(
        "--baseline",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="the run the others are compared with (default: the first RUN_DIR)",
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="directory for compare.json and compare.png (default: a new compare-<time> here)",
    )
    parser.add_argument(
        "--reps", type=int, default=stats.DEFAULT_REPS, help="bootstrap resamples (default 2000)"
    )
    parser.add_argument("--seed", type=int, default=stats.DEFAULT_SEED, help="bootstrap seed")
    parser.add_argument("--dpi", type=int, default=100, help="PNG resolution")
    return parser


def _compare_command(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    if not 100 <= args.reps <= cli.MAX_REPS:
        raise cli.UsageError(f"--reps must be in [100, {cli.MAX_REPS:,}], got {args.reps}")
    if not 0 <= args.seed < 2**32:
        raise cli.UsageError(f"--seed must be in [0, 2**32), got {args.seed}")
    cli.check_dpi(args.dpi)
    result = compare_runs(args.run_dirs, args.baseline, args.out, args.reps, args.seed, args.dpi)
    print(report_text(result.comparison))
    print(f"wrote {result.json_path} and {result.figure_path}", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad input)."""
    return cli.run_command(lambda: _compare_command(argv))


if __name__ == "__main__":
    cli.command_main(main)
