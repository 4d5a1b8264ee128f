"""Runs read for a comparison: each run's per-seed scores by the chosen
:class:`~jaxcart.analysis.summary.Score`, their statistics
(:func:`build_comparison`), arms over several configurations, and what
``python -m jaxcart.compare`` writes (``compare.json`` and the per-seed ``curves.csv``).
"""

from __future__ import annotations

import csv
import functools
import io
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jaxcart.analysis import stats, summary
from jaxcart.analysis.summary import REACHED_METRIC, RETURN_METRIC, Score
from jaxcart.core.config import ConfigError
from jaxcart.core.solved import reached_label, return_bounds, solved_return
from jaxcart.rundir import layout, reader
from jaxcart.rundir.files import RunDirError
from jaxcart.rundir.reader import RunCurves, load_runs


def reached_definition(env_ids: Sequence[str]) -> str:
    """What "reached" means for runs of ``env_ids``: a training episode scored the env's
    solved return (CartPole-v1: 500, its best return; Acrobot-v1: at least -100)."""
    label = reached_label(env_ids)
    if any(solved_return(e) != return_bounds(e)[1] for e in env_ids):  # some score more
        label = "at least " + ("its env's solved return" if label == "threshold" else label)
    return f"first iteration in which a training episode scored {label} ({REACHED_METRIC})"


class CompareError(ValueError):
    """A comparison that cannot be made as asked (one line for the user)."""


@dataclass(frozen=True)
class Entry:
    """One compared run: its curves and per-seed scores."""

    run: RunCurves
    scores: np.ndarray  # [num_seeds] by the comparison's score
    solved: int | None  # seeds solved by evaluate's definition; None without evaluation.json
    episodes: int | None  # greedy episodes per seed

    @property
    def name(self) -> str:
        return self.run.label


def read_evaluation(
    run: RunCurves, required: bool, policy: str = "final"
) -> tuple[np.ndarray | None, int | None]:
    """``(mean greedy return per seed [num_seeds], solved seeds)`` from the run's
    ``evaluation.json`` (as :func:`jaxcart.rundir.reader.load_run` read and checked it), of the
    final policies or (``policy="best"``) of the best ones a run kept; ``(None, None)`` when
    it is missing and not ``required``.

    Raises:
        RunDirError: missing (when required), or without the best policies' evaluation.
    """
    if run.evaluation is None or run.note is not None:
        if not required:
            return None, None
        raise RunDirError(
            f"{run.path} has no {layout.EVALUATION_FILE}: --score eval needs each seed's "
            "greedy evaluation, which training writes when it finishes (--score auc does not)"
        )
    seeds = run.evaluation["seeds"]  # each with a finite gymnasium_mean (the store checks)
    if policy == "best":
        if not all(isinstance(s.get("best"), dict) for s in seeds):
            raise RunDirError(reader.no_best_policy(run.path))
        seeds = [s["best"] for s in seeds]  # each with a finite gymnasium_mean (ditto)
    means = np.array([float(s["gymnasium_mean"]) for s in seeds])
    return means, sum(bool(s.get("solved")) for s in seeds)


def make_entry(run: RunCurves, score: Score, policy: str = "final") -> Entry:
    """A run scored by ``score``.

    Raises:
        RunDirError: an unusable ``evaluation.json``; CompareError: the run lacks what the
            score needs (e.g. it ends before ``return-at``'s steps: :meth:`Score.of_run`).
    """
    means, solved = read_evaluation(run, score.name == "eval" or policy == "best", policy)
    try:
        scores = score.of_run(run, means)
    except ConfigError as exc:  # a comparison's error, as compare_runs documents
        raise CompareError(str(exc)) from None
    episodes = (run.evaluation or {}).get("episodes")  # a bounded int or None (the store checks)
    return Entry(run, scores, solved, episodes)


