"""Greedy (argmax) evaluation, in jaxcart's JAX env and in Gymnasium's own CartPole-v1.

"Solved" means every one of the evaluation episodes (20 by default) scores 500.
``--env-param`` evaluates on other physics and ``--sweep env.NAME=V1,V2`` at each value;
``--out DIR`` writes the evaluation as a run directory without training
(:mod:`jaxcart.rundir.layout`), which ``python -m jaxcart.compare`` reads like any run, and
with ``--sweep`` draws ``robustness.png``: the return against the value, one curve per run.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import io
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jaxcart import cli
from jaxcart.analysis import stats
from jaxcart.core.solved import DEFAULT_ENV, EVAL_SEED, GYMNAX_ENVS, NUM_EVAL_EPISODES, is_solved
from jaxcart.rundir import files, layout

if TYPE_CHECKING:  # the modules that import JAX load once the options are read (--help: none)
    from jaxcart.rundir.policy import RunParams

    _Sources = list[tuple[str | None, list[RunParams]]]
    # per source (the run, or each combination of a sweep): its label and its parameters on
    # each physics evaluated (each swept value, or the one chosen)


def build_parser() -> argparse.ArgumentParser:
    """The ``python -m jaxcart.evaluate`` command line."""
    parser = cli.Parser(
        prog="python -m jaxcart.evaluate",
        description="Evaluate every seed of a jaxcart run greedily in Gymnasium's own "
        "CartPole-v1 (solved = every episode scores 500); optionally render one seed's "
        "policy to an animated GIF. A run that did not finish is evaluated from its last "
        "checkpoint (and says so); a sweep directory, every combination.",
    )
    parser.add_argument(
        "run_dirs",
        type=Path,
        nargs="+",
        metavar="RUN_DIR",
        help="jaxcart run (or sweep) directories",
    )
    parser.add_argument(
        "--episodes",
        type=cli.bounded_count(cli.MAX_EPISODES),
        default=NUM_EVAL_EPISODES,
        help="greedy episodes per seed",
    )
    parser.add_argument(
        "--combination",
        type=int,
        default=None,
        metavar="C",
        help="only this combination of a sweep (needed with --gif)",
    )
    parser.add_argument(
        "--env-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="evaluate on other physics: this field of CartPole's params over the run's own "
        "(repeatable; default: the physics the run trained on, a randomised field at its "
        "nominal value)",
    )
    parser.add_argument(
        "--sweep",
        action="append",
        default=[],
        metavar="env.NAME=V1,V2,...",
        help="evaluate at each value of one continuous physics field (over the run's physics "
        "and --env-param) and print the IQM over seeds with its 95%% bootstrap interval per "
        "value; with --out, one evaluation per value and robustness.png",
    )
    parser.add_argument(
        "--out",
        type=cli.out_dir,
        default=None,
        metavar="DIR",
        help="write the evaluation into this new directory for python -m jaxcart.compare: "
        "every seed's greedy returns, the physics, the run it came from (a sweep of them with "
        "--sweep; one subdirectory per RUN_DIR when there are several)",
    )
    parser.add_argument(
        "--policy",
        choices=list(layout.POLICY_FILES),
        default="final",
        help="final: the parameters at the end of training; best: each seed's best policy "
        "by the evaluation during training (a run trained with --eval-every N --keep-best)",
    )
    cli.add_trust_code_argument(parser)
    parser.add_argument("--gif", type=Path, default=None, help="also render one episode to a GIF")
    parser.add_argument("--seed-index", type=int, default=0, help="the seed --gif renders")
    parser.add_argument(
        "--gif-seed",
        type=cli.seed,
        default=EVAL_SEED,
        help=f"env.reset seed of the GIF's episode (default: {EVAL_SEED}, the first "
        "evaluation episode's)",
    )
    return parser


def _physics_text(sources: list[tuple[str | None, RunParams]], chosen: bool) -> str:
    """`` with length=1`` when every source runs on the same non-default physics; ``""``
    for CartPole-v1's (`` with CartPole-v1's own physics`` when ``--env-param`` chose them);
    `` with each combination's physics`` when they differ."""
    from jaxcart.run import physics

    shown = {physics.describe(physics.overrides(t.env_params)) for _, t in sources}
    if len(shown) > 1:
        return " with each combination's physics"
    text = shown.pop()
    if not text:
        return " with CartPole-v1's own physics" if chosen else ""
    return f" with {text}"


