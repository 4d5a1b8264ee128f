"""Greedy (argmax) evaluation of a run's seeds in Gymnasium's own env of the run's id.

"Solved" is :mod:`jaxcart.core.solved`'s rule for that env (CartPole-v1: every one of the
evaluation episodes, 20 by default, scores 500).
``--env-param`` evaluates on other physics and ``--sweep env.NAME=V1,V2`` at each value;
``--out DIR`` writes the evaluation as a run directory without training
(:mod:`jaxcart.rundir.layout`), which ``python -m jaxcart.compare`` reads like any run, and
with ``--sweep`` draws ``robustness.png``: the return against the value, one curve per run.

Every RUN_DIR gives its sources, each a label and the run's parameters on one physics: each
combination of a sweep (``0 learning_rate=0.001``) or the run itself (None) on the physics
chosen, or with ``--sweep`` the run at each swept value (labelled by the value). Every source
is evaluated once (:func:`jaxcart.run.greedy.evaluate_params`); the tables and ``--out`` read
those returns.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jaxcart import cli
from jaxcart.analysis import stats
from jaxcart.core.solved import EVAL_SEED, NUM_EVAL_EPISODES, is_solved
from jaxcart.rundir import files, layout

if TYPE_CHECKING:  # the modules that import JAX load once the options are read (--help: none)
    from jaxcart.rundir.policy import RunParams

    Run = tuple[Path, dict, list[tuple[str | float | None, RunParams]]]
    # a RUN_DIR, its config.json and its sources: (label, the parameters on one physics)

IQM_TEXT = (
    f"IQM over seeds of each seed's mean return, {stats.CONFIDENCE:.0%} percentile bootstrap "
    f"interval ({stats.DEFAULT_REPS:,} resamples, seed {stats.DEFAULT_SEED})"
)


@dataclasses.dataclass(frozen=True)
class EvaluateOptions:
    """Everything the command line said: nothing past :func:`main` sees argparse. Each
    :func:`~jaxcart.cli.option` field is the option ``--name``, its docstring the help."""

    run_dirs: tuple[Path, ...]
    episodes: int = cli.option(NUM_EVAL_EPISODES, type=cli.bounded_count(cli.MAX_EPISODES))
    """greedy episodes per seed"""
    combination: int | None = cli.option(type=int, metavar="C")
    """only this combination of a sweep (needed with --gif)"""
    env_param: tuple[str, ...] = cli.option((), action="append", metavar="NAME=VALUE")
    """evaluate on other physics: this field of CartPole's params over the run's own
    (repeatable; default: the physics the run trained on, a randomised field at its nominal
    value)"""
    sweep: tuple[str, ...] = cli.option((), action="append", metavar="env.NAME=V1,V2,...")
    """evaluate at each value of one continuous physics field (over the run's physics and
    --env-param) and print the IQM over seeds with its 95% bootstrap interval per value; with
    --out, one evaluation per value and robustness.png"""
    out: Path | None = cli.option(type=cli.out_dir, metavar="DIR")
    """write the evaluation into this new directory for python -m jaxcart.compare: every
    seed's greedy returns, the physics, the run it came from (a sweep of them with --sweep;
    one subdirectory per RUN_DIR when there are several)"""
    policy: str = cli.option("final", choices=list(layout.POLICY_FILES))
    """final: the parameters at the end of training; best: each seed's best policy by the
    evaluation during training (a run trained with --eval-every N --keep-best)"""
    gif: Path | None = cli.option(type=Path)
    """also render one episode to a GIF"""
    seed_index: int = cli.option(0, type=int)
    """the seed --gif renders"""
    gif_seed: int = cli.option(
        EVAL_SEED,
        type=cli.seed,
        help=f"env.reset seed of the GIF's episode (default: {EVAL_SEED}, the first "
        "evaluation episode's)",
    )
    trust_code: bool = False  # cli.SharedOptions'


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m jaxcart.evaluate`` command line."""
    parser = cli.Parser(
        prog="python -m jaxcart.evaluate",
        description="Evaluate every seed of a jaxcart run greedily in Gymnasium's own env of "
        "the run's id (CartPole-v1: solved = every episode scores 500); optionally render "
        "one seed's policy to an animated GIF. A run that did not finish is evaluated from "
        "its last checkpoint (and says so); a sweep directory, every combination.",
    )
    what = "jaxcart run (or sweep) directories"
    parser.add_argument("run_dirs", type=Path, nargs="+", metavar="RUN_DIR", help=what)
    cli.add_options(parser, EvaluateOptions, "")
    cli.add_options(parser, cli.SharedOptions, "", ("trust_code",))
    return parser


def _overrides(trained: RunParams) -> dict:
    """The physics ``trained`` plays on, as the fields that differ from CartPole-v1's (``{}``
    for an env with its own)."""
    from jaxcart.core import physics

    return {} if trained.env_params is None else physics.overrides(trained.env_params)