def load_entries(
    run_dirs: Sequence[str | os.PathLike] = (),
    baseline: str | os.PathLike | None = None,
    score: Score = summary.EVAL,
    policy: str = "final",
    arms: Sequence[tuple[str, Sequence[str | os.PathLike]]] | None = None,
) -> tuple[list[Entry], int, list[str] | None]:
    """The runs to compare (sweeps expanded), each scored (:func:`make_entry`), the
    baseline's index among them and the arms' names (None without ``arms``).

    The baseline is the first run unless ``baseline`` names one (a run directory that is not
    among ``run_dirs`` is added in front). With ``arms`` (``[(name, [run_dir per
    configuration]), ...]``, instead of ``run_dirs``) the entries are arm-major, the baseline
    arm (``baseline`` names it; default the first) first: arm ``a``'s run on configuration
    ``t`` is entry ``a * k + t`` of ``k`` per arm. A sweep stands for its combinations, one
    configuration each (an evaluation's physics values, say), and the arms' sweeps must
    sweep the same values, so that each configuration pairs like with like.

    Raises:
        RunDirError: an unusable run directory; CompareError: nothing to compare, both runs
            and arms, a run given twice, a sweep as the baseline, a run without what the
            score needs, or arms that do not pair up (see :func:`_arm_dirs`).
    """
    if arms and run_dirs:
        raise CompareError("give either RUN_DIRs or --arm, not both")
    if not arms and not run_dirs:
        raise CompareError("nothing to compare: give RUN_DIRs or --arm NAME=DIR,DIR")
    index, names = 0, None
    if arms:
        arms = _arm_dirs(arms, None if baseline is None else str(baseline))
        names = [name for name, _ in arms]
        run_dirs = [d for _, dirs in arms for d in dirs]
    elif baseline is not None and reader.is_sweep(baseline):
        raise CompareError(
            f"--baseline {baseline} is a sweep; name one of its combinations, "
            f"e.g. {layout.combo_dir(baseline, 0)}"
        )
    runs = load_runs(run_dirs)
    if baseline is not None and not arms:
        resolved = [r.path.resolve() for r in runs]
        if Path(baseline).resolve() in resolved:
            index = resolved.index(Path(baseline).resolve())
        else:
            runs = load_runs([baseline, *run_dirs])
    keys = [(run.path.resolve(), run.label if run.combination else "") for run in runs]
    for i, run in enumerate(runs):
        if keys[i] in keys[:i]:
            raise CompareError(f"{run.path} is given twice")
    return [make_entry(run, score, policy) for run in runs], index, names


def parse_arm(text: str) -> tuple[str, list[str]]:
    """``"NAME=DIR,DIR"`` -> ``(NAME, [DIR, DIR])``.

    Raises:
        CompareError: no ``=``, an empty name or no directory.
    """
    name, sep, dirs = text.partition("=")
    paths = [d.strip() for d in dirs.split(",") if d.strip()]
    if not sep or not name.strip() or not paths:
        raise CompareError(f"--arm {text!r}: expected NAME=RUN_DIR[,RUN_DIR...]")
    return name.strip(), paths


def _arm_dirs(
    arms: Sequence[tuple[str, Sequence[str | os.PathLike]]], baseline: str | None
) -> list[tuple[str, list[Path]]]:
    """Each arm's runs, every sweep replaced by its combinations, baseline arm first.

    Raises:
        CompareError: fewer than two arms, repeated names, an unknown ``baseline``, unequal
            configuration counts or sweeps of other values.
    """
    out, swept = [], set()
    for name, dirs in arms:
        runs: list[Path] = []
        for d in map(Path, dirs):
            if reader.is_sweep(d):
                swept.add(repr(reader.recorded_combinations(reader.read_run_config(d))))
                runs += reader.combo_dirs(d)
            else:
                runs.append(d)
        out.append((name, runs))
    names = [name for name, _ in out]
    if len(out) < 2 or len(set(names)) != len(names):
        raise CompareError("--arm needs at least two arms with distinct names")
    if baseline is not None and baseline not in names:
        raise CompareError(f"--baseline {baseline} is not an arm ({', '.join(names)})")
    if len({len(runs) for _, runs in out}) != 1:
        raise CompareError(
            "every --arm needs one run per configuration, in the same order; got "
            + ", ".join(f"{name}: {len(runs)}" for name, runs in out)
        )
    if len(swept) > 1:
        raise CompareError("the --arm sweeps sweep other values; give sweeps of the same values")
    return sorted(out, key=lambda arm: arm[0] != baseline)  # stable: baseline first