def _physics_sweep(specs: list[str], chosen: dict) -> tuple[str | None, list[float]]:
    """``["env.length=0.5,1"]`` -> ``("env.length", [0.5, 1.0])``; ``(None, [])`` without.

    Raises:
        UsageError, ConfigError: not one continuous physics field, or one --env-param sets.
    """
    from jaxcart.run import physics
    from jaxcart.run.sweep import parse_sweep

    if not specs:
        return None, []
    if len(specs) > 1 or not specs[0].strip().startswith(physics.PREFIX):
        raise cli.UsageError(
            "--sweep evaluates on other physics, one field: env.NAME=V1,V2,... (e.g. "
            f"env.length=0.25,0.5,1), got {' '.join(specs)}"
        )
    ((name, values),) = parse_sweep(specs).items()
    if name[len(physics.PREFIX) :] in chosen:
        raise cli.UsageError(f"{name} is both swept and set by --env-param; keep one")
    return name, values


def _check_out(out: Path, chosen: dict) -> None:
    if layout.present(out):
        raise cli.UsageError(
            f"--out {out} exists; evaluate writes a new directory, so that nothing is overwritten"
        )
    scoring = sorted(set(chosen) & {"max_episode_steps", "sutton_barto_reward"})
    if scoring:
        raise cli.UsageError(
            f"--env-param {scoring[0]} changes what an episode scores, and an evaluation "
            "directory judges 500 as solved; evaluate without --out"
        )


def _read_run(
    run_dir: Path, args: argparse.Namespace, chosen: dict, field: str | None, values: list
) -> tuple[dict, _Sources]:
    """A run's ``config.json`` and what to evaluate of it: the run, one combination, or every
    combination of a sweep (each labelled ``0 learning_rate=0.001``), with ``args.policy``'s
    parameters, on each physics (the run's own with ``chosen`` over them, and each swept
    value); every option and physics checked (a value outside physical sense is one line)
    before anything is evaluated."""
    from jaxcart.run import physics
    from jaxcart.rundir.policy import run_params
    from jaxcart.rundir.reader import is_evaluation, read_run_config, recorded_combinations

    info = read_run_config(run_dir)
    if is_evaluation(info):
        source = info[layout.EVALUATION_OF_KEY]["run"]
        raise cli.UsageError(f"{run_dir} is an evaluation of {source}; evaluate that run")
    env_id, combos = info["config"].env, recorded_combinations(info)
    if (chosen or field) and env_id != DEFAULT_ENV:
        option = "--sweep" if field else "--env-param"
        raise cli.UsageError(f"{option} sets CartPole's physics; {run_dir} trained {env_id}")
    if args.gif is not None:
        num_seeds = int(info.get("num_seeds", 1))
        if env_id != DEFAULT_ENV:
            raise cli.UsageError(f"--gif renders CartPole-v1 only; this run trained {env_id}")
        if args.gif.suffix.lower() != ".gif":
            raise cli.UsageError(f"--gif {args.gif} must end in .gif")
        if not args.gif.parent.is_dir():
            raise cli.UsageError(f"--gif {args.gif}: directory {args.gif.parent} does not exist")
        if combos and args.combination is None:
            raise cli.UsageError("--gif on a sweep needs --combination C (which policy to render)")
        if not 0 <= args.seed_index < num_seeds:
            raise cli.UsageError(
                f"--seed-index must be in [0, {num_seeds}) for this {num_seeds}-seed run, "
                f"got {args.seed_index}"
            )
    chosen_combos = range(len(combos)) if combos and args.combination is None else [None]
    if (field or args.out is not None) and len(chosen_combos) > 1:
        raise cli.UsageError(
            f"{run_dir} is a sweep: --sweep and --out evaluate one run; choose --combination C"
        )
    points = [{**chosen, field[len(physics.PREFIX) :]: v} for v in values] if field else [chosen]
    sources = []
    for c in chosen_combos:
        c = args.combination if c is None else c
        trained = run_params(run_dir, c, args.policy, trust_code=args.trust_code)
        label = f"{c} " + ",".join(f"{k}={v:g}" for k, v in combos[c].items()) if combos else None
        on = [
            dataclasses.replace(
                trained,
                env_params=physics.make_env_params({**physics.overrides(trained.env_params), **p}),
            )
            if p
            else trained
            for p in points
        ]
        sources.append((label, on))
    return info, sources