def _options(opts: EvaluateOptions) -> tuple[dict, str | None, list[float]]:
    """``--env-param``'s physics, and ``--sweep``'s field and values (``env.length``,
    ``[0.5, 1.0]``; ``None, []`` without), with ``--out`` and ``--gif``: what no run is needed
    to check, checked first (a value outside physical sense is one line).

    Raises:
        UsageError, ConfigError: not one continuous physics field, one --env-param sets, or
            an option that cannot be honoured.
    """
    from jaxcart.core import physics
    from jaxcart.run.spec import parse_env_params, parse_sweep

    chosen = parse_env_params(opts.env_param)
    field, values = None, []
    if opts.sweep:
        if len(opts.sweep) > 1 or not opts.sweep[0].strip().startswith(physics.PREFIX):
            raise cli.UsageError(
                "--sweep evaluates on other physics, one field: env.NAME=V1,V2,... (e.g. "
                f"env.length=0.25,0.5,1), got {' '.join(opts.sweep)}"
            )
        ((field, values),) = parse_sweep(opts.sweep)[0].items()
        if field[len(physics.PREFIX) :] in chosen:
            raise cli.UsageError(f"{field} is both swept and set by --env-param; keep one")
    if opts.out is not None and files.present(opts.out):
        raise cli.UsageError(
            f"--out {opts.out} exists; evaluate writes a new directory, so that nothing is "
            "overwritten"
        )
    scoring = sorted(set(chosen) & {"max_episode_steps", "sutton_barto_reward"})
    if opts.out is not None and scoring:
        raise cli.UsageError(
            f"--env-param {scoring[0]} changes what an episode scores, and an evaluation "
            "directory judges 500 as solved; evaluate without --out"
        )
    if opts.gif is not None:
        if len(opts.run_dirs) > 1 or field:
            raise cli.UsageError("--gif renders one run on one physics: one RUN_DIR, no --sweep")
        if opts.gif.suffix.lower() != ".gif":
            raise cli.UsageError(f"--gif {opts.gif} must end in .gif")
        if not opts.gif.parent.is_dir():
            raise cli.UsageError(f"--gif {opts.gif}: directory {opts.gif.parent} does not exist")
    return chosen, field, values


def _read_run(
    run_dir: Path, opts: EvaluateOptions, chosen: dict, field: str | None, values: list
) -> Run:
    """A RUN_DIR, its ``config.json`` and its sources (the run, one combination, or every
    combination of a sweep; with ``field``, the one at each of ``values``), with
    ``opts.policy``'s parameters on the run's physics with ``chosen`` over them; every option
    and physics checked (a value outside physical sense is one line) before anything is
    evaluated."""
    from jaxcart import report
    from jaxcart.core import physics
    from jaxcart.rundir.policy import has_physics, run_params, seed_params
    from jaxcart.rundir.reader import is_evaluation, read_run_config, recorded_combinations

    info = read_run_config(run_dir)
    if is_evaluation(info):
        source = info[layout.EVALUATION_OF_KEY]["run"]
        raise cli.UsageError(f"{run_dir} is an evaluation of {source}; evaluate that run")
    env_id, combos = info["config"].env, recorded_combinations(info)
    if (chosen or field) and not has_physics(env_id):
        option = "--sweep" if field else "--env-param"
        raise cli.UsageError(f"{option} sets CartPole's physics; {run_dir} trained {env_id}")
    if opts.gif is not None and (refusal := report.gif_refusal(env_id)):
        raise cli.UsageError(refusal)
    if opts.gif is not None and combos and opts.combination is None:
        raise cli.UsageError("--gif on a sweep needs --combination C (which policy to render)")
    chosen_combos = range(len(combos)) if combos and opts.combination is None else [None]
    if (field or opts.out is not None) and len(chosen_combos) > 1:
        raise cli.UsageError(
            f"{run_dir} is a sweep: --sweep and --out evaluate one run; choose --combination C"
        )
    points = [{**chosen, field[len(physics.PREFIX) :]: v} for v in values] if field else [chosen]
    sources = []
    for c in chosen_combos:
        c = opts.combination if c is None else c
        trained = run_params(run_dir, c, opts.policy, trust_code=opts.trust_code)
        if opts.gif is not None:
            seed_params(trained, opts.seed_index, "--seed-index")
        label = f"{c} " + ",".join(f"{k}={v:g}" for k, v in combos[c].items()) if combos else None
        for value, p in zip(values or [label], points):
            env = physics.make_env_params({**_overrides(trained), **p}) if p else trained.env_params
            sources.append((value, dataclasses.replace(trained, env_params=env)))
    return run_dir, info, sources


