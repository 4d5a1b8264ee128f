"""Structural sweeps: settings that shape the compiled program (``num_envs``, ``num_steps``,
``minibatch_size``, ``update_epochs``, ``hidden_sizes``) swept as shape groups.

Each shape group is one compiled program and one run directory of its own
(``OUT/group-000/``, ...), where the float axes of the sweep stay one vmapped program as in
any sweep. Every group's directory is created (its ``config.json`` naming the sweep's shape
axes) before the first trains, so the sweep directory is the run directories of its groups
at any stage: ``train --resume OUT`` finishes every group, and ``OUT/groups.json`` ranks
every combination of every group together, derived from the groups' own directories. Plot
and compare read ``OUT`` as the runs of its groups. Tune's batches group their trials by
shape with the same routine (:func:`by_shape`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from jaxcart.analysis.summary import EVAL, Score
from jaxcart.core.config import TRACED_FIELDS, ConfigError, PPOConfig
from jaxcart.engine.signals import StopRequest
from jaxcart.run import lifecycle
from jaxcart.run import sweep as sweeps
from jaxcart.run.spec import Hooks, Outcome, RunOptions, RunSpec
from jaxcart.rundir import files, layout, reader
from jaxcart.rundir.reader import AXES_KEY, group_label, group_values


def by_shape(points: Sequence[dict]) -> list[tuple[dict, list[int]]]:
    """Points (config values by field name) grouped by their shape settings (every field
    that is not a traced float: one compiled program per group), as ``(shape settings,
    indices of the group's points)`` in the order of each group's first point."""
    groups: dict[str, tuple[dict, list[int]]] = {}
    for i, point in enumerate(points):
        shape = {k: v for k, v in point.items() if k not in TRACED_FIELDS}
        groups.setdefault(repr(sorted(shape.items())), (shape, []))[1].append(i)
    return list(groups.values())


def group_config(config: PPOConfig, shape: dict, option: str = "--sweep") -> PPOConfig:
    """``config`` with one shape group's settings: the one check that a structural sweep's
    groups and a search space's shape choices fit together.

    Raises:
        ConfigError: shapes that do not fit together (a minibatch that does not divide the
            rollout), naming the ``option`` and the group.
    """
    try:
        return dataclasses.replace(config, **shape)
    except ConfigError as exc:
        raise ConfigError(f"{option} group {group_label(shape)}: {exc}") from None


def group_spec(spec: RunSpec, shape: dict, **changes: object) -> RunSpec:
    """One shape group's run: ``spec`` with the group's shape settings
    (:func:`group_config`) and ``changes`` to the spec, e.g. explicit ``combinations``."""
    return dataclasses.replace(spec, config=group_config(spec.config, shape), **changes)


@dataclass
class GroupsOutcome:
    """What a structural sweep did: the outcome of each group trained by this call, and,
    once every group finished, every combination ranked (``[]`` until then)."""

    out: Path
    groups: list[dict]  # each group's shape values, from its config.json
    sweep: dict
    num_seeds: int
    outcomes: list[Outcome] = field(default_factory=list)
    ranking: list[dict] = field(default_factory=list)
    signum: int | None = None  # the signal that stopped it

    @property
    def stopped(self) -> bool:
        return self.signum is not None


def run_groups(
    spec: RunSpec,
    groups: list[dict],
    out: str | Path,
    options: RunOptions | None = None,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
    command: list[str] | None = None,
    on_group: Callable[[Outcome], None] | None = None,
) -> GroupsOutcome:
    """Creates every shape group's run directory (``out/group-NNN``, each ``config.json``
    naming the shape axes), then trains them (:func:`finish_groups`).

    Raises:
        ConfigError: a group that does not fit together, or ``out`` not empty.
    """
    options = options or RunOptions()
    specs = [group_spec(spec, group) for group in groups]  # every group checked before any runs
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"--out {out} is not empty; a structural sweep starts in a new directory")
    extra = {AXES_KEY: list(groups[0]), "score": (options.score or EVAL).label}
    for g, group in enumerate(specs):
        lifecycle.create_run(group, layout.group_dir(out, g), options, command, extra).close()
    return finish_groups(out, options, hooks, stop, on_group)


def finish_groups(
    out: str | Path,
    options: RunOptions | None = None,
    hooks: Hooks | None = None,
    stop: StopRequest | None = None,
    on_group: Callable[[Outcome], None] | None = None,
) -> GroupsOutcome:
    """Trains every group of the structural sweep ``out`` that has not finished, in order
    (:func:`jaxcart.run.lifecycle.resume_run`: from its checkpoint, or from the start); a
    group stopped stops the sweep there (``train --resume OUT`` goes on). Then writes
    ``out/groups.json``: every combination ranked together from the groups' own
    directories (:func:`jaxcart.run.sweep.rank_dirs`, as a sweep's ``sweep.json``) by the
    score the groups record.

    Raises:
        RunDirError: ``out`` is not a structural sweep, or a group directory is unusable.
    """
    out, stop = Path(out), stop or StopRequest()
    paths = [path for _, path in reader.read_groups(out)]
    done = GroupsOutcome(out, [], {}, 1)
    for path in paths:
        if stop():
            done.signum = stop.signum
            return done
        try:
            outcome = lifecycle.resume_run(path, options, hooks, stop)
        except lifecycle.RunFinished:
            continue
        done.outcomes.append(outcome)
        if on_group:
            on_group(outcome)
        if outcome.stopped:
            done.signum = outcome.signum
            return done
    infos = [reader.read_run_config(path) for path in paths]
    done.groups = [group_values(info) for info in infos]
    done.sweep, done.num_seeds = infos[0].get("sweep", {}), int(infos[0]["num_seeds"])
    ranked = sweeps.rank_dirs(paths, Score.parse(infos[0].get("score", "eval")), done.groups)
    done.ranking = ranked["ranking"]
    listed = [
        {"group": g, "directory": path.name, **sweeps.json_values(shape)}
        for g, (shape, path) in enumerate(zip(done.groups, paths))
    ]
    data = {"groups": listed, "sweep": done.sweep, "num_seeds": done.num_seeds, **ranked}
    files.record_json(out, {layout.GROUPS_FILE: data})  # in the sweep's manifest, as a run's files
    return done