def _print_note(run_dir: Path, trained: RunParams) -> None:
    if trained.note:
        print(
            f"note: parameters {trained.note} (resume with: python -m jaxcart.train --resume "
            f"{run_dir})"
        )


def _policy_text(args: argparse.Namespace) -> str:
    return " (each seed's best policy)" if args.policy == "best" else ""


def _evaluate_run(
    run_dir: Path, info: dict, sources: _Sources, args: argparse.Namespace
) -> list[np.ndarray]:
    """Prints the per-seed table of every source on its one physics; returns each source's
    Gymnasium returns ``[num_seeds, episodes]``."""
    from jaxcart.run.greedy import evaluate_params, summarize
    from jaxcart.rundir.reader import recorded_combinations

    env_id = info["config"].env
    num_seeds = int(info.get("num_seeds", 1))
    sweep = bool(recorded_combinations(info))
    _print_note(run_dir, sources[0][1][0])
    rows, returns = [], []
    for label, (trained,) in sources:
        returns.append(evaluate_params(run_dir, trained, args.episodes))
        summary = summarize(returns[-1], env_id)
        rows += [
            ([label] if sweep else [])
            + [s, f"{summary['mean'][s]:.1f}", f"{summary['min'][s]:.0f}"]
            + ["yes" if summary["solved"][s] else "no"]
            for s in range(num_seeds)
        ]
    on = [(label, trained) for label, (trained,) in sources]
    print(
        f"Greedy evaluation of {run_dir}{_policy_text(args)}, {args.episodes} episodes per seed "
        f"in gymnasium.make('{env_id}'){_physics_text(on, bool(args.env_param))} (reset seeds "
        f"{EVAL_SEED}...{EVAL_SEED + args.episodes - 1}):"
    )
    print(cli.format_table(rows, ["combination"] * sweep + ["seed", "mean", "min", "solved"]))
    solved = sum(r[-1] == "yes" for r in rows)
    rule = "" if env_id == DEFAULT_ENV else f" (solved: mean >= {GYMNAX_ENVS[env_id]:g})"
    print(f"solved {solved}/{len(rows)} seed(s){rule}", flush=True)
    return returns


IQM_TEXT = (
    f"IQM over seeds of each seed's mean return, {stats.CONFIDENCE:.0%} percentile bootstrap "
    f"interval ({stats.DEFAULT_REPS:,} resamples, seed {stats.DEFAULT_SEED})"
)