def _heading(what: str, env_id: str, on: str, opts: EvaluateOptions) -> str:
    best = " (each seed's best policy)" if opts.policy == "best" else ""
    return (
        f"Greedy evaluation {what}{best}, {opts.episodes} episodes per seed in "
        f"gymnasium.make('{env_id}'){on} (reset seeds {EVAL_SEED}..."
        f"{EVAL_SEED + opts.episodes - 1}):"
    )


def _print_seeds(run: Run, returns: list[np.ndarray], opts: EvaluateOptions) -> None:
    """The per-seed table of a RUN_DIR's sources, each on its one physics."""
    from jaxcart import report
    from jaxcart.core import physics

    run_dir, info, sources = run
    env_id, sweep = info["config"].env, sources[0][0] is not None
    rows = []
    for (label, _), r in zip(sources, returns):
        rows += [[label] * sweep + row for row in report.seed_rows(r, env_id)]
    shown = {physics.describe(_overrides(t)) for _, t in sources}
    text = shown.pop() if len(shown) == 1 else "each combination's physics"
    if not text and opts.env_param:  # --env-param chose the env's own
        text = f"{env_id}'s own physics"
    print(_heading(f"of {run_dir}", env_id, f" with {text}" if text else "", opts))
    print(cli.format_table(rows, ["combination"] * sweep + ["seed", "mean", "min", "solved"]))
    solved = sum(r[-1] == "yes" for r in rows)
    print(f"solved {solved}/{len(rows)} seed(s){report.mean_rule(env_id)}", flush=True)


def _print_values(
    runs: list[Run],
    returns: list[list[np.ndarray]],
    field: str,
    chosen: dict,
    opts: EvaluateOptions,
) -> list[list[stats.Estimate]]:
    """One row per run and swept value: the IQM over seeds of each seed's mean return with its
    interval, as ``compare`` computes it; returns those IQMs, per run and value."""
    from jaxcart.core import physics

    iqms = [[stats.bootstrap_ci(r.mean(-1), stats.iqm) for r in rs] for rs in returns]
    rows = []
    for (run_dir, info, sources), rs, estimates in zip(runs, returns, iqms):
        for (value, _), r, iqm in zip(sources, rs, estimates):
            solved = is_solved(r, info["config"].env)
            row = [run_dir, f"{value:g}", f"{solved.sum()}/{solved.size}", iqm.format(1)]
            rows.append([*row, f"{r.mean():.1f}", f"{r.mean(-1).min():.1f}"])
    on = " with each run's physics" + (f" and {physics.describe(chosen)}" if chosen else "")
    print(_heading(f"at each {field}", runs[0][1]["config"].env, on, opts))
    header = ["run", field, "solved", "IQM [95% CI]", "mean", "worst seed"]
    print(cli.format_table(rows, header, cli.TABLE_WIDTH))
    print(cli.wrap(f"IQM [95% CI]: {IQM_TEXT}, as python -m jaxcart.compare computes it"))
    return iqms


@cli.command(ValueError, ImportError)
def main(argv: list[str] | None = None) -> int:
    """``python -m jaxcart.evaluate RUN_DIR [RUN_DIR ...]``: prints the per-seed Gymnasium
    evaluation table (with ``--sweep``, the IQM over seeds at each value); with ``--out``,
    writes the evaluation; with ``--gif``, renders seed ``--seed-index``. Returns 0, or 2 for
    bad input."""
    opts = cli.options_from(EvaluateOptions, build_parser().parse_args(argv))
    from jaxcart.run.greedy import evaluate_params  # JAX: once the options are read

    chosen, field, values = _options(opts)  # before any run is read
    runs = [_read_run(d, opts, chosen, field, values) for d in opts.run_dirs]
    returns = []  # per run, per source: [num_seeds, episodes]
    for run in runs:
        note = run[2][0][1].note
        if note:
            resume = f"python -m jaxcart.train --resume {run[0]}"
            print(f"note: parameters {note} (resume with: {resume})")
        returns.append([evaluate_params(t, opts.episodes) for _, t in run[2]])
        if field is None:
            _print_seeds(run, returns[-1], opts)
    iqms = None if field is None else _print_values(runs, returns, field, chosen, opts)
    if opts.out is not None:
        _write(opts, runs, returns, field, iqms)
    if opts.gif is not None:
        _write_gif(opts, runs[0][2][0][1])  # one run, one source
    return 0


