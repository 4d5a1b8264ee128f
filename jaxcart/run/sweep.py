"""Hyperparameter sweeps as one compiled program, and the order of runs on the seed axis.

Every combination x seed is one run on the vmapped axis; the swept float hyperparameters
travel as arrays (the config's traced fields, one value per run), so the program compiles once
whatever the values. :class:`RunGrid` is the one definition of the run order: run ``r`` is
combination ``r // num_seeds`` with seed index ``r % num_seeds``; all combinations share the
seeds' random streams. "Seeds" are per combination, "runs" are all of them.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from jaxcart.analysis import stats, summary
from jaxcart.analysis.summary import RETURN_METRIC
from jaxcart.core import physics
from jaxcart.core.cartpole import EnvParams
from jaxcart.core.config import TRACED_FIELDS, ConfigError, PPOConfig, float_dtype
from jaxcart.rundir import files, layout, reader


@dataclass(frozen=True)
class RunGrid:
    """Which runs train together: ``num_seeds`` seeds for each combination (one combination,
    the config itself, when there is no sweep), combination-major."""

    num_seeds: int
    combos: tuple[dict[str, float], ...] = field(default_factory=tuple)

    @property
    def is_sweep(self) -> bool:
        return bool(self.combos)

    @property
    def num_combos(self) -> int:
        return max(1, len(self.combos))

    @property
    def num_runs(self) -> int:
        """Every run on the seed axis: combinations x seeds."""
        return self.num_combos * self.num_seeds

    def run_index(self, combo: int, seed_index: int) -> int:
        return combo * self.num_seeds + seed_index

    def combo_of(self, run: int) -> int:
        return run // self.num_seeds

    def seed_index_of(self, run: int) -> int:
        return run % self.num_seeds

    def seed_indices(self, runs: range | None = None) -> np.ndarray:
        """Each run's seed index, ``[len(runs)]`` (default: every run, ``[num_runs]``)."""
        runs = range(self.num_runs) if runs is None else runs
        return np.arange(runs.start, runs.stop) % self.num_seeds

    def runs_of(self, combo: int) -> slice:
        """The runs of one combination, as a slice of the seed axis."""
        return slice(self.run_index(combo, 0), self.run_index(combo + 1, 0))

    def run_name(self, run: int) -> str:
        """``seed3``, or ``combo001-seed3`` in a sweep (also directory names for loggers)."""
        seed = f"seed{self.seed_index_of(run)}"
        return f"combo{self.combo_of(run):03d}-{seed}" if self.is_sweep else seed

    def run_names(self) -> list[str]:
        return [self.run_name(r) for r in range(self.num_runs)]


def validate_sweep(config: PPOConfig, sweep: dict[str, list[float]]) -> None:
    """Raises :class:`ConfigError` for a swept value that is invalid with ``config``'s other
    fields, before anything compiles. Only traced hyperparameters are swept and each is checked
    on its own, so checking every value once checks every combination (a million-combination
    sweep costs its 2,000 values, not a million configs). Physics are checked with the run's
    env params (:func:`validate_env_sweep`)."""
    floats = {k: v for k, v in sweep.items() if not k.startswith(physics.PREFIX)}
    _check_each(floats, lambda name, value: dataclasses.replace(config, **{name: value}))


def validate_env_sweep(env_params: EnvParams, sweep: dict[str, list[float]]) -> None:
    """Raises :class:`ConfigError` for a swept physics value outside sense with
    ``env_params``' other fields (each checked on its own, as :func:`validate_sweep`)."""
    check = lambda name, value: physics.check_physics(env_params.replace(**{name: value}))
    _check_each(reader.env_values(sweep), check)


def _check_each(sweep: dict[str, list[float]], check: Callable[[str, float], object]) -> None:
    """``check(name, value)`` of every swept value; its ConfigError said as the sweep's."""
    for name, values in sweep.items():
        for value in values:
            try:
                check(name, value)
            except ConfigError as exc:
                raise ConfigError(f"--sweep value out of range: {exc}") from None


def validate_combinations(config: PPOConfig, combos: tuple[dict[str, float], ...]) -> None:
    """Raises :class:`ConfigError` for explicit combinations that set anything but traced
    float hyperparameters, or a value invalid with ``config``'s other fields."""
    for combo in combos:
        unknown = [name for name in combo if name not in TRACED_FIELDS]
        if unknown:
            raise ConfigError(
                f"a combination sets {unknown[0]!r}: only float hyperparameters run in one "
                f"program ({', '.join(TRACED_FIELDS)})"
            )
        try:
            dataclasses.replace(config, **combo)
        except ConfigError as exc:
            raise ConfigError(f"combination value out of range: {exc}") from None