Stats = dict[str, stats.Estimate | None]
"""Named estimates, as ``compare.json`` names them (None: not made, e.g. a baseline's
difference from itself)."""


@dataclass
class Comparison:
    """Every run's statistics, computed when made from the scored entries
    (:func:`make_entry`), the score and the baseline; what the reader should know besides is
    :func:`comparison_notes`'s.

    Attributes:
        arms: the arms' names, baseline arm first (None without ``--arm``); the entries are
            arm-major, ``len(entries) // len(arms)`` configurations per arm.
        references: per run, the index of the run it is compared with (itself: a baseline).
        comparisons: differences read against a reference (each with a ``P(X > Y)``), the
            arms' included.
        confidence: of each difference and ``P(X > Y)`` interval (Bonferroni-widened with
            ``adjust="bonferroni"``).
        runs: per entry, :data:`stats.ESTIMATORS`' estimates with their bootstrap intervals,
            ``solved`` (the fraction of seeds solved with its Wilson interval; None: not
            known), ``difference_iqm`` and ``probability_of_improvement`` against its
            reference (None for a reference itself).
        matrix: ``[R, R]`` ``P(row > column)`` point values, None with two runs or fewer
            (or arms: across configurations, pairs of runs compare unlike things).
        arm_stats: per arm over every configuration (stratified estimates,
            :data:`jaxcart.analysis.stats.Scores`): ``iqm`` of all its tasks' scores pooled,
            and against the baseline arm ``difference_iqm`` and ``probability_of_improvement``
            (the mean over tasks of ``P(X_m > Y_m)``).
    """

    entries: list[Entry]
    baseline: int = 0
    score: Score = summary.EVAL
    reps: int = stats.DEFAULT_REPS
    seed: int = stats.DEFAULT_SEED
    adjust: str = "none"  # or "bonferroni"
    arms: list[str] | None = None
    references: list[int] = field(init=False)
    comparisons: int = field(init=False)
    confidence: float = field(init=False)
    runs: list[Stats] = field(init=False)
    matrix: np.ndarray | None = field(init=False, default=None)
    arm_stats: list[Stats] | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        """Statistics of every run from its per-seed scores, each against the baseline (with
        ``arms``, the arms' names: against the baseline arm's run on the same configuration),
        and the arms aggregated (:data:`jaxcart.analysis.stats.Scores` per configuration);
        ``adjust="bonferroni"`` widens every difference and ``P(X > Y)`` interval to
        :func:`stats.bonferroni_confidence` of the number of comparisons."""
        entries, arms, reps, seed = self.entries, self.arms, self.reps, self.seed
        if self.adjust not in summary.ADJUSTMENTS:
            raise ValueError(f"adjust must be one of {summary.ADJUSTMENTS}, got {self.adjust!r}")
        scores = [stats.check_seeds(e.scores, f"scores[{i}]") for i, e in enumerate(entries)]
        k = len(entries) // len(arms) if arms else 0  # configurations per arm
        self.references = [i % k if arms else self.baseline for i in range(len(entries))]
        self.comparisons = sum(r != i for i, r in enumerate(self.references))
        self.comparisons += len(arms) - 1 if arms else 0
        self.confidence = stats.CONFIDENCE
        if self.adjust == "bonferroni" and self.comparisons:
            self.confidence = stats.bonferroni_confidence(self.comparisons)

        def against(x: stats.Scores, y: stats.Scores | None) -> Stats:
            """The IQM difference and ``P(X > Y)``, each with its interval (None without
            ``y``)."""
            if y is None:
                return {"difference_iqm": None, "probability_of_improvement": None}
            difference = stats.difference_ci(x, y, stats.iqm, reps, self.confidence, seed)
            better = stats.probability_of_improvement_ci(x, y, reps, self.confidence, seed)
            return {"difference_iqm": difference, "probability_of_improvement": better}

        self.runs = []
        for i, (x, e, ref) in enumerate(zip(scores, entries, self.references)):
            solved = None if e.solved is None else stats.wilson_interval(int(e.solved), x.size)
            # the optimality gap: the mean shortfall from the run's env's solved return
            gap = functools.partial(stats.optimality_gap, target=solved_return(e.run.env))
            estimators = stats.ESTIMATORS | {"optimality_gap": gap}
            estimates = {  # each from the same resamples (one seed)
                name: stats.bootstrap_ci(x, statistic, reps, seed=seed)
                for name, statistic in estimators.items()
            }
            versus = against(x, scores[ref] if ref != i else None)
            self.runs.append({**estimates, "solved": solved, **versus})
        if not arms and len(scores) > 2:
            self.matrix = np.array(
                [[stats.probability_of_improvement(x, y) for y in scores] for x in scores]
            )
        if arms:
            per_arm = [scores[a * k : (a + 1) * k] for a in range(len(arms))]
            self.arm_stats = [
                {"iqm": stats.bootstrap_ci(arm, stats.iqm, reps, seed=seed)}
                | against(arm, per_arm[0] if a else None)
                for a, arm in enumerate(per_arm)
            ]

    @property
    def env_ids(self) -> list[str]:
        """The env each compared run trained on, in entry order."""
        return [e.run.env for e in self.entries]

    @property
    def reached(self) -> str:
        """The compared runs' solved return as a label (:func:`reached_label`: ``500``)."""
        return reached_label(self.env_ids)

    @property
    def saturated(self) -> bool:
        """Every seed of every run has the same score."""
        return stats.saturated([e.scores for e in self.entries])

    def reading_note(self) -> str:
        """One line: how many comparisons, and what that means for reading the intervals."""
        n = self.comparisons
        if n == 0:
            return "no comparison made (one run, or only baselines)"
        if self.adjust == "bonferroni":
            return (
                f"{n} comparison(s) against a baseline; each difference and P(X > Y) "
                f"interval is widened to {self.confidence:.2%} (Bonferroni) so that all {n} "
                f"hold together with probability at least {stats.CONFIDENCE:.0%}"
            )
        miss = stats.familywise_miss_bound(n)
        return (
            f"{n} comparison(s) against a baseline; each interval is "
            f"{stats.CONFIDENCE:.0%} on its own, so up to {miss:.0%} chance that at least one "
            "misses its true value (--adjust bonferroni widens them to hold together)"
        )

    def run_dict(self, i: int) -> dict:
        """``compare.json``'s entry of run ``i``."""

        def seeds(x: np.ndarray | None) -> list | None:
            return None if x is None else [float(v) if np.isfinite(v) else None for v in x]

        entry, run = self.entries[i], self.runs[i]
        return {
            "name": entry.name,
            "path": str(entry.run.path),
            "score": self.score.label,
            "num_seeds": len(entry.scores),
            "scores": entry.scores.tolist(),
            **_dicts(run),
            "solved_seeds": entry.solved,
            "reference": self.entries[self.references[i]].name,
            "evaluation_episodes": entry.episodes,
            "steps_to_500": seeds(summary.first_reached(entry.run, entry.run.env_steps)),
            "seconds_to_500": seeds(summary.first_reached(entry.run, entry.run.elapsed)),
        }

    def to_dict(self) -> dict:
        names = [e.name for e in self.entries]
        matrix = None if self.matrix is None else {"runs": names, "values": self.matrix.tolist()}
        arms = None
        if self.arms is not None and self.arm_stats is not None:
            k = len(names) // len(self.arms)
            arms = [
                {"name": name, "runs": names[a * k : (a + 1) * k], **_dicts(st)}
                for a, (name, st) in enumerate(zip(self.arms, self.arm_stats))
            ]
        return {
            "score": self.score.label,
            "score_definition": self.score.definition(self.env_ids),
            "saturated": self.saturated,
            "baseline": self.arms[0] if self.arms else names[self.baseline],
            "definitions": summary.DEFINITIONS,
            "reached_500": reached_definition(self.env_ids),
            "confidence": stats.CONFIDENCE,
            "comparisons": {
                "count": self.comparisons,
                "adjust": self.adjust,
                "confidence_each": self.confidence,
                "note": self.reading_note(),
            },
            "bootstrap": {"method": "percentile", "reps": self.reps, "seed": self.seed},
            "curves_file": layout.COMPARE_CURVES_FILE,
            "notes": comparison_notes(self.entries),
            "runs": [self.run_dict(i) for i in range(len(self.entries))],
            "probability_of_improvement_matrix": matrix,
            "arms": arms,
        }