def _write(
    opts: EvaluateOptions,
    runs: list[Run],
    returns: list[list[np.ndarray]],
    field: str | None,
    iqms: list[list[stats.Estimate]] | None,
) -> None:
    """The evaluations into ``--out``, a new directory (several runs: one subdirectory each,
    named after the run). Without ``field`` each is one evaluation; with it, a sweep of them:
    ``combo-NNN/`` per value, then the sweep's ``config.json`` and ``sweep.json`` (the IQM at
    each value), and ``robustness.png`` in ``--out``."""
    from jaxcart.results import figure  # matplotlib: only when drawn
    from jaxcart.rundir.directory import write_evaluation_dir
    from jaxcart.rundir.reader import default_label

    fig = None
    if iqms is not None:  # drawn first: a figure that cannot be drawn leaves no directory
        labels = [default_label(Path(run_dir), info) for run_dir, info, _ in runs]
        env_ids = [info["config"].env for _, info, _ in runs]
        values = [value for value, _ in runs[0][2]]
        fig = figure.draw_robustness(field, values, labels, iqms, env_ids, IQM_TEXT, opts.episodes)
    opts.out.mkdir(parents=True)  # never an existing one: a race for it ends here, in one line
    written = []
    for k, ((run_dir, info, sources), rs) in enumerate(zip(runs, returns)):
        path = opts.out
        if len(runs) > 1:
            path = layout.fresh_dir(opts.out / Path(run_dir).resolve().name)  # run-2: a twin
            path.mkdir()
        record = functools.partial(_record, run_dir, info, opts)
        with files.opened(path) as directory:
            if field is None:
                write_evaluation_dir(directory, record(sources[0][1]), rs[0])
            else:
                values = [value for value, _ in sources]
                for c, ((value, trained), r) in enumerate(zip(sources, rs)):
                    name = layout.combo_dir(".", c).name
                    with contextlib.closing(directory.sub(name, create=True)) as sub:
                        write_evaluation_dir(sub, record(trained, combination={field: value}), r)
                points = [
                    {field: v, "iqm": e.to_dict(), "solved_seeds": int(is_solved(r).sum())}
                    for v, e, r in zip(values, iqms[k], rs)
                ]
                ranking = {"sweep": {field: values}, "score": "eval", "statistic": IQM_TEXT}
                swept = field.split(".", 1)[1]
                base = {n: v for n, v in _overrides(sources[0][1]).items() if n != swept}
                top = record(sources[0][1], sweep={field: values}, env_params=base)
                others = {layout.SWEEP_FILE: {**ranking, "values": points}}
                write_evaluation_dir(directory, top, others=others)
        written.append(path)
    if fig is not None:
        figure.save(fig, opts.out / layout.ROBUSTNESS_FIGURE_FILE)
    _print_written(opts.out, written, field)


def _record(run_dir: Path, info: dict, opts: EvaluateOptions, trained: RunParams, **extra) -> dict:
    """An evaluation's ``config.json``: the seeds' config as the run trained them, the
    physics they are evaluated on (``env_params``) and the run they came from."""
    from jaxcart.rundir.directory import package_versions
    from jaxcart.rundir.reader import X64_KEY, physics_label

    return {
        "format_version": layout.FORMAT_VERSION,
        "preset": info.get("preset", ""),
        "num_seeds": trained.num_seeds,
        "seed": info.get("seed", 0),
        X64_KEY: info.get(X64_KEY, False),
        "config": trained.config.to_dict(),
        "env_params": _overrides(trained),
        "eval_episodes": opts.episodes,
        "versions": package_versions(),
        layout.EVALUATION_OF_KEY: {
            "run": str(run_dir),
            "combination": opts.combination,
            "policy": opts.policy,
            "trained_physics": physics_label(info),
            "note": trained.note,
        },
        **extra,
    }


def _print_written(out: Path, written: list[Path], field: str | None) -> None:
    """Where the evaluations went, and the ``compare`` command that reads them."""
    listed = " ".join(map(str, written))
    if field is None:
        other = " OTHER_EVALUATION" if len(written) == 1 else ""
        print(f"wrote {listed}; compare: python -m jaxcart.compare {listed}{other}")
        return
    runs = " ".join(f"--arm {p.name}={p}" for p in written) if len(written) > 1 else str(out)
    print(
        f"wrote {listed} (one evaluation per {field}: combo-000/, ...) and "
        f"{out / layout.ROBUSTNESS_FIGURE_FILE}; per value: python -m jaxcart.compare {runs}"
    )


def _write_gif(opts: EvaluateOptions, trained: RunParams) -> None:
    from jaxcart.results.gif import render_gif
    from jaxcart.rundir.policy import make_policy, seed_params

    policy = make_policy(seed_params(trained, opts.seed_index, "--seed-index"), trained.config)
    env_id, env_params = trained.config.env, trained.env_params
    gif = render_gif(policy, opts.gif, seed=opts.gif_seed, env_id=env_id, env_params=env_params)
    print(
        f"wrote {gif.path}: seed {opts.seed_index}, {gif.steps} steps, return "
        f"{gif.episode_return:.0f}, {gif.frames} frames ({gif.backend} renderer)"
    )


if __name__ == "__main__":
    cli.command_main(main)