def grid_values(grid: RunGrid, runs: range, name: str, base: float, dtype=float) -> np.ndarray:
    """Each of ``runs``' value of the swept field ``name`` (in ``grid`` order; a wave's, never
    every seed's), ``[len(runs)]`` of ``dtype``: its combination's, or ``base`` where that
    sets none."""
    per_combo = np.array([c.get(name, base) for c in grid.combos] or [base], dtype)
    return per_combo[np.arange(runs.start, runs.stop) // grid.num_seeds]  # each run's combination


def grid_env_values(grid: RunGrid, runs: range) -> dict[str, np.ndarray]:
    """Each swept physics field's value for ``runs`` (in ``grid`` order), float64
    ``[len(runs)]`` (``{}`` when the sweep has none): a wave's, never every seed's."""
    names = sorted({k for c in grid.combos for k in reader.env_values(c)})
    return {n: grid_values(grid, runs, physics.PREFIX + n, math.nan) for n in names}


def grid_config(config: PPOConfig, grid: RunGrid, runs: range) -> PPOConfig:
    """The config of ``runs`` (in ``grid`` order; a wave's, never every seed's), its traced
    fields ``[len(runs)]`` (float32, or float64 under x64): each run's combination's values
    (``config``'s own where it sweeps nothing)."""
    leaves = {
        n: grid_values(grid, runs, n, getattr(config, n), float_dtype()) for n in TRACED_FIELDS
    }
    return dataclasses.replace(config, **leaves)


def rank(
    grid: RunGrid,
    scores: np.ndarray,
    solved: np.ndarray,
    final_return: np.ndarray,
    steps_to_500: np.ndarray,
    diverged_at: np.ndarray | None = None,
    score: str = "eval",
) -> list[dict]:
    """Per-combination summary, best first: by the IQM of the per-seed scores (then solve
    rate, final return, steps to 500), with the statistics of :mod:`jaxcart.compare`.

    Each row holds ``score`` (the score's name, as ``compare --score`` takes it), the seeds'
    ``scores``, ``rank`` (1 + the combinations with a higher IQM: combinations tied on the
    IQM share it, and the tie-breakers alone order them), ``iqm`` and
    ``probability_of_improvement`` over combination 0 (None for combination 0 itself) as
    ``{value, ci_low, ci_high}`` with percentile bootstrap intervals at
    :data:`stats.CONFIDENCE` (:data:`stats.DEFAULT_REPS` resamples: deterministic; with fewer
    than :data:`stats.RANGE_BELOW` seeds, the range of the seeds, :func:`stats.interval_label`).

    Args:
        scores: per run, ``[num_runs]``: each seed's score by ``score``
            (:meth:`jaxcart.analysis.summary.Score.compute`, as ``compare`` scores a run).
        solved, final_return, steps_to_500: per run, ``[num_runs]``.
        diverged_at: per run, the iteration it diverged at (-1 or NaN: never).
        score: what the scores are: ``"eval"`` (each seed's mean greedy Gymnasium return),
            ``"auc"`` or ``"return-at:STEPS"``.

    Raises:
        ValueError: an unknown score, or scores that are not finite.
    """
    ranked_by = summary.Score.parse(score)
    scores = stats.check_seeds(scores)
    first = scores[grid.runs_of(0)]
    rows = []
    for c, combo in enumerate(grid.combos):
        runs = grid.runs_of(c)
        steps = steps_to_500[runs]
        improvement = stats.probability_of_improvement_ci(scores[runs], first) if c else None
        rows.append(
            {
                "combination": c,
                **combo,
                "score": ranked_by.label,
                "scores": [float(s) for s in scores[runs]],
                "iqm": stats.bootstrap_ci(scores[runs], stats.iqm).to_dict(),
                "probability_of_improvement": improvement and improvement.to_dict(),
                "solve_rate": float(np.mean(solved[runs])),
                "final_return": float(np.nanmean(final_return[runs]))
                if np.isfinite(final_return[runs]).any()
                else math.nan,
                "median_steps_to_500": float(np.median(steps)),
                "seeds_reaching_500": int(np.isfinite(steps).sum()),
                "seeds_diverged": 0 if diverged_at is None else int((diverged_at[runs] >= 0).sum()),
            }
        )
    for row in rows:
        row["rank"] = 1 + sum(r["iqm"]["value"] > row["iqm"]["value"] for r in rows)
    return sorted(
        rows,
        key=lambda r: (
            -r["iqm"]["value"],
            -r["solve_rate"],
            -np.nan_to_num(r["final_return"], nan=-1.0),
            r["median_steps_to_500"],
        ),
    )


TIE_BREAKERS = "solve rate, then final ep_rew_mean, then median steps to 500"
"""What orders combinations whose IQMs tie (:func:`rank`)."""


def saturated(ranking: list[dict]) -> bool:
    """Whether every seed of every ranked combination has the same score
    (:func:`jaxcart.analysis.stats.saturated`): the score ranks nothing."""
    return stats.saturated([np.asarray(r["scores"]) for r in ranking])


def json_values(group: dict) -> dict:
    """A shape group's values as JSON writes them (``hidden_sizes`` a list)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in group.items()}


def rank_dirs(dirs: list[Path], score: summary.Score, groups: list[dict] | None = None) -> dict:
    """Every combination of the finished run directories ``dirs`` (a sweep's ``combo-NNN/``,
    a run as one combination) ranked together (:func:`rank`), read back from each one's own
    ``config.json``, ``metrics.csv`` and ``evaluation.json`` as ``compare`` reads them: each
    seed scored on its own run's curve (runs may train different numbers of iterations).
    The one ranking of a sweep (``sweep.json``, ``dirs`` its own directory) and of a
    structural sweep's shape groups (``groups.json``: ``groups``, each group's shape values,
    added to its rows with the group and its ``group_combination``).

    Returns:
        ``{"score", "score_definition", "saturated", "ranking"}``: the ranking, best first.

    Raises:
        ConfigError: a score a run cannot give (``return-at`` past its end).
    """
    runs, where = [], []  # every combination's run, and its (group, combination) there
    for g, path in enumerate(dirs):
        swept = files.present(layout.combo_dir(path, 0))  # before sweep.json is written
        for c, combo_dir in enumerate(reader.combo_dirs(path) if swept else [path]):
            runs.append(reader.load_run(combo_dir))
            where.append((g, c if swept else None))
    seeds = [seed for run in runs for seed in run.evaluation["seeds"]]  # every run's, in order
    solved = np.array([bool(s["solved"]) for s in seeds])
    diverged = np.array([s.get("diverged_at_iteration") for s in seeds], float)  # NaN: never
    final = np.concatenate([run.metrics[RETURN_METRIC][-1] for run in runs])
    # env steps at which each seed's training episode first scored its env's solved return
    # (500 on CartPole-v1; the ranking's keys keep that name), inf: never
    reach = [summary.first_reached(run, run.env_steps) for run in runs]
    reach = np.concatenate(
        [np.full(run.num_seeds, np.inf) if r is None else r for run, r in zip(runs, reach)]
    )
    grid = RunGrid(runs[0].num_seeds, tuple(dict(run.combination or {}) for run in runs))
    scores = np.concatenate([score.of_run(run) for run in runs])
    rows = rank(grid, scores, solved, final, reach, diverged, score=score.label)
    if groups is not None:
        for row in rows:
            g, c = where[row["combination"]]
            row.update({"group": g, **json_values(groups[g]), "group_combination": c})
    return {
        "score": score.label,
        "score_definition": score.definition([run.env for run in runs]),
        "saturated": saturated(rows),
        "ranking": rows,
    }


def ranking_notes(ranking: list[dict]) -> list[str]:
    """What a ranking cannot tell, a line each: that its score is saturated, or which ranks
    combinations share (the same IQM: the tie-breakers alone order them). Empty when every
    IQM differs."""
    if not ranking:
        return []
    label = ranking[0]["score"]
    if saturated(ranking):
        hint = "try --score auc or return-at:STEPS" if label == "eval" else "try another --score"
        return [
            f"saturated: every seed of every combination scores {ranking[0]['scores'][0]:g} by "
            f"{label}: the ranking cannot tell them apart, their order is the tie-breakers' "
            f"({TIE_BREAKERS}); {hint}"
        ]
    notes = []
    for place in sorted({r["rank"] for r in ranking}):
        tied = sum(r["rank"] == place for r in ranking)
        if tied > 1:
            notes.append(
                f"tie: {tied} combinations share rank {place} (the same IQM by {label}); the "
                f"tie-breakers alone order them ({TIE_BREAKERS})"
            )
    return notes
