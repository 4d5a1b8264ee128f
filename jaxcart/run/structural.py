"""Structural sweeps: settings that shape the compiled program (``num_envs``, ``num_steps``,
``minibatch_size``, ``update_epochs``, ``hidden_sizes``) swept as shape groups.

Each shape group is one compiled program and one run directory of its own
(``OUT/group-000/``, ...), where the float axes of the sweep stay one vmapped program as in
any sweep; ``OUT/groups.json`` records every group's shape values and ranks every
combination of every group together by the sweep's score. Plot and compare read ``OUT`` as
the runs of its groups.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from jaxcart.analysis.summary import EVAL, Score
from jaxcart.core.config import ConfigError
from jaxcart.run import sweep as sweeps
from jaxcart.run.spec import Outcome, RunSpec
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.reader import group_label

SHAPE_FIELDS = ("num_envs", "num_steps", "minibatch_size", "update_epochs", "hidden_sizes")
"""Settings a structural sweep groups by: each value changes the program's shapes."""
MAX_GROUPS = 64
"""Shape groups per structural sweep: each compiles a program of its own."""


def parse_shape_value(name: str, text: str) -> int | tuple[int, ...]:
    """One value of a shape axis: an integer, or for ``hidden_sizes`` widths joined by ``x``
    (``64x64``)."""
    try:
        if name == "hidden_sizes":
            return tuple(int(w) for w in text.strip().split("x"))
        return int(text)
    except ValueError:
        example = "64x64" if name == "hidden_sizes" else "8"
        raise ConfigError(f"--sweep {name}: {text!r} is not a value like {example}") from None


def split_sweep(specs: list[str]) -> tuple[list[str], dict[str, list]]:
    """The ``--sweep`` options on float hyperparameters (one program), and the shape axes
    ``{name: [values]}`` (one program per combination of their values).

    Raises:
        ConfigError: a shape axis given twice, with repeated values, or too many groups.
    """
    floats, shapes = [], {}
    for spec in specs:
        name, sep, values = spec.partition("=")
        name = name.strip().replace("-", "_")
        if name not in SHAPE_FIELDS or not sep:
            floats.append(spec)
            continue
        if name in shapes:
            raise ConfigError(f"--sweep {name} given twice; put all its values in one option")
        parsed = [parse_shape_value(name, v) for v in values.split(",") if v.strip()]
        if not parsed or len(set(parsed)) != len(parsed):
            raise ConfigError(f"--sweep {name}: give distinct values, got {values!r}")
        shapes[name] = parsed
    groups = math.prod(len(v) for v in shapes.values())
    if groups > MAX_GROUPS:
        raise ConfigError(
            f"--sweep: {groups} shape groups, each its own program; at most {MAX_GROUPS}"
        )
    return floats, shapes


def shape_groups(shapes: dict[str, list]) -> list[dict]:
    """Every combination of the shape axes, in ``itertools.product`` order."""
    return [dict(zip(shapes, values)) for values in itertools.product(*shapes.values())]


def group_specs(spec: RunSpec, groups: list[dict]) -> list[RunSpec]:
    """Each group's run: the spec with the group's shape values (checked before any runs).

    Raises:
        ConfigError: a group whose shapes do not fit together (e.g. a minibatch that does not
            divide the rollout), naming the group.
    """
    out = []
    for group in groups:
        try:
            config = dataclasses.replace(spec.config, **group)
            out.append(dataclasses.replace(spec, config=config))
        except ConfigError as exc:
            raise ConfigError(f"--sweep group {group_label(group)}: {exc}") from None
    return out


@dataclass
class GroupsOutcome:
    """What a structural sweep did: each group's outcome, and every combination ranked."""

    out: Path
    groups: list[dict]
    outcomes: list[Outcome]
    ranking: list[dict]