def _evaluate_sweep(
    runs: list[tuple[Path, dict, _Sources]], field: str, values: list, args: argparse.Namespace
) -> tuple[list[list[np.ndarray]], list[list[stats.Estimate]]]:
    """Every run at every value: prints one row per run and value (the IQM over seeds of each
    seed's mean return with its interval, as ``compare`` computes it); returns per run, per
    value, the returns ``[num_seeds, episodes]`` and that IQM."""
    from jaxcart.run import physics
    from jaxcart.run.greedy import evaluate_params

    rows, returns, iqms = [], [], []
    for run_dir, _, [(_, trained)] in runs:
        _print_note(run_dir, trained[0])
        returns.append([evaluate_params(run_dir, t, args.episodes) for t in trained])
        iqms.append([stats.bootstrap_ci(r.mean(-1), stats.iqm) for r in returns[-1]])
        for value, r, iqm in zip(values, returns[-1], iqms[-1]):
            solved = is_solved(r)
            rows.append(
                [run_dir, f"{value:g}", f"{solved.sum()}/{solved.size}", iqm.format(1)]
                + [f"{r.mean():.1f}", f"{r.mean(-1).min():.1f}"]
            )
    chosen = physics.describe(physics.parse_env_params(args.env_param))
    print(
        f"Greedy evaluation at each {field}{_policy_text(args)}, {args.episodes} episodes per "
        f"seed in gymnasium.make('{DEFAULT_ENV}') with each run's physics"
        + (f" and {chosen}" if chosen else "")
        + f" (reset seeds {EVAL_SEED}...{EVAL_SEED + args.episodes - 1}):"
    )
    header = ["run", field, "solved", "IQM [95% CI]", "mean", "worst seed"]
    print(cli.format_table(rows, header, cli.TABLE_WIDTH))
    print(cli.wrap(f"IQM [95% CI]: {IQM_TEXT}, as python -m jaxcart.compare computes it"))
    return returns, iqms


def _evaluate_command(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)  # imports JAX once the options are read
    from jaxcart.run import physics

    chosen = physics.parse_env_params(args.env_param)  # a bad --env-param before anything is read
    field, values = _physics_sweep(args.sweep, chosen)
    if args.out is not None:
        _check_out(args.out, chosen)
    if args.gif is not None and (len(args.run_dirs) > 1 or field):
        raise cli.UsageError("--gif renders one run on one physics: one RUN_DIR, no --sweep")
    runs = [(d, *_read_run(d, args, chosen, field, values)) for d in args.run_dirs]
    # per run, its returns [num_seeds, episodes] per source (one with --out) or swept value
    if field is None:
        returns = [_evaluate_run(d, info, sources, args) for d, info, sources in runs]
        iqms = None
    else:
        returns, iqms = _evaluate_sweep(runs, field, values, args)
    if args.out is not None:
        _write(args, runs, returns, field, values, iqms)
    if args.gif is not None:
        (_, _, [(_, [trained])]) = runs[0]  # one run, one source, one physics
        _write_gif(args, trained)
    return 0


def _write(
    args: argparse.Namespace,
    runs: list[tuple[Path, dict, _Sources]],
    returns: list[list[np.ndarray]],
    field: str | None,
    values: list,
    iqms: list[list[stats.Estimate]] | None,
) -> None:
    """The evaluations into ``--out``, a new directory (several runs: one subdirectory
    each, named after the run), and ``robustness.png`` in it after a sweep."""
    from jaxcart.rundir.directory import write_evaluation_dir

    png = None if iqms is None else _robustness_png(runs, field, values, iqms, args.episodes)
    args.out.mkdir(parents=True)  # never an existing one: a race for it ends here, in one line
    written = []
    for k, (run_dir, info, [(_, trained)]) in enumerate(runs):
        path = args.out
        if len(runs) > 1:
            path = layout.fresh_dir(args.out / Path(run_dir).resolve().name)  # run-2: a twin
            path.mkdir()
        record = functools.partial(_record, run_dir, info, args)
        with files.opened(path) as directory:
            if iqms is None:
                write_evaluation_dir(directory, record(trained[0]), returns[k][0])
            else:
                _write_sweep(directory, record, trained, returns[k], field, values, iqms[k])
        written.append(path)
    if png is not None:
        files.atomic_write_bytes(args.out / layout.ROBUSTNESS_FIGURE_FILE, png)
    _print_written(args.out, written, field)