def _dicts(estimates: Stats) -> dict:
    return {name: e and e.to_dict() for name, e in estimates.items()}


build_comparison = Comparison
"""A comparison's statistics from its scored runs (:class:`Comparison`, which computes them
when made): ``build_comparison(entries, baseline, score, reps, seed, adjust, arms)``."""


def comparison_notes(entries: list[Entry]) -> list[str]:
    """What the numbers do not say by themselves: unequal or single seeds, and the rest."""
    notes = []
    groups: dict[int, list[str]] = {}
    for e in entries:
        groups.setdefault(len(e.scores), []).append(e.name)
    if len(groups) > 1:
        listed = "; ".join(
            f"{count} for {names[0] if len(names) == 1 else f'{len(names)} runs'}"
            for count, names in sorted(groups.items(), reverse=True)
        )
        notes.append(
            f"seed counts differ ({listed}): each run's estimates use its own seeds, and fewer "
            "seeds give wider intervals"
        )
    for e in entries:
        if len(e.scores) == 1:
            notes.append(
                f"{e.name} has a single seed: its confidence intervals are degenerate (one value) "
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
    reached = reached_label(e.run.env for e in entries)
    evaluations = [e.name for e in entries if not e.run.metrics]  # evaluate --out's: no curves
    if evaluations:
        who = "every run is" if len(evaluations) == len(entries) else ", ".join(evaluations) + ":"
        notes.append(
            f"{who} an evaluation of a trained run (python -m jaxcart.evaluate --out): no "
            f"learning curves, so no sample efficiency and no steps to {reached}"
        )
    for e in entries:
        if e.solved is None:
            notes.append(f"{e.name} has no {layout.EVALUATION_FILE}: its solve rate is unknown")
        if not e.run.metrics:
            continue
        if not np.isfinite(e.run.metrics.get(RETURN_METRIC, np.nan)).any():
            notes.append(f"{e.name} has no {RETURN_METRIC}: no sample-efficiency curve")
        if summary.first_reached(e.run, e.run.env_steps) is None:
            notes.append(
                f"{e.name} did not record {REACHED_METRIC} (Stable-Baselines3 logs none): "
                f"left out of steps to {reached}"
            )
        if e.run.note:
            notes.append(f"{e.name}: {e.run.note}")
    return notes


def curves_csv(entries: list[Entry]) -> bytes:
    """Every seed's learning curve, ``run,seed,env_steps,ep_rew_mean`` (``nan``: no value)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["run", "seed", "env_steps", "ep_rew_mean"])
    for e in entries:
        values = e.run.metrics.get(RETURN_METRIC)
        if values is None:
            continue
        for s in range(values.shape[1]):
            for steps, v in zip(e.run.env_steps, values[:, s]):
                writer.writerow([e.name, s, f"{steps:.0f}", repr(float(v))])
    return buf.getvalue().encode()


def named_dir(run: RunCurves) -> Path:
    """The directory a run was named by: a sweep's combinations stand for their sweep (a
    finished one's are its ``combo-NNN/`` directories, an unfinished one's the sweep itself),
    and so do a structural sweep's groups."""
    in_combo_dir = run.path.name.startswith("combo-")  # layout.combo_dir's names
    path = run.path.parent if run.combination is not None and in_combo_dir else run.path
    return path.parent if reader.is_groups(path.parent) else path


def prepare_out(out: Path | None, entries: list[Entry]) -> Path:
    """Creates the output directory (default: a new ``compare-<time>`` beside the first
    compared run, e.g. in ``runs/``); refuses one inside a compared run (or its sweep)."""
    if out is None:
        out = layout.default_compare_dir(named_dir(entries[0].run).parent)
    target = out.resolve()
    for entry in entries:
        owner = named_dir(entry.run).resolve()
        if target == owner or owner in target.parents:
            raise CompareError(
                f"--out {out} is inside the run directory {owner}; write the comparison elsewhere"
            )
    if out.exists() and not out.is_dir():
        raise CompareError(f"--out {out} exists and is not a directory")
    out.mkdir(parents=True, exist_ok=True)
    return out