def run_groups(
    spec: RunSpec,
    groups: list[dict],
    out: str | Path,
    train_group: Callable[[RunSpec, Path], Outcome],
    score: Score | None = None,
) -> GroupsOutcome:
    """Trains every shape group into ``out/group-NNN`` (``train_group(spec, out)``, e.g.
    :func:`jaxcart.run.lifecycle.run_new`), then writes ``out/groups.json``: the groups and
    every combination ranked together by ``score`` (default eval; whether it is saturated, and each row's
    rank: :func:`jaxcart.run.sweep.rank`). A group stopped early stops the sweep there.

    Raises:
        ConfigError: a group that does not fit together, or ``out`` not empty.
    """
    specs = group_specs(spec, groups)
    score = score or EVAL
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"--out {out} is not empty; a structural sweep starts in a new directory")
    out.mkdir(parents=True, exist_ok=True)
    outcomes = []
    for g, group_spec in enumerate(specs):
        outcome = train_group(group_spec, layout.group_dir(out, g))
        outcomes.append(outcome)
        if outcome.stopped:
            return GroupsOutcome(out, groups, outcomes, [])
    ranking = rank_groups(groups, outcomes, spec.num_seeds, score)
    data = {
        "groups": [
            {"group": g, "directory": layout.group_dir(".", g).name, **_json(group)}
            for g, group in enumerate(groups)
        ],
        "sweep": spec.sweep,
        "num_seeds": spec.num_seeds,
        "score": score.label,
        "score_definition": score.definition,
        "saturated": sweeps.saturated(ranking),
        "ranking": ranking,
    }
    files.write_json(out / layout.GROUPS_FILE, data)
    return GroupsOutcome(out, groups, outcomes, ranking)


def _json(group: dict) -> dict:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in group.items()}


def rank_groups(
    groups: list[dict], outcomes: list[Outcome], num_seeds: int, score: Score = EVAL
) -> list[dict]:
    """Every combination of every group ranked together as one sweep's
    (:func:`jaxcart.run.sweep.rank`: IQM of each seed's ``score``, by default its mean greedy
    Gymnasium return, then solve rate, final return, steps to 500), each row with its group
    and shape values. Each group's seeds are scored on their own curves (groups may train
    different numbers of iterations)."""
    combos, scores, solved, final, reach, diverged, where = [], [], [], [], [], [], []
    for g, (group, outcome) in enumerate(zip(groups, outcomes)):
        run_dir = outcome.run.out
        grid = outcome.run.grid
        for c in range(grid.num_combos):
            combo = grid.combos[c] if grid.is_sweep else {}
            combos.append({**combo})
            where.append((g, c if grid.is_sweep else None))
        metrics = _metrics(run_dir, grid)
        steps = metrics["env_steps"][:, 0]
        curves = metrics["rollout/ep_rew_mean"] if score.name != "eval" else None
        gym = outcome.evaluation.gym_returns.mean(-1)
        scores.append(score.compute(gym, curves, steps, outcome.run.config.env))
        solved.append(outcome.evaluation.solved)
        final.append(outcome.final_return)
        diverged.append(outcome.diverged_at)
        reach.append(sweeps.first_reach(metrics["rollout/ep_rew_max"], steps))
    grid = sweeps.RunGrid(num_seeds, tuple(combos))
    rows = sweeps.rank(
        grid,
        np.concatenate(scores),
        np.concatenate(solved),
        np.concatenate(final),
        np.concatenate(reach),
        np.concatenate(diverged),
        score=score.label,
    )
    for row in rows:
        g, c = where[row["combination"]]
        row.update({"group": g, **_json(groups[g]), "group_combination": c})
    return rows


def _metrics(run_dir: Path, grid: sweeps.RunGrid) -> dict[str, np.ndarray]:
    """A group's metrics.csv columns ``[iterations, runs]``, every combination's runs side
    by side."""
    dirs = (
        [layout.combo_dir(run_dir, c) for c in range(grid.num_combos)]
        if grid.is_sweep
        else [run_dir]
    )
    parts = [reader.read_run_metrics(d, reader.read_run_config(d)) for d in dirs]
    return {k: np.concatenate([m[k] for m in parts], axis=1) for k in parts[0]}