def _record(
    run_dir: Path, info: dict, args: argparse.Namespace, trained: RunParams, **extra
) -> dict:
    """An evaluation's ``config.json``: the seeds' config as the run trained them, the
    physics they are evaluated on (``env_params``) and the run they came from."""
    from jaxcart.run import physics
    from jaxcart.rundir.directory import package_versions
    from jaxcart.rundir.reader import X64_KEY, physics_label

    return {
        "format_version": layout.FORMAT_VERSION,
        "preset": info.get("preset", ""),
        "num_seeds": trained.num_seeds,
        "seed": info.get("seed", 0),
        X64_KEY: info.get(X64_KEY, False),
        "config": trained.config.to_dict(),
        "env_params": physics.overrides(trained.env_params),
        "eval_episodes": args.episodes,
        "versions": package_versions(),
        layout.EVALUATION_OF_KEY: {
            "run": str(run_dir),
            "combination": args.combination,
            "policy": args.policy,
            "trained_physics": physics_label(info),
            "note": trained.note,
        },
        **extra,
    }


def _write_sweep(
    directory: files.Dir,
    record: Callable[..., dict],
    trained: list[RunParams],
    returns: list[np.ndarray],
    field: str,
    values: list,
    iqms: list[stats.Estimate],
) -> None:
    """A sweep of evaluations: ``combo-NNN/`` per value, then the sweep's ``config.json``
    and ``sweep.json`` (the IQM at each value)."""
    from jaxcart.run import physics
    from jaxcart.rundir.directory import write_evaluation_dir

    for c, (value, t, r) in enumerate(zip(values, trained, returns)):
        sub = directory.sub(layout.combo_dir(".", c).name, create=True)
        try:
            write_evaluation_dir(sub, record(t, combination={field: value}), r)
        finally:
            sub.close()
    points = [
        {field: v, "iqm": e.to_dict(), "solved_seeds": int(is_solved(r).sum())}
        for v, e, r in zip(values, iqms, returns)
    ]
    ranking = {"sweep": {field: values}, "score": "eval", "statistic": IQM_TEXT, "values": points}
    swept = field[len(physics.PREFIX) :]
    base = {k: v for k, v in physics.overrides(trained[0].env_params).items() if k != swept}
    top = record(trained[0], sweep={field: values}, env_params=base)
    write_evaluation_dir(directory, top, others={layout.SWEEP_FILE: ranking})


def _robustness_png(
    runs: list[tuple[Path, dict, _Sources]],
    field: str,
    values: list,
    iqms: list[list[stats.Estimate]],
    episodes: int,
) -> bytes:
    from jaxcart.results.figure import draw_robustness  # matplotlib: only when drawn
    from jaxcart.rundir.reader import default_label

    curves = [
        (
            default_label(Path(run_dir), info),
            *np.array([[e.value, e.ci_low, e.ci_high] for e in iqm]).T,
        )
        for (run_dir, info, _), iqm in zip(runs, iqms)
    ]
    title = (
        f"Greedy return in Gymnasium's CartPole-v1 ({episodes} episodes per seed) against "
        f"{field}: {IQM_TEXT}; band: that interval"
    )
    buf = io.BytesIO()
    draw_robustness(field, values, curves, title).savefig(buf, format="png", dpi=100)
    return buf.getvalue()


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


def _write_gif(args: argparse.Namespace, trained: RunParams) -> None:
    import jax

    from jaxcart.results.gif import render_gif
    from jaxcart.rundir.policy import make_policy

    one = jax.tree.map(lambda x: x[args.seed_index], trained.params)
    policy = make_policy(one, trained.config)
    gif = render_gif(policy, args.gif, seed=args.gif_seed, env_params=trained.env_params)
    print(
        f"wrote {gif.path}: seed {args.seed_index}, {gif.steps} steps, return "
        f"{gif.episode_return:.0f}, {gif.frames} frames ({gif.backend} renderer)"
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m jaxcart.evaluate RUN_DIR [RUN_DIR ...]``: prints the per-seed Gymnasium
    evaluation table (with ``--sweep``, the IQM over seeds at each value); with ``--out``,
    writes the evaluation; with ``--gif``, renders seed ``--seed-index``. Returns 0, or 2 for
    bad input."""
    return cli.run_command(lambda: _evaluate_command(argv), also=(ValueError, ImportError))


if __name__ == "__main__":
    cli.command_main(main)
